"""Features and frame distances (design §3): GEMM grid vs an explicit per-pair alignment."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from fixtures import small_skeleton, wiggle
from motionweb.store.kinematics import quat_from_axis_angle, quat_mul
from motionweb.tasks.distance import (
    _cells_kernel,
    distance_block,
    distance_cells,
    distance_grid,
    distance_grid_cells,
    distance_prepared,
    distance_row,
    prepare_pair,
    rigid_align_2d,
)
from motionweb.tasks.features import FeatureParams, clip_features, point_weights
from naive import slow_grid
from scipy.optimize import minimize

ROT_CH = ("Zrotation", "Xrotation", "Yrotation")


@pytest.fixture(scope="module")
def clouds() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    cfg = FeatureParams()
    a, b = wiggle(90, 30.0, 1), wiggle(70, 30.0, 2)
    return clip_features(a, 30.0, cfg), clip_features(b, 30.0, cfg), point_weights(a.skeleton, cfg)


def test_features_shape_window_and_units() -> None:
    cfg = FeatureParams(window=5)
    m = wiggle(61, 60.0, 3)
    f = clip_features(m, 30.0, cfg)
    j = m.skeleton.n_joints
    assert f.shape == (31, 5 * j, 3) and f.dtype == np.float32
    # window frame 2 (the centre) of frame 10 is frame 10's joints; window frame 0 of frame 0 is clamped
    centre = f[:, 2 * j:3 * j]
    assert np.allclose(f[10, 0:j], centre[8], atol=1e-6)
    assert np.allclose(f[0, 0:j], centre[0]) and np.allclose(f[0, j:2 * j], centre[0])
    assert np.allclose(f[-1, 4 * j:], centre[-1])
    # metres: the file is in cm, the root sits ~95 cm above the ground
    assert 0.85 < centre[:, 0, 1].mean() < 1.05
    # z-up: the same clip with its axes turned so that the file's up is z gives the same clouds
    rot = quat_from_axis_angle(np.array([1.0, 0, 0]), np.array(np.pi / 2))
    rz = replace(m, rotations=np.concatenate([quat_mul(rot, m.rotations[:, :1]), m.rotations[:, 1:]], axis=1),
                 root_positions=m.root_positions @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]).T)
    fz = clip_features(rz, 30.0, cfg, up="z")
    assert np.allclose(fz, f, atol=1e-5)


def test_point_weights() -> None:
    sk = small_skeleton()
    w = point_weights(sk, FeatureParams(window=3, joint_weights={"head": 3.0, "lknee": 0.0}))
    assert w.shape == (3 * sk.n_joints,) and np.isclose(w.sum(), 1.0)
    assert np.isclose(w[2], 3 * w[0]) and w[4] == 0 and np.isclose(w[2 + sk.n_joints], w[2])
    with pytest.raises(ValueError, match="no joint"):
        point_weights(sk, FeatureParams(joint_weights={"tail": 1.0}))


def test_closed_form_is_the_optimal_alignment(clouds) -> None:
    fa, fb, w = clouds
    rng = np.random.default_rng(0)
    for _ in range(4):
        p, q = fa[rng.integers(len(fa))].astype(float), fb[rng.integers(len(fb))].astype(float)
        theta, t, d = rigid_align_2d(p, q, w)

        def cost(x: np.ndarray, p: np.ndarray = p, q: np.ndarray = q) -> float:
            c, s = np.cos(x[0]), np.sin(x[0])
            qx = c * q[:, 0] + s * q[:, 2] + x[1]
            qz = -s * q[:, 0] + c * q[:, 2] + x[2]
            return float(np.sum(w * ((p[:, 0] - qx) ** 2 + (p[:, 1] - q[:, 1]) ** 2 + (p[:, 2] - qz) ** 2)))

        assert np.isclose(cost(np.array([theta, *t])), d)
        for start in np.linspace(-np.pi, np.pi, 4, endpoint=False):
            res = minimize(cost, np.array([start, 0.0, 0.0]), method="Nelder-Mead",
                           options={"xatol": 1e-9, "fatol": 1e-12, "maxiter": 4000})
            assert res.fun >= d - 1e-9


def test_gemm_grid_matches_slow_reference(clouds) -> None:
    fa, fb, w = clouds
    ref = slow_grid(fa, fb, w)
    g64 = distance_grid(fa, fb, w, dtype=np.float64)
    assert g64.shape == (len(fa), len(fb))
    assert np.allclose(g64, ref, rtol=1e-9, atol=1e-12)
    g32 = distance_grid(fa, fb, w)
    assert g32.dtype == np.float32
    # 1e-4 relative to each cell, with an absolute floor of 1e-4 of the grid's mean
    assert np.all(np.abs(g32 - ref) <= 1e-4 * ref + 1e-4 * ref.mean())
    assert np.allclose(distance_grid(fa, fb, w, tile=16), g32, rtol=1e-5, atol=1e-7)
    assert (g32 >= 0).all()


def test_self_grid_diagonal_is_zero_and_symmetric(clouds) -> None:
    fa, _, w = clouds
    g = distance_grid(fa, fa, w, dtype=np.float64)
    assert np.allclose(np.diag(g), 0.0, atol=1e-12) and np.allclose(g, g.T, atol=1e-12)


def test_invariant_to_vertical_rotation_and_horizontal_translation(clouds) -> None:
    fa, fb, w = (np.asarray(x, dtype=np.float64) for x in clouds)
    rng = np.random.default_rng(5)
    angles = rng.uniform(-np.pi, np.pi, len(fb))  # a different rigid motion for every frame
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    moved = np.empty_like(fb)
    moved[:, :, 0] = c * fb[:, :, 0] + s * fb[:, :, 2] + rng.uniform(-5, 5, (len(fb), 1))
    moved[:, :, 1] = fb[:, :, 1]
    moved[:, :, 2] = -s * fb[:, :, 0] + c * fb[:, :, 2] + rng.uniform(-5, 5, (len(fb), 1))
    g, gm = distance_grid(fa, fb, w, dtype=np.float64), distance_grid(fa, moved, w, dtype=np.float64)
    assert np.allclose(g, gm, rtol=1e-9, atol=1e-10)
    lifted = fb.copy()
    lifted[:, :, 1] += 0.3  # a vertical shift is not factored out
    assert not np.allclose(distance_grid(fa, lifted, w, dtype=np.float64), g, atol=1e-3)


def test_blocks_and_cells_agree_with_the_grid(clouds) -> None:
    fa, fb, w = clouds
    g = distance_grid(fa, fb, w)
    rows, cols = np.array([3, 4, 50, 7]), np.array([0, 69, 5])
    assert np.allclose(distance_block(fa, fb, w, rows, cols), g[np.ix_(rows, cols)], rtol=1e-5, atol=1e-7)
    assert np.allclose(distance_block(fa, fb, w, slice(10, 20), slice(30, 33)), g[10:20, 30:33], rtol=1e-5,
                       atol=1e-7)
    pa, pb = prepare_pair(fa, fb, w)
    r = np.array([0, 5, 89, 40])
    c = np.array([0, 69, 1, 40])
    assert np.allclose(distance_cells(pa, pb, r, c), g[r, c], rtol=1e-4, atol=1e-6)
    assert np.allclose(distance_prepared(pa, pb, r, c), g[np.ix_(r, c)], rtol=1e-5, atol=1e-7)


def test_prepare_gives_the_bytes_of_the_numpy_expressions_it_fuses():
    """ClipOperands.prepare's fused pass (_shift_heights) against the NumPy expressions it
    replaced: the operands, and so every web built from them, are the same bytes (issue 25)."""
    from motionweb.tasks.distance import ClipOperands

    rng = np.random.default_rng(3)
    for _ in range(60):
        f_n, p_n = int(rng.integers(1, 300)), int(rng.integers(1, 130))
        clouds = (rng.normal(size=(f_n, p_n, 3)) * rng.uniform(0.01, 3)).astype(np.float32)
        w = rng.random(p_n) + 0.01
        for dt in (np.float32, np.float64):
            ops = ClipOperands.of(clouds, w, dt)
            y0 = float(rng.normal())
            got = ops.prepare(y0)
            y = ops.y - y0
            assert got.norms.tobytes() == ((ops.xx + y * y + ops.zz) @ ops.w).astype(dt).tobytes()
            assert got.left_y.tobytes() == np.ascontiguousarray(y * ops.w, dtype=dt).tobytes()
            assert got.right_y.tobytes() == np.ascontiguousarray(y, dtype=dt).tobytes()
            assert got.left_y.dtype == dt and got.right_y.flags.c_contiguous


def test_row_kernel_gives_the_bytes_of_the_cell_kernel() -> None:
    """tasks.distance.distance_row (a row's cells in one call, the cell body inlined) and the full
    grid through it are the bytes of cell_distance called cell by cell, for every number of points
    up to 139: LLVM vectorizes the sums over the points the same way in both (its main loop, its
    epilogue and the scalar tail all exercised)."""
    rng = np.random.default_rng(11)
    for p in range(1, 140):
        a = (rng.normal(size=(9, p, 3)) * rng.uniform(1e-3, 10, (9, p, 1))).astype(np.float32)
        b = rng.normal(size=(7, p, 3)).astype(np.float32)
        pa, pb = prepare_pair(a, b, rng.uniform(0.5, 1.5, p))
        rows, cols = np.repeat(np.arange(9), 7), np.tile(np.arange(7), 9)
        want = np.empty(63)  # one cell_distance call per cell, float64 as the refinement keeps them
        _cells_kernel(pa.left, pa.left_y, pa.norms, pb.right, pb.right_y, pb.norms, rows, cols, want)
        row = np.empty(63)
        for i in range(9):
            distance_row(pa.left, pa.left_y, pa.norms, pb.right, pb.right_y, pb.norms, i, 0, 7, row, 7 * i)
        assert row.tobytes() == want.tobytes(), p
        grid = distance_grid_cells(pa, pb)
        assert grid.tobytes() == want.astype(np.float32).tobytes(), p
