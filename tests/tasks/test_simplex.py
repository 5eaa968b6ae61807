"""The dense bounded simplex of the polygon LPs (tasks/retime/simplex.py) against scipy/HiGHS.

Random LPs of the polygon LPs' shapes (≤ 36 rows × ≤ 40 columns; feasible, infeasible and
unbounded), degenerate ones (Beale's cycling example, many rows through one vertex), warm-started
sequences of costs and bounds as the sweep issues them, the real LPs of the synthetic jumper's and
of CMU frames (polygons equal to the HiGHS ones), and the HiGHS fallback.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from fixtures import synthetic_jump
from motionweb.store.formats import read_motion
from motionweb.tasks.retime import RetimeParams, prepare
from motionweb.tasks.retime.polygons import FrameLP, feasible_polygons, polygon_area
from motionweb.tasks.retime.simplex import INFEASIBLE, ITERATION_LIMIT, OPTIMAL, UNBOUNDED, DenseLP
from scipy.optimize import linprog

OPTS = RetimeParams(torque_limits_from="clip")  # the synthetic jumper's 3-joint legs are no adult's
TIGHT = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}


def reference(c, M, clo, chi, rlo, rhi):
    """scipy linprog (HiGHS, tight tolerances): (status as simplex.py names it, objective)."""
    a_ub = np.vstack([M, -M])
    b_ub = np.concatenate([rhi, -rlo])
    keep = np.isfinite(b_ub)
    bounds = [(a if np.isfinite(a) else None, b if np.isfinite(b) else None) for a, b in zip(clo, chi)]

    def run(cost):
        return linprog(cost, A_ub=a_ub[keep], b_ub=b_ub[keep], bounds=bounds, method="highs", options=TIGHT)

    ref = run(c)
    if ref.status == 0:
        return OPTIMAL, ref.fun
    if ref.status == 3:
        return UNBOUNDED, None
    assert ref.status == 2, ref.message
    # HiGHS's presolve may say "infeasible or unbounded": a feasible point decides
    return (UNBOUNDED if run(np.zeros_like(c)).status == 0 else INFEASIBLE), None


def random_lp(rng, kind: str):
    """An LP of the polygon LPs' sizes; 'feasible' rows hold at a known point, 'infeasible' not."""
    m, n = int(rng.integers(1, 37)), int(rng.integers(1, 41))
    M = rng.normal(size=(m, n)) * (rng.random((m, n)) < 0.5)
    clo = np.where(rng.random(n) < 0.2, -np.inf, -3 * rng.random(n))
    chi = np.where(rng.random(n) < 0.3, np.inf, 3 * rng.random(n))
    x0 = np.clip(rng.normal(size=n), np.maximum(clo, -5), np.minimum(chi, 5))
    r = M @ x0
    rlo = np.where(rng.random(m) < 0.3, -np.inf, r - rng.random(m))
    rhi = np.where(rng.random(m) < 0.3, np.inf, r + rng.random(m))
    if kind == "infeasible":  # push some rows' ranges past the point (may still be feasible elsewhere)
        k = rng.random(m) < 0.5
        rlo = np.where(k, r + 0.5 + rng.random(m), rlo)
        rhi = np.where(k, np.maximum(rhi, rlo + rng.random(m)), rhi)
    return rng.normal(size=n), M, clo, chi, rlo, rhi


def check_solution(lp: DenseLP, M, clo, chi, rlo, rhi) -> None:
    x = lp.solution
    r = M @ x
    tol = 1e-9 * (1 + np.abs(x).max() + np.abs(r).max())
    assert (x >= clo - tol).all() and (x <= chi + tol).all()
    assert (r >= rlo - tol).all() and (r <= rhi + tol).all()


def test_random_lps_match_highs() -> None:
    rng = np.random.default_rng(11)
    seen = {OPTIMAL: 0, INFEASIBLE: 0, UNBOUNDED: 0}
    for k in range(500):
        c, M, clo, chi, rlo, rhi = random_lp(rng, "infeasible" if k % 3 == 2 else "feasible")
        status, fun = reference(c, M, clo, chi, rlo, rhi)
        for maximize in (False, True):
            lp = DenseLP(M, clo, chi, rlo, rhi, maximize=maximize)
            lp.set_cost(-c if maximize else c)
            assert lp.solve() == status
            seen[status] += 1
            if status == OPTIMAL:
                assert abs((-lp.objective if maximize else lp.objective) - fun) <= 1e-9 * (1 + abs(fun))
                check_solution(lp, M, clo, chi, rlo, rhi)
    # the draws exercise every outcome
    assert min(seen.values()) >= 20, seen


def test_crossed_bounds_are_infeasible() -> None:
    lp = DenseLP(np.ones((1, 2)), np.zeros(2), np.ones(2), np.array([1.0]), np.array([0.5]))
    assert lp.solve() == INFEASIBLE


