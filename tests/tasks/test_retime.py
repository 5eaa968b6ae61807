"""Physics-based retiming (MPS06 §3.3-3.6) on the synthetic jumper of test_dynamics."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from fixtures import G, synthetic_jump
from motionweb.store.kinematics import hold_ends
from motionweb.tasks.retime import (
    ContactParams,
    RetimeError,
    RetimeParams,
    prepare,
    retime_plan,
    shortest_duration,
)
from motionweb.tasks.retime.objective import evaluate
from motionweb.tasks.retime.polygons import EDGE_TOL, N_ROOT, FrameLP
from motionweb.tasks.retime.report import free_fall, held_up, inner_flights
from motionweb.tasks.retime.spline import TimingSpline, check_keytimes, objective_function
from naive import evaluate_numpy
from scipy.optimize import linprog

# the machinery on a synthetic body: limits from the clip itself (its 3-joint legs are no adult's)
OPTS = RetimeParams(torque_limits_from="clip")


@pytest.fixture(scope="module")
def jump():
    motion, flight = synthetic_jump(fps=30, stand=1.2, bend=0.6)
    return motion, flight, prepare(motion, OPTS)


def _flight_speed(res, t0: float, t1: float) -> tuple[np.ndarray, float]:
    tt = np.linspace(0, res.t[-1], 4000)
    p, pd, _ = res.spline.evaluate(res.z, tt)
    m = (p > t0 + 0.02) & (p < t1 - 0.02)
    return pd[m], float(tt[m][-1] - tt[m][0])


def test_lp_vertices_match_a_slow_reference(jump) -> None:
    _motion, _, plan = jump
    opts = OPTS.polygons
    for i in (10, 45, 60, 80):  # standing, crouch, flight, landing
        cols = plan.contacts.columns(i)
        N = plan.contacts.basis[i][:, cols]
        A, B, C = plan.A[i], plan.B[i], plan.C[i]
        tol = plan.polygons.tolerance[i]
        lim = plan.original.limits[N_ROOT:]
        # reference: scipy linprog, x = [p̈, ṗ², λ], root rows |·| ≤ tol, joints |·| ≤ limits
        G = np.hstack([A[:, None], B[:, None], -N])
        a_ub = np.vstack([G[:N_ROOT], -G[:N_ROOT], G[N_ROOT:], -G[N_ROOT:]])
        b_ub = np.concatenate([tol - C[:N_ROOT], tol + C[:N_ROOT], lim - C[N_ROOT:], lim + C[N_ROOT:]])
        bounds = [(-opts.pdd_max, opts.pdd_max), (0, opts.speed_max**2)] + [(0, None)] * len(cols)
        verts = plan.polygons.vertices[i]
        for ang in np.linspace(0, 2 * np.pi, 9)[:-1]:
            d = np.array([np.cos(ang), np.sin(ang)])
            ref = linprog(-np.concatenate([d, np.zeros(len(cols))]), A_ub=a_ub, b_ub=b_ub, bounds=bounds,
                          method="highs")
            assert ref.status == 0
            best = -ref.fun
            # every polygon vertex is feasible: none exceeds the true support value
            assert (verts @ d).max() <= best + 1e-6 * (1 + abs(best))
            # the sweep found the extreme in these directions (up to the refinement threshold)
            assert (verts @ d).max() >= best - EDGE_TOL
        lp = FrameLP(A, B, C, N, plan.original.limits, opts)
        lp.set_residual_bound(tol)
        x = lp.solve(np.concatenate([[0.0, 1.0, 0.0], np.zeros(len(cols))]))
        ref = linprog(-np.concatenate([[0.0, 1.0], np.zeros(len(cols))]), A_ub=a_ub, b_ub=b_ub, bounds=bounds,
                      method="highs")
        assert abs(x[1] + ref.fun) < 1e-6 * (1 + abs(ref.fun))


def test_standing_polygon_contains_original_timing(jump) -> None:
    _motion, _, plan = jump
    v = plan.polygons.vertices[5]  # static standing pose
    assert len(v) >= 3
    # (0, 1) strictly inside with margin: every edge's inward distance > 0.5
    e = np.roll(v, -1, axis=0) - v
    rel = np.array([0.0, 1.0]) - v
    cross = (e[:, 0] * rel[:, 1] - e[:, 1] * rel[:, 0]) / np.linalg.norm(e, axis=1)
    assert cross.min() > 0.5
    assert plan.polygons.original_inside.all()


def test_halving_keeps_flight_at_normal_speed(jump) -> None:
    motion, (t0, t1), plan = jump
    _, res = retime_plan(plan, motion.duration / 2, None, OPTS)
    pd, _ = _flight_speed(res, t0, t1)
    assert np.abs(pd - 1).max() < 0.10
    assert np.all(np.diff(res.p) > 0) and res.p[0] == 0 and abs(res.p[-1] - motion.duration) < 1e-9
    # the ground phases absorbed the change: somewhere much faster than 2x
    assert res.pd.max() > 2.5


def test_half_gravity_lengthens_flight_by_sqrt2(jump) -> None:
    motion, (t0, t1), plan = jump
    low = prepare(motion, OPTS, gravity=plan.body.default_gravity() * 0.5)
    _, res = retime_plan(low, motion.duration, None, OPTS)
    _, flight = _flight_speed(res, t0, t1)
    expected = (t1 - t0 - 0.04) * np.sqrt(2)
    assert abs(flight / expected - 1) < 0.05


def test_free_fall_checks_the_length_unit(jump) -> None:
    """The ballistic flight falls at the fixture's gravity. A jump falling at 0.7 g, as a clip
    whose unit is 0.7 of the truth would: alone it is only a flight that is not ballistic; twice in
    one clip, alike, it is a unit, and the report names the scale_to_m that makes both fall right."""
    _, _, plan = jump
    ff = free_fall(plan)
    assert ff["flights"] == 1 and ff["gravity"] == pytest.approx(G, rel=0.02) and ff["note"] == ""
    assert not held_up(ff, next(iter(ff["per_flight"])))
    slow, _ = synthetic_jump(fps=30, g=0.7 * G, stand=1.2, bend=0.6)
    one = free_fall(prepare(slow, OPTS))
    assert one["gravity"] == pytest.approx(0.7 * G, rel=0.02) and one["note"] == ""
    assert held_up(one, next(iter(one["per_flight"])))
    twice = replace(slow, root_positions=np.concatenate([slow.root_positions] * 2),
                    rotations=np.concatenate([slow.rotations] * 2))
    ff = free_fall(prepare(twice, OPTS))
    assert ff["flights"] == 2 and "scale_to_m 1.429 (now 1)" in ff["note"], ff
    assert ff["expected"] == pytest.approx(0.7 * G, rel=0.02) and not any(held_up(ff, s0) for s0 in ff["per_flight"])


def test_keytimes_met_and_monotone(jump) -> None:
    _motion, _, plan = jump
    keys = [(1.5, 1.0), (3.0, 2.6)]
    _, res = retime_plan(plan, 3.5, keys, OPTS)
    for s, o in keys:
        p, _, _ = res.spline.evaluate(res.z, np.array([o]))
        assert abs(p[0] - s) < 1e-9
    tt = np.linspace(0, 3.5, 5000)
    p, pd, _ = res.spline.evaluate(res.z, tt)
    assert np.all(np.diff(p) > 0) and pd.min() > 0


def test_impossible_requests_are_explained() -> None:
    with pytest.raises(RetimeError, match="speed"):
        check_keytimes(4.0, 0.5, [], 6.0)
    with pytest.raises(RetimeError, match="increase"):
        check_keytimes(4.0, 3.0, [(1.0, 2.0), (2.0, 1.0)], 6.0)
    with pytest.raises(RetimeError, match="outside"):
        check_keytimes(4.0, 3.0, [(5.0, 1.0)], 6.0)


def test_no_contact_is_a_clear_error() -> None:
    motion, _ = synthetic_jump(fps=20)
    lifted = replace(motion, root_positions=motion.root_positions + [0.0, 2.0, 0.0])
    # the clip's own floor follows it up; a floor given at 0 leaves it 2 m in the air
    assert prepare(lifted, OPTS).contacts.ground == pytest.approx(2.0, abs=0.06)
    with pytest.raises(RetimeError, match="flight"):
        prepare(lifted, OPTS.model_copy(update={"contacts": ContactParams(floor_height=0.0)}))


def test_objective_gradient_and_compiled_kernel(jump) -> None:
    motion, _, plan = jump
    rng = np.random.default_rng(1)
    u = rng.uniform(0, motion.n_frames - 1, 300)
    x = rng.uniform([-20, 0], [20, 10], (300, 2))
    for a, b in zip(evaluate(plan.baked, u, x), evaluate_numpy(plan.baked, u, x), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)
    sp = TimingSpline.make(np.array([0.0, 3.0]), np.array([0.0, motion.duration]), 8.0)
    fun = objective_function(plan.baked, sp, motion.fps, 3.0, 800)
    z = rng.normal(0, 0.3, sp.n_params)
    f0, g = fun(z)
    for k in rng.choice(sp.n_params, 5, replace=False):
        h = 1e-6
        e = np.zeros_like(z)
        e[k] = h
        num = (fun(z + e)[0] - fun(z - e)[0]) / (2 * h)
        assert abs(num - g[k]) <= 1e-3 * (abs(num) + abs(g[k])) + 1e-4 * abs(f0)


@pytest.fixture(scope="module")
def real_jump(deepmimic_dir):
    from motionweb.store.deepmimic import read_deepmimic, read_humanoid_urdf

    motion = read_deepmimic(deepmimic_dir / "motions" / "humanoid3d_jump.txt")
    humanoid = read_humanoid_urdf(deepmimic_dir / "humanoid.urdf")
    return motion, humanoid, prepare(motion, OPTS, humanoid=humanoid)


def _inner_flight(plan, motion) -> tuple[float, float]:
    flights = inner_flights(plan.contacts.active, motion.fps)
    assert len(flights) == 1
    return flights[0]


def test_real_jump_flight_held_when_the_ground_phases_can_absorb(real_jump) -> None:
    """DeepMimic jump (MPS06 Fig. 1): its ground phases are all crouch, push-off and landing.

    Halving it is out of reach of any feasible timing (the crouch is a controlled fall, which
    unilateral contacts cannot speed up much), so the bound of ``shortest_duration`` exceeds half
    the clip; a shortening the ground phases can absorb keeps the flight near normal speed.
    """
    motion, _, plan = real_jump
    t0, t1 = _inner_flight(plan, motion)
    assert 0.4 < t1 - t0 < 0.6  # one ~0.45 s flight (last to first frame on the ground)
    assert shortest_duration(plan.polygons, motion.fps) > motion.duration / 2
    _, res = retime_plan(plan, 0.85 * motion.duration, None, OPTS)
    pd, _ = _flight_speed(res, t0, t1)
    assert np.abs(pd - 1).max() < 0.15
    assert res.pd.max() > 1.3  # the ground phases took the change


def test_real_jump_with_idle_time_halved_keeps_its_flight(real_jump) -> None:
    """MPS06 Fig. 1 on real data: given idle time (1.5 s standing before and after), halving the
    DeepMimic jump speeds up the standing and keeps the flight at normal speed."""
    motion, humanoid, _ = real_jump
    still = replace(hold_ends(motion, 1.5), name="jump_idle")
    plan = prepare(still, OPTS, humanoid=humanoid)
    t0, t1 = _inner_flight(plan, still)
    _, res = retime_plan(plan, still.duration / 2, None, OPTS)
    pd, _ = _flight_speed(res, t0, t1)
    assert np.abs(pd - 1).max() < 0.10
    assert res.pd.max() > 3.0  # the standing absorbed the change


def test_bands_clip_a_polygon_exactly_and_interpolate_forces() -> None:
    """λ-free joint rows are cut from the polygon as 2-D bands (polygons.HalfPlanes): a unit square
    cut by 0.25 ≤ x ≤ 0.5 and y ≤ 0.75 is that rectangle, λ linear along the cut edges; a segment
    (a flight's thin polygon) is cut to its part inside; a band missing the polygon empties it."""
    from motionweb.tasks.retime.polygons import HalfPlanes, polygon_area

    sq = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    lam = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])  # λ = (x, y): linear in the point
    bands = HalfPlanes(np.array([[1.0, 0.0], [0.0, 2.0]]), np.array([0.25, -np.inf]), np.array([0.5, 1.5]))
    v, lv = bands.clip(sq, lam)
    assert polygon_area(v) == pytest.approx(0.25 * 0.75)
    assert v[:, 0].min() == pytest.approx(0.25) and v[:, 0].max() == pytest.approx(0.5)
    assert v[:, 1].max() == pytest.approx(0.75)
    np.testing.assert_allclose(lv, v, atol=1e-12)  # interpolated λ equals the linear field
    assert bands.violation(np.array([0.3, 0.5])) == 0.0 and bands.violation(np.array([0.6, 0.5])) == pytest.approx(0.1)
    seg = np.array([[0.0, 0.5], [1.0, 0.5]])
    v, lv = bands.clip(seg, seg.copy())
    np.testing.assert_allclose(v, [[0.25, 0.5], [0.5, 0.5]])
    np.testing.assert_allclose(lv, v)
    v, _ = HalfPlanes(np.array([[1.0, 0.0]]), np.array([2.0]), np.array([3.0])).clip(sq, lam)
    assert len(v) == 0


def test_largest_step_finds_a_one_frame_jump_of_a_joint() -> None:
    """The report names a capture glitch by the joint's largest one-frame turn near the frame."""
    from motionweb.tasks.retime.report import largest_step

    ang = np.radians(np.concatenate([np.zeros(10), np.full(10, 84.0)]) + np.arange(20) * 1.0)  # 1°/frame, 84° jump
    rot = np.stack([np.cos(ang / 2), np.sin(ang / 2), np.zeros(20), np.zeros(20)], axis=1)
    deg, at = largest_step(rot, 12, 5)
    assert deg == pytest.approx(85.0) and at == 10
    deg, at = largest_step(rot, 2, 5)  # the window 0..7 does not reach the jump
    assert deg == pytest.approx(1.0)
