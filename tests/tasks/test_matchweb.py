"""Match webs (design §4, KG04 §3.1-3.2): numba kernels vs slow references, constructed grids,
a clip against a time-warped copy of itself, and coarse-to-fine vs the full build."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
from fixtures import wiggle
from motionweb.store.kinematics import sample_motion
from motionweb.store.web import MatchWeb
from motionweb.tasks.distance import distance_cells, distance_grid, prepare_pair
from motionweb.tasks.features import FeatureParams, clip_features, point_weights
from motionweb.tasks.matchweb.band import optimal_path
from motionweb.tasks.matchweb.bridges import find_bridges
from motionweb.tasks.matchweb.build import build_web, build_web_full
from motionweb.tasks.matchweb.minima import find_chains, local_minima, valid_region
from motionweb.tasks.matchweb.params import MatchWebParams
from naive import all_paths, ref_bridges, ref_chains, ref_minima, ref_valid, slope_ok
from scipy.spatial import cKDTree

CFG = MatchWebParams()
ROT_CH = ("Zrotation", "Xrotation", "Yrotation")


# ---------------------------------------------------------------------------- slow references


# ---------------------------------------------------------------------------- constructed grids


def valleys(shape: tuple[int, int], offsets: list[int], slope: float) -> np.ndarray:
    """Grid with diagonal valleys j = i + offset (value 0.1), rising by ``slope`` per cell away
    (no plateaus: a plateau's border minima would make a wide valid region)."""
    i, j = np.mgrid[0:shape[0], 0:shape[1]]
    g = np.full(shape, np.inf)
    for off in offsets:
        g = np.minimum(g, 0.1 + slope * np.abs(j - i - off))
    return g.astype(np.float32)


def chain_list(web: MatchWeb) -> list[np.ndarray]:
    return [web.path(p)[0] for p in range(web.n_paths)]


def test_kernels_match_slow_references() -> None:
    rng = np.random.default_rng(3)
    g = rng.random((40, 33)).astype(np.float32)
    g[5, 5] = g[5, 6]  # a tie
    g[10:14, 3:9] = 0.5  # a plateau
    g[20, :] = np.inf  # an ignored row
    m = local_minima(g)
    assert np.array_equal(m, ref_minima(g))
    assert np.array_equal(valid_region(g, m, 0.15), ref_valid(g, m, 0.15))
    # chains on a smoother grid, where minima line up
    g2 = (np.sin(np.add.outer(np.arange(60) * 0.3, -np.arange(50) * 0.25)) + 1.2 + 0.3 * rng.random((60, 50)))
    m2 = local_minima(g2)
    for k, ext in [(3, 2), (2, 3), (1, 1)]:
        cells, offs = find_chains(g2, m2, k, ext)
        got = [list(map(tuple, cells[a:b].tolist())) for a, b in itertools.pairwise(offs)]
        want = ref_chains(g2.astype(np.float32), m2, k, ext)
        assert got == want and len(got) > 3
        assert all(slope_ok(np.array(c), k) for c in got)


def test_optimal_path_is_the_brute_force_optimum() -> None:
    rng = np.random.default_rng(7)
    for k in (1, 2, 3):
        g = rng.random((6, 7))
        mask = rng.random((6, 7)) > 0.15
        mask[0, 0] = mask[5, 6] = True
        best = np.inf
        for p in all_paths((0, 0), 11, lambda c, _p, mask=mask: c[0] < 6 and c[1] < 7 and mask[c]):
            if p[-1] == (5, 6) and slope_ok(np.array(p), k):
                best = min(best, sum(g[c] for c in p))
        path = optimal_path(g, (0, 0), (5, 6), k, mask=mask)
        if np.isfinite(best):
            assert path is not None and slope_ok(path, k) and mask[path[:, 0], path[:, 1]].all()
            assert tuple(path[0]) == (0, 0) and tuple(path[-1]) == (5, 6)
            assert np.isclose(g[path[:, 0], path[:, 1]].sum(), best)
        else:
            assert path is None


def check_bridges(g: np.ndarray, valid: np.ndarray, cells: np.ndarray, offs: np.ndarray, L: int) -> int:
    br, bcells, boffs = find_bridges(g, valid, cells, offs, 3, L)
    want = ref_bridges(g, valid, cells, offs, L)
    got = {}
    for b, (c, _, d, _) in enumerate(br):
        x = bcells[boffs[b]:boffs[b + 1]]
        assert valid[x[:, 0], x[:, 1]].all() and slope_ok(x, 3)
        got[(int(c), int(d))] = float(g[x[:, 0], x[:, 1]].mean())
    assert set(got) == set(want)
    for key, value in got.items():
        assert np.isclose(value, want[key], rtol=1e-5)
    return len(got)


def test_bridges_match_brute_force() -> None:
    g = valleys((16, 18), [0, 5], slope=0.002)
    g += np.random.default_rng(1).random(g.shape).astype(np.float32) * 1e-4
    m = local_minima(g)
    valid = valid_region(g, m, 0.15)
    cells, offs = find_chains(g, m, 3, 4)
    assert len(offs) == 3
    assert check_bridges(g, valid, cells, offs, 7) == 2


def test_bridges_on_a_holed_valid_region_match_brute_force() -> None:
    """The bridge search only visits cells reachable from its start: holes and dead ends in the
    valid region (random masks) must not change which bridges are found or their costs."""
    rng = np.random.default_rng(5)
    g = valleys((16, 18), [0, 4, -4], slope=0.002)
    g += rng.random(g.shape).astype(np.float32) * 1e-4
    cells, offs = find_chains(g, local_minima(g), 3, 4)
    assert len(offs) >= 3
    found = 0
    for _ in range(6):
        valid = rng.random(g.shape) < 0.75
        valid[cells[:, 0], cells[:, 1]] = True
        found += check_bridges(g, valid, cells, offs, 6)
    assert found > 0


def test_a_chain_bridged_to_many_chains_keeps_each_bridge_path() -> None:
    """A chain with bridges to more chains than the kept-path buffer first holds (16): each
    bridge's path is the one found for it (it starts at its junction on the from-chain, ends at
    its junction on the to-chain, moves up or right by unit steps under the slope rule, inside
    the valid region) whatever the buffer's growth."""
    rng = np.random.default_rng(3)
    n = 48
    g = (0.5 + rng.random((n, n))).astype(np.float32)
    diag = np.stack([np.arange(n)] * 2, axis=1)
    pits = np.array([[i, i + 3] for i in range(0, n - 3, 2)])  # one-cell chains beside the diagonal
    cells = np.concatenate([diag, pits])
    offs = np.concatenate([[0, n], n + np.arange(1, len(pits) + 1)])
    valid = np.ones_like(g, dtype=bool)
    br, bc, bo = find_bridges(g, valid, cells, offs, 3, 9)
    from_diag = br[br[:, 0] == 0]
    assert len(from_diag) > 16 and len(set(from_diag[:, 2].tolist())) == len(from_diag)
    for b, (c, ia, d, ic) in enumerate(br.tolist()):
        x = bc[bo[b]:bo[b + 1]]
        assert tuple(x[0]) == tuple(cells[offs[c] + ia]) and tuple(x[-1]) == tuple(cells[offs[d] + ic])
        step = np.diff(x, axis=0)
        assert ((step >= 0) & (step <= 1)).all() and (step.sum(axis=1) >= 1).all() and slope_ok(x, 3)
        assert len(x) <= 9


def test_chains_found_and_short_ones_dropped() -> None:
    g = valleys((50, 50), [0], slope=0.05)
    for i in range(5, 10):  # an isolated pit of 5 cells along j = i + 25
        g[i, i + 25] = 0.1
    web = build_web_full(g, 30.0, CFG, self_pair=False)
    long = [c for c in chain_list(web) if np.ptp(c[:, 0]) >= 8]
    assert len(long) == 1 and np.array_equal(long[0], np.stack([np.arange(50)] * 2, axis=1))
    short = {(i, i + 25) for i in range(5, 10)}
    assert not short & set(map(tuple, web.paths_cells.tolist()))
    # the same valley at 10 Hz is long enough (extent 4 frames >= 0.25 s · 10 Hz)
    web10 = build_web_full(g, 10.0, CFG, self_pair=False)
    assert short <= set(map(tuple, web10.paths_cells.tolist()))


@pytest.mark.parametrize("slope,expect_bridges", [(0.001, True), (0.05, False)])
def test_bridges_inside_the_valid_region_only(slope: float, expect_bridges: bool) -> None:
    g = valleys((60, 70), [0, 10], slope=slope)
    web = build_web_full(g, 30.0, CFG, self_pair=False)
    chains = chain_list(web)
    assert len(chains) == 2
    if not expect_bridges:  # a ridge (> 15% above the valley floor) between the valleys
        assert web.n_bridges == 0
        return
    valid = valid_region(g, local_minima(g), CFG.valid_a)
    pairs = {(int(a), int(c)) for a, _, c, _ in web.bridges}
    assert pairs == {(0, 1), (1, 0)}
    for b in range(web.n_bridges):
        cells, vals = web.bridge(b)
        p, a, q, c = web.bridges[b]
        assert np.array_equal(cells[0], chains[p][a]) and np.array_equal(cells[-1], chains[q][c])
        assert slope_ok(cells, CFG.slope_k) and valid[cells[:, 0], cells[:, 1]].all()
        assert np.abs(cells[-1] - cells[0]).sum() < 2.0 * 30.0
        assert np.allclose(vals, g[cells[:, 0], cells[:, 1]])


def test_bridge_across_a_gap() -> None:
    """A valley that jumps 8 columns at row 30: the slope rule cuts the chain, a bridge joins it."""
    i, j = np.mgrid[0:70, 0:70]
    centre = np.where(i < 30, i, i + 8)
    g = (0.1 + 0.001 * np.abs(j - centre)).astype(np.float32)
    web = build_web_full(g, 30.0, CFG, self_pair=False)
    chains = chain_list(web)
    first = next(p for p, c in enumerate(chains) if (10, 10) in set(map(tuple, c.tolist())))
    second = next(p for p, c in enumerate(chains) if (50, 58) in set(map(tuple, c.tolist())))
    assert first != second
    assert any(a == first and c == second for a, _, c, _ in web.bridges)
    valid = valid_region(g, local_minima(g), CFG.valid_a)
    for b in range(web.n_bridges):
        cells = web.bridge(b)[0]
        assert slope_ok(cells, CFG.slope_k) and valid[cells[:, 0], cells[:, 1]].all()


def test_self_pair_ignores_the_diagonal_band() -> None:
    g = valleys((60, 60), [0, 20, -20], slope=0.05)
    web = build_web_full(g, 30.0, CFG, self_pair=True)
    band = int(CFG.self_band_s * 30)
    cells = np.concatenate([web.paths_cells, web.bridges_cells])
    assert len(cells) and np.all(np.abs(cells[:, 0] - cells[:, 1]) > band)
    assert {tuple(c) for c in web.paths_cells.tolist()} >= {(i, i + 20) for i in range(40)}


def test_round_trip_arrays() -> None:
    g = valleys((60, 70), [0, 10], slope=0.001)
    web = build_web_full(g, 30.0, CFG.model_copy(update={"keep_grids": True}), self_pair=False)
    d = web.to_arrays()
    assert all(isinstance(v, np.ndarray) for v in d.values())
    back = MatchWeb.from_arrays(d)
    assert back.rate == web.rate and back.shape == web.shape and back.self_pair == web.self_pair
    for key, v in d.items():
        assert np.array_equal(back.to_arrays()[key], v) and back.to_arrays()[key].dtype == v.dtype
    assert web.n_bridges > 0 and np.array_equal(back.grid, g)


# ---------------------------------------------------------------------------- motions


def smooth_warp(n_out: int, n_in: int, seed: int) -> np.ndarray:
    """Fractional source frames of a smooth monotone warp with speeds within [0.6, 1.6]."""
    rng = np.random.default_rng(seed)
    x = np.linspace(0, 1, n_out)
    speed = np.ones(n_out)
    for _ in range(3):
        speed += rng.uniform(-0.3, 0.3) * np.sin(2 * np.pi * rng.uniform(0.5, 3) * x + rng.uniform(0, 6))
    c = np.concatenate([[0], np.cumsum(np.clip(speed, 0.6, 1.6)[:-1])])
    return c / c[-1] * (n_in - 1)


@pytest.fixture(scope="module")
def warped_pair():
    fc = FeatureParams()
    a = wiggle(1200, 60.0, 1)  # 20 s
    warp = smooth_warp(1000, 1200, 2)
    b = replace(sample_motion(a, warp), name="warped")
    w = point_weights(a.skeleton, fc)
    fa = {r: clip_features(a, r, fc) for r in fc.rates}
    fb = {r: clip_features(b, r, fc) for r in fc.rates}
    web = build_web(fa, fb, w, CFG, self_pair=False)
    full = build_web_full(distance_grid(fa[30.0], fb[30.0], w), 30.0, CFG, self_pair=False)
    return warp, web, full


def test_time_warped_copy_follows_the_warp(warped_pair) -> None:
    warp, web, full = warped_pair
    assert web.rate == 30.0 and web.shape == (600, 500)
    for wb in (web, full):
        lengths = np.diff(wb.paths_offsets)
        cells, _ = wb.path(int(np.argmax(lengths)))
        # B's frame j (30 Hz) is B's 60 Hz frame 2j, which shows A's 60 Hz frame warp[2j]
        truth = warp[np.minimum(2 * cells[:, 1], len(warp) - 1)] / 2.0
        assert np.abs(cells[:, 0] - truth).max() <= 2.0
        assert np.ptp(cells[:, 1]) > 0.9 * 500  # spans (nearly) the whole clip
        assert slope_ok(cells, CFG.slope_k)


def test_coarse_to_fine_covers_the_full_build(warped_pair) -> None:
    """"Same chains": every chain of the full 30 Hz build spanning ≥ 1 s has ≥ 70% of its cells
    (≥ 90% over all such cells) within 2 cells (Chebyshev) of a coarse-to-fine path."""
    _, web, full = warped_pair
    tree = cKDTree(web.paths_cells)
    fractions, total, covered = [], 0, 0
    for cells in chain_list(full):
        if max(np.ptp(cells[:, 0]), np.ptp(cells[:, 1])) < 30:
            continue
        d, _ = tree.query(cells, p=np.inf)
        fractions.append(np.mean(d <= 2))
        total += len(cells)
        covered += int(np.sum(d <= 2))
    assert len(fractions) >= 3
    assert min(fractions) >= 0.7 and covered / total >= 0.9
    # every refined path and bridge is a valid slope-ruled path with its values recorded
    for p in range(web.n_paths):
        assert slope_ok(web.path(p)[0], CFG.slope_k)
    for b in range(web.n_bridges):
        cells = web.bridge(b)[0]
        p, a, q, c = web.bridges[b]
        assert slope_ok(cells, CFG.slope_k)
        assert np.array_equal(cells[0], web.path(p)[0][a]) and np.array_equal(cells[-1], web.path(q)[0][c])
    assert web.n_bridges > 0 and np.all(np.isfinite(web.paths_values))


def test_single_rate_build_is_the_full_build() -> None:
    fc = FeatureParams()
    a, b = wiggle(300, 30.0, 4), wiggle(240, 30.0, 5)
    w = point_weights(a.skeleton, fc)
    fa, fb = clip_features(a, 10.0, fc), clip_features(b, 10.0, fc)
    web = build_web({10.0: fa}, {10.0: fb}, w, CFG, self_pair=False)
    full = build_web_full(distance_grid(fa, fb, w), 10.0, CFG, self_pair=False)
    assert np.array_equal(web.paths_cells, full.paths_cells) and np.array_equal(web.bridges, full.bridges)


def test_refined_values_are_the_cell_distances() -> None:
    """Refined paths and bridges carry D at their cells (each band cell evaluated once into the
    level's tiles, shared by overlapping bands): the same values as the per-cell reference."""
    fc = FeatureParams()
    a, b = wiggle(900, 60.0, 6), wiggle(700, 60.0, 7)
    w = point_weights(a.skeleton, fc)
    fa = {r: clip_features(a, r, fc) for r in fc.rates}
    fb = {r: clip_features(b, r, fc) for r in fc.rates}
    for other, self_pair in ((fb, False), (fa, True)):
        web = build_web(fa, other, w, CFG, self_pair=self_pair)
        pa, pb = prepare_pair(fa[30.0], other[30.0], w)
        assert web.n_paths > 0
        for cells, vals in ((web.paths_cells, web.paths_values), (web.bridges_cells, web.bridges_values)):
            assert np.array_equal(vals, distance_cells(pa, pb, cells[:, 0], cells[:, 1]))