def test_beale_cycling_example() -> None:
    """Beale (1955): Dantzig's rule with smallest-index ties cycles on it; optimum −1/20 (x = (1/25, 0, 1, 0))."""
    c = np.array([-0.75, 150.0, -0.02, 6.0])
    M = np.array([[0.25, -60.0, -0.04, 9.0], [0.5, -90.0, -0.02, 3.0], [0.0, 0.0, 1.0, 0.0]])
    lp = DenseLP(M, np.zeros(4), np.full(4, np.inf), np.full(3, -np.inf), np.array([0.0, 0.0, 1.0]))
    lp.set_cost(c)
    assert lp.solve() == OPTIMAL
    assert abs(lp.objective + 0.05) < 1e-12
    np.testing.assert_allclose(lp.solution, [0.04, 0.0, 1.0, 0.0], atol=1e-12)


def test_degenerate_vertex_many_tight_rows() -> None:
    """30 rows all tight at the optimum (a highly degenerate vertex), each cost direction solved warm."""
    rng = np.random.default_rng(3)
    n = 8
    v = rng.normal(size=n)
    G = rng.normal(size=(30, n))
    G[:, 0] = np.abs(G[:, 0]) + 0.1  # every row rises with x0: maximizing x0 is bounded
    lp = DenseLP(G, np.full(n, -10.0), np.full(n, 10.0), np.full(30, -np.inf), G @ v, maximize=True)
    for k in range(40):
        c = rng.normal(size=n)
        c[0] = abs(c[0]) + 3.0
        lp.set_cost(c)
        status, fun = reference(-c, G, np.full(n, -10.0), np.full(n, 10.0), np.full(30, -np.inf), G @ v)
        assert lp.solve() == status == OPTIMAL
        assert abs(lp.objective + fun) <= 1e-9 * (1 + abs(fun))


def test_warm_started_sweep_matches_fresh_solves() -> None:
    """One LP re-solved as the sweep does: new costs, fixed and freed columns, changed coefficients."""
    rng = np.random.default_rng(5)
    m, n = 30, 36
    M = rng.normal(size=(m, n))
    x0 = rng.uniform(0, 1, n)
    clo, chi = np.zeros(n), np.where(np.arange(n) < 2, 2.0, np.inf)
    rlo, rhi = M @ x0 - rng.random(m), M @ x0 + rng.random(m)
    lp = DenseLP(M.copy(), clo.copy(), chi.copy(), rlo, rhi, maximize=True)
    iters = []
    for step, a in enumerate(np.linspace(0, 4 * np.pi, 40, endpoint=False)):
        c = np.zeros(n)
        c[:2] = np.cos(a), np.sin(a)
        if step == 13:  # fix the first two columns at the feasible point, then free them
            for j in (0, 1):
                lp.set_col_bounds(j, x0[j], x0[j])
                clo[j] = chi[j] = x0[j]
            c[2:] = -1.0
        if step == 14:
            for j in (0, 1):
                lp.set_col_bounds(j, 0.0, 2.0)
                clo[j], chi[j] = 0.0, 2.0
        if step == 25:  # a coefficient changes (the residual bound's column)
            lp.set_coeff(3, 2, 0.5)
            M[3, 2] = 0.5
        lp.set_cost(c)
        status, fun = reference(-c, M, clo, chi, rlo, rhi)
        assert lp.solve() == status
        if status == OPTIMAL:
            assert abs(lp.objective + fun) <= 1e-9 * (1 + abs(fun))
            check_solution(lp, M, clo, chi, rlo, rhi)
        iters.append(lp.iterations)
    cold = DenseLP(M, clo, chi, rlo, rhi, maximize=True)
    cold.set_cost(c)
    cold.solve()
    assert np.median(iters[1:]) < cold.iterations  # warm starts pivot less than a cold start


def test_start_from_another_lps_basis() -> None:
    """A frame starts from the previous frame's basis: same optimum as a cold start, also when that
    basis is singular for the new matrix (replaced by the slacks)."""
    rng = np.random.default_rng(8)
    for k in range(60):
        c, M, clo, chi, rlo, rhi = random_lp(rng, "feasible")
        first = DenseLP(M, clo, chi, rlo, rhi)
        first.set_cost(c)
        first.solve()
        M2 = M + 0.05 * rng.normal(size=M.shape) * (M != 0)
        if k % 4 == 0:  # a basic column of the first LP is zero in the second: its basis is singular there
            basic = first.head[first.head < M.shape[1]]
            if len(basic):
                M2[:, basic[0]] = 0.0
        status, fun = reference(c, M2, clo, chi, rlo, rhi)
        second = DenseLP(M2, clo, chi, rlo, rhi)
        second.set_cost(c)
        second.start_from(first.basis())
        assert second.solve() == status
        if status == OPTIMAL:
            assert abs(second.objective - fun) <= 1e-9 * (1 + abs(fun))
            check_solution(second, M2, clo, chi, rlo, rhi)


def test_iteration_limit_reported_and_frame_lp_falls_back_to_highs(jump) -> None:
    plan, i = jump, 10
    cols = plan.contacts.columns(i)
    N = plan.contacts.basis[i][:, cols]
    opts = OPTS.polygons
    args = (plan.A[i], plan.B[i], plan.C[i], N, plan.original.limits, opts)
    cost = np.concatenate([[0.3, 1.0, 0.0], np.zeros(len(cols))])
    ours = FrameLP(*args)
    ours.dense.max_iter = 1
    ours.set_residual_bound(plan.polygons.tolerance[i])
    x = ours.solve(cost)
    assert ours.dense.status == ITERATION_LIMIT and ours.n_fallback == 1
    highs = FrameLP(*args[:-1], opts.model_copy(update={"lp_solver": "highs"}))
    highs.set_residual_bound(plan.polygons.tolerance[i])
    xh = highs.solve(cost)
    np.testing.assert_allclose(x, xh)
    ours.dense.max_iter = 10_000  # the next solve restarts from the slack basis and succeeds
    x = ours.solve(cost)
    assert ours.dense.status == OPTIMAL and ours.n_fallback == 1
    assert abs(cost @ x - cost @ xh) <= 1e-9 * (1 + abs(cost @ xh))


@pytest.fixture(scope="module")
def jump():
    motion, _ = synthetic_jump(fps=30, stand=1.2, bend=0.6)
    return prepare(motion, OPTS)


def sweep_lps_agree(plan, frames, n_dir: int = 24) -> None:
    """Every frame's LP (root rows at the polygon's tolerance) in n_dir directions: ours = HiGHS."""
    opts = OPTS.polygons
    for i in frames:
        cols = plan.contacts.columns(i)
        N = plan.contacts.basis[i][:, cols]
        lps = [FrameLP(plan.A[i], plan.B[i], plan.C[i], N, plan.original.limits, opts.model_copy(update={"lp_solver": s}))
               for s in ("simplex", "highs")]
        for lp in lps:
            lp.set_residual_bound(plan.polygons.tolerance[i])
        for a in np.linspace(0, 2 * np.pi, n_dir, endpoint=False):
            cost = np.array([np.cos(a), np.sin(a), 0.0])
            x, xh = (lp.solve(cost) for lp in lps)
            assert (x is None) == (xh is None)
            if x is not None:
                assert abs(cost @ x[:3] - cost @ xh[:3]) <= 1e-9 * (1 + np.abs(xh[:2]).max())
        assert lps[0].n_fallback == 0


def polygons_agree(plan, weight: float, frames=None) -> None:
    """feasible_polygons by the simplex and by HiGHS: the same vertices, areas, residuals, centres."""
    sl = slice(None) if frames is None else frames
    contacts = replace(plan.contacts, active=plan.contacts.active[sl], basis=plan.contacts.basis[sl],
                       corner_active=None if plan.contacts.corner_active is None else plan.contacts.corner_active[sl])
    opts = OPTS.polygons
    out = [feasible_polygons(plan.A[sl], plan.B[sl], plan.C[sl], contacts, plan.original.limits, weight,
                             opts.model_copy(update={"lp_solver": s})) for s in ("simplex", "highs")]
    ours, ref = out
    assert ours.n_fallback == 0
    scale = 1e-7 * (opts.pdd_max + opts.speed_max**2)
    for v, vh in zip(ours.vertices, ref.vertices):
        assert v.shape == vh.shape
        if len(v):  # the same cycle (its start, on the angle seam about the mean, may differ)
            v = np.roll(v, -int(np.argmin(((v - vh[0]) ** 2).sum(axis=1))), axis=0)
        np.testing.assert_allclose(v, vh, atol=scale)
        assert abs(polygon_area(v) - polygon_area(vh)) <= 1e-7 * (1 + polygon_area(vh))
    np.testing.assert_allclose(ours.residual, ref.residual, rtol=1e-9, atol=1e-9 * weight)
    np.testing.assert_allclose(ours.center, ref.center, atol=scale)
    assert (ours.original_inside == ref.original_inside).all()
    assert (ours.infeasible == ref.infeasible).all()


def test_synthetic_jump_lps_and_polygons_equal_highs(jump) -> None:
    plan = jump
    sweep_lps_agree(plan, (5, 10, 45, 60, 80))  # standing, crouch, flight, landing
    polygons_agree(plan, plan.body.total_mass * float(np.linalg.norm(plan.body.default_gravity())))


@pytest.fixture(scope="module")
def cmu_jump(cmu_dir: Path):
    """16_06 frames 200-330 (counter-movement, take-off, flight, landing) with the default parameters."""
    path = cmu_dir / "asf_amc" / "16" / "16_06.amc"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    m = read_motion(path)
    m = replace(m, root_positions=m.root_positions[200:330], rotations=m.rotations[200:330])
    return prepare(m, RetimeParams())


def test_cmu_lps_and_polygons_equal_highs(cmu_jump) -> None:
    plan = cmu_jump
    assert plan.contacts.active.any(axis=1).mean() < 0.9  # a flight is in the window
    frames = np.linspace(0, len(plan.A) - 1, 12).astype(int)
    sweep_lps_agree(plan, frames)
    polygons_agree(plan, plan.body.total_mass * float(np.linalg.norm(plan.body.default_gravity())))
    assert plan.polygons.n_fallback == 0
