"""Physics-based motion retiming (design §8, MPS06 §3.3-3.6).

Pipeline (each stage a pure function, data passed in dataclasses):

1. ``original_forces`` — contact forces λ₀ and torques τ₀ of the original timing (p̈, ṗ²) = (0, 1)
   from an LP minimizing Σλ (root rows relaxed by the smallest residual that works); joint
   torque limits are τ₀'s peaks times a margin (MPS06 §4: limits observed from the motion).
2. ``feasible_polygons`` — per frame, the projection onto (p̈, ṗ²) of the polytope of MPS06
   Eqn. 13 by LPs maximizing a sweep of directions, refined where edges are long (MPS06 §3.3,
   Fig. 4), root rows bounded per row by the original timing's own residual. One HiGHS
   instance for all frames; only the objective changes between directions (primal simplex).
3. ``bake`` — λ at every vertex (from its LP), λ at the centre (≈ original timing) from a
   min-Σλ LP, barycentric interpolation in a fan triangulation around the centre (MPS06 §3.4,
   Fig. 5), so τ is affine in (p̈, ṗ²) per fan sector and β‖τ − τ'‖² is six coefficients per
   sector and frame (MPS06 §3.6), torques in units of their limits; the distance to the
   polygon is priced per frame by the root force a unit of (p̈, ṗ²) asks for.
4. ``optimize_timing`` — p(t) (output → source time) a clamped cubic B-spline per keytime
   segment with strictly increasing control points (positive increments by a softmax), so p is
   strictly monotone and meets endpoints and keytimes exactly; objective MPS06 Eqn. 14 sampled
   ≥ 4 times per source frame in one compiled pass (value and analytic gradient), L-BFGS-B.

Costs: polygons O(F · n_LP · LP), baking O(F · K · nv · nλ), one objective evaluation
O(S · K) with S samples and K polygon vertices (independent of the number of dofs).
"""

from __future__ import annotations

import ctypes
import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import highspy
import numpy as np
from motionweb.store.kinematics import sample_motion
from motionweb.store.motion import Motion, Skeleton
from motionweb.store.params import Params
from motionweb.tasks.contacts import Contacts, contacts_for
from motionweb.tasks.dynamics import BodyModel, DynamicsTerms, body_model_for, dynamics_terms, mass_factors
from numba import njit
from pydantic import Field
from scipy.interpolate import BSpline
from scipy.optimize import minimize


class RetimeParams(Params):
    """Physics-based retiming (design §8, MPS06 §3)."""

    body_model: Literal["cylinders", "table"] = "cylinders"
    total_mass: float | None = None
    friction: float = 0.5
    contact_height: float = 0.05
    contact_speed: float = 0.3
    torque_margin: float = 1.5
    samples_per_frame: int = 4
    #: MPS06 Eqn. 14 weights, both unit-free: α on the squared distance to the feasible polygon
    #: priced as unexplained root force in body weights, β on the mean squared torque deviation
    #: in units of the torque limits
    alpha: float = 1.0
    beta: float = 0.1
    objective: Literal["match", "minimize"] = "match"
    ground_height: float = 0.0
    #: per clip name: {foot joint: [[start_s, end_s], ...]} replacing detected contacts
    contact_intervals: dict[str, dict[str, list[tuple[float, float]]]] = Field(default_factory=dict)
    #: retime clips with no ground contact as pure flight instead of failing
    allow_flight_only: bool = False
    #: box of the (p̈, ṗ²) plane the feasible polygons are clipped to (MPS06 §3.4)
    speed_max: float = 6.0
    pdd_max: float = 40.0
    #: initial sweep directions and the LP budget per frame of the polygon sweep
    directions: int = 8
    max_lps: int = 16
    #: knots of the monotone timing spline p(t) per second of output
    knots_per_second: float = 8.0



N_ROOT = 6
INF = highspy.kHighsInf


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run the block with the OpenBLAS libraries of numpy and scipy on one thread, then restore.

    Retiming solves tiny problems (L-BFGS-B on ~10² parameters, 2×2 to 60×20 products), where
    OpenBLAS threads only add synchronization: on a loaded 2-core machine scipy's L-BFGS-B ran
    ~50× slower per iteration with its default thread count. The libraries are found among the
    loaded shared objects (``/proc/self/maps``); elsewhere the block runs unchanged.
    """
    libs = []
    try:
        with open("/proc/self/maps") as fh:
            paths = sorted({line.split()[-1] for line in fh if "openblas" in line.lower() and "/" in line})
    except OSError:
        paths = []
    for path in paths:
        lib = ctypes.CDLL(path)
        for suffix in ("64_", ""):
            get = getattr(lib, f"scipy_openblas_get_num_threads{suffix}", None)
            put = getattr(lib, f"scipy_openblas_set_num_threads{suffix}", None)
            if get is not None and put is not None:
                libs.append((put, int(get())))
                put(1)
                break
    try:
        yield
    finally:
        for put, n in libs:
            put(n)


class RetimeError(ValueError):
    """A retiming request that cannot be met (explained in the message)."""


@dataclass(frozen=True)
class PolygonOptions:
    """Sweep settings: box of (p̈, ṗ²), initial directions, LP budget (from :class:`RetimeParams`,
    see :func:`polygon_options`), refinement threshold."""

    pdd_max: float
    speed_max: float
    directions: int
    max_lps: int
    edge_tol: float = 0.5
    abs_tol: float = 1e-3  # root residual tolerance as a fraction of body weight
    infeasible_tol: float = 0.05  # residual (fraction of body weight) above which a frame is infeasible


def polygon_options(params: RetimeParams) -> PolygonOptions:
    """The polygon sweep's settings of a retiming's parameters."""
    return PolygonOptions(pdd_max=params.pdd_max, speed_max=params.speed_max, directions=params.directions,
                          max_lps=params.max_lps)


@dataclass(frozen=True, eq=False)
class OriginalForces:
    """Forces of the original timing (p̈, ṗ²) = (0, 1).

    Attributes:
        tau: (F, nv) generalized forces left for the actuators (root rows ≈ 0).
        lam: (F, nλ) contact magnitudes (zeros for feet not in contact).
        residual: (F,) root residual of the best contact forces (0: explained by contacts).
        limits: (nv,) symmetric joint torque limits (0 on root rows, unused there).
    """

    tau: np.ndarray
    lam: np.ndarray
    residual: np.ndarray
    limits: np.ndarray


@dataclass(frozen=True, eq=False)
class FeasiblePolygons:
    """Per-frame feasible regions in (p̈, ṗ²) with contact forces at vertices and centre.

    Attributes:
        vertices: per frame (K, 2), counter-clockwise.
        lambdas: per frame (K, nλ) contact magnitudes at each vertex.
        center: (F, 2) the fan centre (original timing (0, 1) when inside).
        center_lambda: (F, nλ) min-Σλ contact magnitudes at the centre.
        residual: (F,) smallest root residual (N or N·m) over the whole box; tolerance: (F, 6)
            the residual allowed on each root row in the polygon; infeasible: (F,) no timing has a residual
            below ``infeasible_tol`` of body weight (the contact model cannot explain the frame);
            original_inside: (F,) whether (0, 1) is in the polygon.
        n_lps: LPs solved; seconds, cpu_seconds: wall and CPU time of this process.
    """

    vertices: list[np.ndarray]
    lambdas: list[np.ndarray]
    center: np.ndarray
    center_lambda: np.ndarray
    residual: np.ndarray
    tolerance: np.ndarray
    infeasible: np.ndarray
    original_inside: np.ndarray
    n_lps: int
    seconds: float
    cpu_seconds: float


# --------------------------------------------------------------------------- LPs


class FrameLP:
    """One HiGHS model of MPS06 Eqn. 13 for a frame: columns [p̈, ṗ², s, λ], maximize.

    Rows: root rows −s ≤ A p̈ + B ṗ² − N λ + C ≤ s; joint rows |A p̈ + B ṗ² − N λ + C| ≤ limits
    (left out when ``limits`` is None: they would be free rows).
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, N: np.ndarray, limits: np.ndarray | None,
                 opts: PolygonOptions, highs: highspy.Highs | None = None):
        nv, nl = N.shape
        self.nl = nl
        h = highs or new_highs()  # passModel replaces the previous frame's model
        lp = highspy.HighsLp()
        ncol = 3 + nl
        nj = 0 if limits is None else nv - N_ROOT
        lim = np.zeros(0) if limits is None else limits[N_ROOT:]
        # dense constraint matrix: root upper (6), root lower (6), joints
        M = np.zeros((2 * N_ROOT + nj, ncol))
        for blk, sgn in ((0, -1.0), (N_ROOT, 1.0)):
            M[blk:blk + N_ROOT, 0] = A[:N_ROOT]
            M[blk:blk + N_ROOT, 1] = B[:N_ROOT]
            M[blk:blk + N_ROOT, 2] = sgn
            M[blk:blk + N_ROOT, 3:] = -N[:N_ROOT]
        if nj:
            M[2 * N_ROOT:, 0] = A[N_ROOT:]
            M[2 * N_ROOT:, 1] = B[N_ROOT:]
            M[2 * N_ROOT:, 3:] = -N[N_ROOT:]
        lo = np.concatenate([np.full(N_ROOT, -INF), -C[:N_ROOT], -lim - C[N_ROOT:N_ROOT + nj]])
        hi = np.concatenate([-C[:N_ROOT], np.full(N_ROOT, INF), lim - C[N_ROOT:N_ROOT + nj]])
        lo[~np.isfinite(lo)] = -INF
        hi[~np.isfinite(hi)] = INF
        lp.num_col_, lp.num_row_ = ncol, M.shape[0]
        lp.col_cost_ = np.zeros(ncol)
        lp.col_lower_ = np.concatenate([[-opts.pdd_max, 0.0, 0.0], np.zeros(nl)])
        lp.col_upper_ = np.concatenate([[opts.pdd_max, opts.speed_max**2, INF], np.full(nl, INF)])
        lp.row_lower_, lp.row_upper_ = lo, hi
        nz = M != 0
        lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
        lp.a_matrix_.start_ = np.concatenate([[0], np.cumsum(nz.sum(axis=0))]).astype(np.int32)
        rows, cols = np.nonzero(nz.T)
        lp.a_matrix_.index_ = cols.astype(np.int32)
        lp.a_matrix_.value_ = M.T[rows, cols]
        lp.sense_ = highspy.ObjSense.kMaximize
        h.passModel(lp)
        self.h = h
        self.opts = opts
        self._all = np.arange(ncol, dtype=np.int32)
        self.n_solved = 0

    def solve(self, cost: np.ndarray) -> np.ndarray | None:
        """Maximize ``cost · x`` (costs of the columns past ``len(cost)`` unchanged); x or None if infeasible."""
        self.h.changeColsCost(len(cost), self._all[:len(cost)], np.asarray(cost, dtype=float))
        self.h.run()
        self.n_solved += 1
        if self.h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
            return None
        return np.asarray(self.h.getSolution().col_value)

    def set_residual_bound(self, upper: float | np.ndarray) -> None:
        """Bound the root residual: |row i| ≤ upper (a scalar, or one bound per root row).

        Per-row bounds scale the residual column's coefficients (row i: |r_i| ≤ w_i s, s ≤ max).
        """
        up = np.broadcast_to(np.asarray(upper, dtype=float), (N_ROOT,))
        top = max(float(up.max()), 1e-300)
        for r in range(N_ROOT):
            self.h.changeCoeff(r, 2, -up[r] / top)
            self.h.changeCoeff(N_ROOT + r, 2, up[r] / top)
        self.h.changeColBounds(2, 0.0, top)

    def fix_timing(self, x: tuple[float, float] | None) -> None:
        o = self.opts
        if x is None:
            self.h.changeColBounds(0, -o.pdd_max, o.pdd_max)
            self.h.changeColBounds(1, 0.0, o.speed_max**2)
        else:
            self.h.changeColBounds(0, x[0], x[0])
            self.h.changeColBounds(1, x[1], x[1])


def new_highs() -> highspy.Highs:
    """A HiGHS instance set up for the tiny, often re-solved LPs of MPS06 §3.3 (reused across frames)."""
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("presolve", "off")  # tiny LPs re-solved from the previous basis
    h.setOptionValue("threads", 1)  # HiGHS's worker pool only adds synchronization here (7x on 2 busy cores)
    # a new direction changes costs only: the basis stays primal feasible, so primal simplex
    # re-optimizes from it (1.7x fewer ms per direction than dual simplex)
    h.setOptionValue("simplex_strategy", 4)
    return h


def _lp_cost(nl: int, pdd: float = 0.0, pd2: float = 0.0, s: float = 0.0, lam: float = 0.0) -> np.ndarray:
    return np.concatenate([[pdd, pd2, s], np.full(nl, lam)])


def original_forces(A: np.ndarray, B: np.ndarray, C: np.ndarray, contacts: Contacts, margin: float = 1.5,
                    weight: float = 1.0, opts: PolygonOptions | None = None) -> OriginalForces:
    """Contact forces and torques of the original timing, and torque limits (MPS06 §3.2, §4).

    Per frame one LP at (p̈, ṗ²) = (0, 1) without torque limits minimizing W·s + Σλ (W large:
    the root residual s first). Limits: ``margin`` × the peak |τ₀| of each joint's dofs, at least
    2 % of the largest. O(F) LPs.
    """
    opts = opts or polygon_options(RetimeParams())
    f, nv = A.shape
    nl_all = contacts.basis.shape[2]
    tau = np.zeros((f, nv))
    lam = np.zeros((f, nl_all))
    res = np.zeros(f)
    big = 1e3 / max(weight, 1e-9)  # W·s dominates Σλ
    highs = new_highs()
    for i in range(f):
        cols = contacts.columns(i)
        N = contacts.basis[i][:, cols]
        lp = FrameLP(A[i], B[i], C[i], N, None, opts, highs)
        lp.fix_timing((0.0, 1.0))
        x = lp.solve(_lp_cost(len(cols), s=-big * weight, lam=-1.0))
        if x is None:  # cannot happen with a free residual; keep zeros
            continue
        res[i] = x[2]
        lam[i, cols] = x[3:]
        tau[i] = B[i] + C[i] - N @ x[3:]
    peak = np.abs(tau[:, N_ROOT:]).max(axis=0) if f else np.zeros(nv - N_ROOT)
    # one limit per 3-dof joint (isotropic), from the peaks of its components
    peak3 = peak.reshape(-1, 3).max(axis=1).repeat(3) if peak.size % 3 == 0 else peak
    lim = margin * np.maximum(peak3, 0.02 * max(peak3.max(initial=0.0), 1e-6))
    limits = np.concatenate([np.zeros(N_ROOT), lim])
    return OriginalForces(tau=tau, lam=lam, residual=res, limits=limits)


def _dedupe(points: list[tuple[float, np.ndarray, np.ndarray]], tol: float) -> list[tuple[float, np.ndarray, np.ndarray]]:
    out: list[tuple[float, np.ndarray, np.ndarray]] = []
    for p in points:
        if not out or math.dist(p[1], out[-1][1]) > tol:
            out.append(p)
    if len(out) > 1 and math.dist(out[0][1], out[-1][1]) <= tol:
        out.pop()
    return out


def sweep_polygon(lp: FrameLP, opts: PolygonOptions) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (K, 2) counter-clockwise and their λ (K, nλ) by direction sweep + refinement.

    Directions start straight down (−ṗ²) and turn counter-clockwise (MPS06 Fig. 4); an edge
    longer than ``edge_tol`` is probed along its outward normal, and the new vertex is kept when
    it lies beyond the edge. The polygon found is inside the true projection. O(max_lps) LPs.
    """
    nl = lp.nl
    pts: list[tuple[float, np.ndarray, np.ndarray]] = []
    angles = -np.pi / 2 + 2 * np.pi * np.arange(opts.directions) / opts.directions
    for a in angles:  # λ costs are 0 after the residual LP: change the (p̈, ṗ², s) costs only
        x = lp.solve(np.array([np.cos(a), np.sin(a), 0.0]))
        if x is None:
            return np.zeros((0, 2)), np.zeros((0, nl))
        pts.append((float(a), x[:2].copy(), x[3:].copy()))
    tol = 1e-7 * (opts.pdd_max + opts.speed_max**2)
    pts = _dedupe(pts, tol)
    budget = opts.max_lps - opts.directions
    changed = True
    while changed and budget > 0 and len(pts) > 1:
        changed = False
        new = []
        for k in range(len(pts)):
            _a0, v0, _ = pts[k]
            _a1, v1, _ = pts[(k + 1) % len(pts)]
            ex, ey = float(v1[0] - v0[0]), float(v1[1] - v0[1])
            length = math.hypot(ex, ey)
            if length <= opts.edge_tol or budget <= 0:
                continue
            n = np.array([ey / length, -ex / length, 0.0])  # outward unit normal of a counter-clockwise edge
            an = math.atan2(n[1], n[0])
            x = lp.solve(n)
            budget -= 1
            if x is not None and n[:2] @ (x[:2] - v0) > 1e-6 * (1 + np.abs(v0).max()):
                new.append((an, x[:2].copy(), x[3:].copy()))
                changed = True
        if new:
            allp = pts + new
            c = np.mean([p[1] for p in allp], axis=0)
            allp.sort(key=lambda p: np.arctan2(p[1][1] - c[1], p[1][0] - c[0]))
            pts = _dedupe(allp, tol)
    verts = np.array([p[1] for p in pts])
    lams = np.array([p[2] for p in pts]).reshape(len(pts), nl)
    if len(verts) >= 3:
        c = verts.mean(axis=0)
        order = np.argsort(np.arctan2(verts[:, 1] - c[1], verts[:, 0] - c[0]))
        verts, lams = verts[order], lams[order]
    return verts, lams


def polygon_area(v: np.ndarray) -> float:
    if len(v) < 3:
        return 0.0
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def closest_point(v: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The point of convex polygon ``v`` (K, 2, counter-clockwise) closest to ``x`` (2,)."""
    if len(v) == 1:
        return v[0].copy()
    e = np.roll(v, -1, axis=0) - v
    if len(v) >= 3 and polygon_area(v) > 1e-12:
        cross = e[:, 0] * (x[1] - v[:, 1]) - e[:, 1] * (x[0] - v[:, 0])
        if np.all(cross >= 0):
            return x.copy()
    ee = np.maximum((e * e).sum(axis=1), 1e-300)
    t = np.clip(((x - v) * e).sum(axis=1) / ee, 0, 1)
    proj = v + t[:, None] * e
    return proj[np.argmin(((proj - x) ** 2).sum(axis=1))]


def feasible_polygons(A: np.ndarray, B: np.ndarray, C: np.ndarray, contacts: Contacts, limits: np.ndarray,
                      weight: float, opts: PolygonOptions | None = None,
                      original_residual: np.ndarray | None = None) -> FeasiblePolygons:
    """Feasible (p̈, ṗ²) polygons of every frame (MPS06 §3.3) with λ at vertices and centre (§3.4).

    Mocap is never exactly consistent with the body model: the original timing leaves a root
    residual ρ (``original_residual``, (F, 6), under the original physics) that its own timing
    must be allowed. Each root row i gets its own bound |ρ_i| + ``abs_tol``·weight, so that a large
    inconsistency in one row (e.g. angular momentum in flight) does not loosen the others (the
    vertical force that makes a flight ballistic). Where no timing meets those bounds (changed
    physics), every row gets max(1.05 s*, max|ρ|) + ``abs_tol``·weight with s* the smallest
    uniform residual over the box (an LP; 0 when contacts explain the frame). Then the
    direction sweep, then
    the centre (0, 1) — or, when outside, its closest polygon point pulled 5 % toward the
    vertex mean — and its min-Σλ forces. Flight frames (no contact) give a thin polygon around the
    ballistic segment or point. Cost O(F · max_lps) LPs of (3 + nλ) columns.
    """
    opts = opts or polygon_options(RetimeParams())
    t0, c0 = time.perf_counter(), time.process_time()
    f = A.shape[0]
    nl_all = contacts.basis.shape[2]
    verts, lams = [], []
    center = np.zeros((f, 2))
    clam = np.zeros((f, nl_all))
    res = np.zeros(f)
    tol = np.zeros((f, N_ROOT))
    rho = np.zeros((f, N_ROOT)) if original_residual is None else np.abs(original_residual)
    inside = np.zeros(f, bool)
    n_lps = 0
    highs = new_highs()
    for i in range(f):
        cols = contacts.columns(i)
        N = contacts.basis[i][:, cols]
        lp = FrameLP(A[i], B[i], C[i], N, limits, opts, highs)
        x = lp.solve(_lp_cost(len(cols), s=-1.0))
        res[i] = x[2] if x is not None else np.inf
        tol[i] = rho[i] + opts.abs_tol * weight
        lp.set_residual_bound(tol[i])
        v, lv = sweep_polygon(lp, opts)
        if not len(v):
            tol[i] = max(1.05 * res[i], rho[i].max()) + opts.abs_tol * weight
            lp.set_residual_bound(tol[i])
            v, lv = sweep_polygon(lp, opts)
        full = np.zeros((len(v), nl_all))
        full[:, cols] = lv
        o = np.array([0.0, 1.0])
        cp = closest_point(v, o) if len(v) else o
        inside[i] = bool(len(v) and np.allclose(cp, o))
        c = cp if inside[i] else cp + 0.05 * (v.mean(axis=0) - cp)
        lp.fix_timing((float(c[0]), float(c[1])))
        xc = lp.solve(_lp_cost(len(cols), lam=-1.0))
        if xc is None:  # numerically on the boundary: use the nearest vertex
            k = int(np.argmin(((v - c) ** 2).sum(axis=1)))
            c, xl = v[k], lv[k]
        else:
            xl = xc[3:]
        center[i] = c
        clam[i, cols] = xl
        verts.append(v)
        lams.append(full)
        n_lps += lp.n_solved
    infeasible = res > opts.infeasible_tol * weight
    return FeasiblePolygons(vertices=verts, lambdas=lams, center=center, center_lambda=clam, residual=res,
                            tolerance=tol, infeasible=infeasible, original_inside=inside, n_lps=n_lps,
                            seconds=time.perf_counter() - t0, cpu_seconds=time.process_time() - c0)


def shortest_duration(polys: FeasiblePolygons, fps: float) -> float:
    """A lower bound on the duration of any timing that stays inside every polygon (MPS06 §3.3).

    Each frame's polygon bounds ṗ² from above; playing every source interval at the largest ṗ
    its two end frames allow (trapezoid rule on 1/ṗ_max) ignores the coupling through p̈, so
    no feasible timing is shorter (``inf`` when some frame allows no motion). A requested
    duration below it must leave the polygons somewhere. O(Σ K).
    """
    top = np.array([v[:, 1].max() if len(v) else 0.0 for v in polys.vertices])
    if np.any(top <= 0):
        return float("inf")
    inv = 1.0 / np.sqrt(top)
    return float(0.5 * (inv[1:] + inv[:-1]).sum() / fps)


# --------------------------------------------------------------------------- baking


@dataclass(frozen=True, eq=False)
class BakedObjective:
    """Per-frame piecewise-quadratic objective in x = (p̈, ṗ²) (MPS06 §3.6), padded to K sectors.

    Attributes:
        verts: (F, K, 2) polygon vertices (padded by repeating the last); count: (F,) vertices
            before the padding; inv_len2: (F, K) 1 / squared length of edge k → k+1 (0 for
            degenerate edges); solid: (F,) area > 0.
        center: (F, 2); theta0: (F,) angle of the first vertex about the centre; theta: (F, K)
            vertex angles relative to theta0 in [0, 2π) (padding 10).
        coef: (F, K, 6) torque-term coefficients of p̈², p̈ṗ², ṗ⁴, p̈, ṗ², 1 per sector (β included).
        lam_center: (F, nλ); lam_slope: (F, K, nλ, 2): λ(x) = λ_c + Λ_k (x − c) in sector k.
        alpha: (F,) per-frame weight of the squared distance to the polygon (α times the frame's
            root force per unit of (p̈, ṗ²), squared, see :func:`bake`); beta: torque weight.
    """

    verts: np.ndarray
    count: np.ndarray
    inv_len2: np.ndarray
    solid: np.ndarray
    center: np.ndarray
    theta0: np.ndarray
    theta: np.ndarray
    coef: np.ndarray
    lam_center: np.ndarray
    lam_slope: np.ndarray
    alpha: np.ndarray
    beta: float

    @property
    def n_frames(self) -> int:
        return self.verts.shape[0]


def bake(polys: FeasiblePolygons, A: np.ndarray, B: np.ndarray, C: np.ndarray, contacts: Contacts,
         tau_target: np.ndarray, alpha: float, beta: float, tau_scale: np.ndarray) -> BakedObjective:
    """Fan-triangulated contact model and six coefficients per sector (MPS06 §3.4, §3.6).

    The torque term of MPS06 Eqn. 14 is made dimensionless: each generalized force is divided by
    ``tau_scale`` (its torque limit; body weight on the root rows) and the sum by nv, so β‖τ − τ'‖²
    is β times the mean squared deviation in units of the limits, and α, β compare unit-free
    quantities whatever the body's size. With D = diag(1/tau_scale)/√nv and τ(x) − τ' =
    a_k p̈ + b_k ṗ² + e_k in sector k (a, b, e scaled by D), the term is β(a·a p̈² + 2a·b p̈ṗ² +
    b·b ṗ⁴ + 2a·e p̈ + 2b·e ṗ² + e·e).

    The feasibility term is priced in force as well: a step δ = [p̈, ṗ²] − c out of frame i's
    polygon asks the unactuated root for [A, B]_root δ that no contact can supply, so the frame's
    weight is α σ_i² with σ_i = ‖[A_i, B_i]_root / tau_scale_root‖₂ (body weights per unit of
    (p̈, ṗ²)). A flight frame, whose whole weight rides on ṗ², pays ~1 per unit; a still frame
    (q' = q'' = 0) only the floor of 0.1 body weight per unit that keeps it inside the box
    (``speed_max``, ``pdd_max``) — so the squared-distance penalty of MPS06 Eqn. 14 no longer
    trades a ballistic flight against a standing pose one to one. O(F · K · nv · nλ).
    """
    f = A.shape[0]
    K = max(max((len(v) for v in polys.vertices), default=1), 1)
    nl = contacts.basis.shape[2]
    verts = np.zeros((f, K, 2))
    count = np.ones(f, np.int64)
    theta = np.full((f, K), 10.0)
    theta0 = np.zeros(f)
    coef = np.zeros((f, K, 6))
    slope = np.zeros((f, K, nl, 2))
    solid = np.zeros(f, bool)
    d = 1.0 / (np.asarray(tau_scale, dtype=float) * np.sqrt(A.shape[1]))
    for i in range(f):
        v, lv, c = polys.vertices[i], polys.lambdas[i], polys.center[i]
        k = len(v)
        if k == 0:
            v, lv, k = c[None], polys.center_lambda[i][None], 1
        verts[i, :k] = v
        verts[i, k:] = v[-1]
        count[i] = k
        solid[i] = polygon_area(v) > 1e-12
        ang = np.arctan2(v[:, 1] - c[1], v[:, 0] - c[0])
        theta0[i] = ang[0]
        theta[i, :k] = np.mod(ang - ang[0], 2 * np.pi)
        theta[i, 0] = 0.0
        lc = polys.center_lambda[i]
        if k >= 3:  # sector s spans centre, v_s, v_{s+1}: λ(x) = λ_c + [λ_s − λ_c, λ_{s+1} − λ_c] D_s⁻¹ (x − c)
            r0, r1 = v - c, np.roll(v, -1, axis=0) - c
            det = r0[:, 0] * r1[:, 1] - r1[:, 0] * r0[:, 1]
            ok = np.abs(det) > 1e-12
            inv = np.stack([np.stack([r1[:, 1], -r1[:, 0]], 1), np.stack([-r0[:, 1], r0[:, 0]], 1)], 1)
            inv /= np.where(ok, det, 1.0)[:, None, None]
            dl = np.stack([lv - lc, np.roll(lv, -1, axis=0) - lc], axis=2)  # (k, nλ, 2)
            slope[i, :k] = np.where(ok[:, None, None], dl @ inv, 0.0)
            slope[i, k:] = slope[i, k - 1]
        N = contacts.basis[i]
        L = slope[i]  # (K, nλ, 2)
        a = d[:, None] * (A[i][:, None] - N @ L[:, :, 0].T)  # (nv, K)
        b = d[:, None] * (B[i][:, None] - N @ L[:, :, 1].T)
        e = d[:, None] * ((C[i] - tau_target[i] - N @ lc)[:, None] + N @ (L @ c).T)
        coef[i] = beta * np.stack([(a * a).sum(0), 2 * (a * b).sum(0), (b * b).sum(0), 2 * (a * e).sum(0),
                                   2 * (b * e).sum(0), (e * e).sum(0)], axis=1)
    edge = np.zeros_like(verts)
    for i in range(f):
        k = count[i]
        edge[i, :k] = np.roll(verts[i, :k], -1, axis=0) - verts[i, :k]
    len2 = (edge * edge).sum(axis=2)
    inv_len2 = np.divide(1.0, len2, out=np.zeros_like(len2), where=len2 > 0)
    root = np.stack([A[:, :N_ROOT], B[:, :N_ROOT]], axis=2) / np.asarray(tau_scale, float)[None, :N_ROOT, None]
    sigma = np.linalg.norm(root, ord=2, axis=(1, 2))
    return BakedObjective(verts=verts, count=count, inv_len2=inv_len2, solid=solid, center=polys.center.copy(), theta0=theta0, theta=theta,
                          coef=coef, lam_center=polys.center_lambda.copy(), lam_slope=slope,
                          alpha=alpha * (sigma**2 + 0.1**2), beta=beta)


def _sector(obj: BakedObjective, fr: np.ndarray, x: np.ndarray) -> np.ndarray:
    c = obj.center[fr]
    ang = np.mod(np.arctan2(x[:, 1] - c[:, 1], x[:, 0] - c[:, 0]) - obj.theta0[fr], 2 * np.pi)
    return np.maximum((obj.theta[fr] <= ang[:, None]).sum(axis=1) - 1, 0)


def _frame_terms(obj: BakedObjective, fr: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-sample value (S,), gradient (S, 2) and closest feasible point (S, 2) of one frame's terms."""
    s = _sector(obj, fr, x)
    k = obj.coef[fr, s]  # (S, 6)
    x0, x1 = x[:, 0], x[:, 1]
    val = k[:, 0] * x0 * x0 + k[:, 1] * x0 * x1 + k[:, 2] * x1 * x1 + k[:, 3] * x0 + k[:, 4] * x1 + k[:, 5]
    grad = np.stack([2 * k[:, 0] * x0 + k[:, 1] * x1 + k[:, 3], k[:, 1] * x0 + 2 * k[:, 2] * x1 + k[:, 4]], axis=1)
    # distance to the polygon
    v = obj.verts[fr]  # (S, K, 2)
    e = np.roll(v, -1, axis=1) - v
    rel = x[:, None, :] - v
    cross = e[..., 0] * rel[..., 1] - e[..., 1] * rel[..., 0]
    inside = obj.solid[fr] & np.all(cross >= 0, axis=1)
    ee = np.maximum((e * e).sum(axis=2), 1e-300)
    t = np.clip((rel * e).sum(axis=2) / ee, 0.0, 1.0)
    proj = v + t[..., None] * e
    d2 = ((x[:, None, :] - proj) ** 2).sum(axis=2)
    j = np.argmin(d2, axis=1)
    cp = proj[np.arange(len(fr)), j]
    cp[inside] = x[inside]
    diff = x - cp
    val = val + obj.alpha[fr] * (diff * diff).sum(axis=1)
    grad = grad + 2 * obj.alpha[fr][:, None] * diff
    return val, grad, cp


def evaluate_numpy(obj: BakedObjective, u: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference (numpy) version of :func:`evaluate`."""
    f = obj.n_frames
    u = np.clip(u, 0.0, f - 1.0)
    i0 = np.minimum(np.floor(u).astype(np.int64), max(f - 2, 0))
    i1 = np.minimum(i0 + 1, f - 1)
    w = u - i0
    v0, g0, _ = _frame_terms(obj, i0, x)
    v1, g1, _ = _frame_terms(obj, i1, x)
    val = (1 - w) * v0 + w * v1
    gx = (1 - w)[:, None] * g0 + w[:, None] * g1
    return val, gx, v1 - v0


@njit(cache=True, inline="always")
def _frame_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, fr, x0, x1):  # pragma: no cover
    """Value and d/dx of frame ``fr``'s terms at x = (x0, x1): O(count[fr]), padding skipped."""
    K = count[fr]
    ang = np.arctan2(x1 - center[fr, 1], x0 - center[fr, 0]) - theta0[fr]
    two_pi = 2.0 * np.pi
    ang = ang - two_pi * np.floor(ang / two_pi)
    s = 0
    while s + 1 < K and theta[fr, s + 1] <= ang:  # vertex angles increase
        s += 1
    c = coef[fr, s]
    val = c[0] * x0 * x0 + c[1] * x0 * x1 + c[2] * x1 * x1 + c[3] * x0 + c[4] * x1 + c[5]
    g0 = 2 * c[0] * x0 + c[1] * x1 + c[3]
    g1 = c[1] * x0 + 2 * c[2] * x1 + c[4]
    best, b0, b1 = 1e300, x0, x1
    if solid[fr]:
        # the closest point of a convex polygon lies on an edge whose half-plane x violates (at a
        # vertex, one of its two edges' half-planes is violated), so project on those only
        inside = True
        for k in range(K):
            kn = k + 1 if k + 1 < K else 0
            ax, ay = verts[fr, k, 0], verts[fr, k, 1]
            if (verts[fr, kn, 0] - ax) * (x1 - ay) - (verts[fr, kn, 1] - ay) * (x0 - ax) < 0:
                inside = False
                d, px, py = _edge_point(verts, inv_len2, fr, k, K, x0, x1)
                if d < best:
                    best, b0, b1 = d, px, py
        if inside:
            return val, g0, g1
    else:  # a segment or a point (flight frames): every edge
        for k in range(K):
            d, px, py = _edge_point(verts, inv_len2, fr, k, K, x0, x1)
            if d < best:
                best, b0, b1 = d, px, py
    return val + alpha[fr] * best, g0 + 2 * alpha[fr] * (x0 - b0), g1 + 2 * alpha[fr] * (x1 - b1)


@njit(cache=True, inline="always")
def _edge_point(verts, inv_len2, fr, k, K, x0, x1):  # pragma: no cover - numba
    """Squared distance from x to edge k → k+1 of frame ``fr`` and the closest point on it."""
    ax, ay = verts[fr, k, 0], verts[fr, k, 1]
    kn = k + 1 if k + 1 < K else 0
    ex, ey = verts[fr, kn, 0] - ax, verts[fr, kn, 1] - ay
    t = min(max(((x0 - ax) * ex + (x1 - ay) * ey) * inv_len2[fr, k], 0.0), 1.0)
    px, py = ax + t * ex, ay + t * ey
    return (x0 - px) ** 2 + (x1 - py) ** 2, px, py


@njit(cache=True, inline="always")
def _sample_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, u, x0, x1):  # pragma: no cover
    """Density at source frame ``u`` (linear blend of its two frames): value, d/dx0, d/dx1, d/du."""
    f = verts.shape[0]
    ui = min(max(u, 0.0), f - 1.0)
    i0 = min(int(np.floor(ui)), max(f - 2, 0))
    i1 = min(i0 + 1, f - 1)
    w = ui - i0
    va, ga0, ga1 = _frame_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, i0, x0, x1)
    vb, gb0, gb1 = _frame_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, i1, x0, x1)
    return (1 - w) * va + w * vb, (1 - w) * ga0 + w * gb0, (1 - w) * ga1 + w * gb1, vb - va


@njit(cache=True)
def _evaluate_kernel(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, u, x):  # pragma: no cover
    n = u.shape[0]
    val = np.empty(n)
    gx = np.empty((n, 2))
    gu = np.empty(n)
    for i in range(n):
        val[i], gx[i, 0], gx[i, 1], gu[i] = _sample_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha,
                                                          u[i], x[i, 0], x[i, 1])
    return val, gx, gu


@njit(cache=True)
def _objective_kernel(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, ctrl, w, c, fps, dt
                      ):  # pragma: no cover
    """MPS06 Eqn. 14 summed over samples and its gradient in the control points, in one pass.

    Sample s depends on control points ``ctrl[s]`` (4) with weights ``w[:, s]`` for p, ṗ, p̈
    (MPS06 §3.6: four control points per sample, so the gradient is linear in the samples).
    """
    n = ctrl.shape[0]
    grad = np.zeros(c.shape[0])
    total = 0.0
    for s in range(n):
        p = 0.0
        pd = 0.0
        pdd = 0.0
        for j in range(4):
            cj = c[ctrl[s, j]]
            p += w[0, s, j] * cj
            pd += w[1, s, j] * cj
            pdd += w[2, s, j] * cj
        v, g0, g1, gu = _sample_value(verts, count, inv_len2, solid, center, theta0, theta, coef, alpha, p * fps, pdd, pd * pd)
        total += v
        g_p = gu * fps * dt
        g_pd = g1 * 2.0 * pd * dt
        g_pdd = g0 * dt
        for j in range(4):
            grad[ctrl[s, j]] += w[0, s, j] * g_p + w[1, s, j] * g_pd + w[2, s, j] * g_pdd
    return total * dt, grad


def evaluate(obj: BakedObjective, u: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Objective density at source frames ``u`` (S,) and x = (p̈, ṗ²) (S, 2), blending frames linearly.

    Returns value (S,), d/dx (S, 2) and d/du (S,). O(S · K), compiled (numba); the numpy
    reference is :func:`evaluate_numpy`.
    """
    return _evaluate_kernel(obj.verts, obj.count, obj.inv_len2, obj.solid, obj.center, obj.theta0, obj.theta, obj.coef,
                            obj.alpha, np.ascontiguousarray(u, dtype=np.float64),
                            np.ascontiguousarray(x, dtype=np.float64))


def contact_lambda(obj: BakedObjective, frame: int, x: np.ndarray) -> np.ndarray:
    """λ at (p̈, ṗ²) = ``x`` from the fan model of ``frame`` (clipped at 0 outside the polygon)."""
    s = int(_sector(obj, np.array([frame]), x[None])[0])
    lam = obj.lam_center[frame] + obj.lam_slope[frame, s] @ (x - obj.center[frame])
    return np.maximum(lam, 0.0)


# --------------------------------------------------------------------------- timing spline


@dataclass(frozen=True, eq=False)
class TimingSpline:
    """p(t): output seconds → source seconds, clamped cubic B-splines between keytimes.

    Segment k spans output [out[k], out[k+1]] and source [src[k], src[k+1]]; its control points
    are src[k] + cumsum of positive increments (softmax of free parameters times the source span),
    so p is strictly increasing and passes exactly through every keytime.
    """

    out: np.ndarray
    src: np.ndarray
    knots: list[np.ndarray]
    n_ctrl: list[int]

    @classmethod
    def make(cls, out: np.ndarray, src: np.ndarray, knots_per_second: float) -> TimingSpline:
        knots, n_ctrl = [], []
        for k in range(len(out) - 1):
            n_int = max(2, round((src[k + 1] - src[k]) * knots_per_second))
            inner = np.linspace(out[k], out[k + 1], n_int + 1)
            knots.append(np.concatenate([[out[k]] * 3, inner, [out[k + 1]] * 3]))
            n_ctrl.append(n_int + 3)
        return cls(out=np.asarray(out, float), src=np.asarray(src, float), knots=knots, n_ctrl=n_ctrl)

    @property
    def n_params(self) -> int:
        return sum(n - 1 for n in self.n_ctrl)

    def controls(self, z: np.ndarray) -> np.ndarray:
        """The concatenated control points of all segments for parameters ``z``."""
        return _controls(np.asarray(z, float), np.asarray(self.n_ctrl, np.int64), self.src)

    def design(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The 4 control points (S, 4; indices into the concatenated controls) each output time
        depends on and their weights (3, S, 4) for p, ṗ, p̈ (the nonzeros of the design matrices)."""
        t = np.asarray(t, float)
        ctrl = np.zeros((len(t), 4), np.int64)
        w = np.zeros((3, len(t), 4))
        offset = 0
        for k, n in enumerate(self.n_ctrl):
            last = k == len(self.n_ctrl) - 1
            sel = np.flatnonzero((t >= self.out[k]) & ((t <= self.out[k + 1]) if last else (t < self.out[k + 1])))
            tt = t[sel]
            first = np.clip(np.searchsorted(self.knots[k], tt, side="right") - 1, 3, n - 1) - 3
            cols = first[:, None] + np.arange(4)
            spl = BSpline(self.knots[k], np.eye(n), 3, extrapolate=False)
            for d in range(3):
                dense = np.nan_to_num((spl.derivative(d) if d else spl)(tt))
                w[d, sel] = np.take_along_axis(dense, cols, axis=1)
            ctrl[sel] = offset + cols
            offset += n
        return ctrl, w

    def evaluate(self, z: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """p, ṗ, p̈ at output times ``t``."""
        ctrl, w = self.design(t)
        c = self.controls(z)[ctrl]
        return (w[0] * c).sum(axis=1), (w[1] * c).sum(axis=1), (w[2] * c).sum(axis=1)


@njit(cache=True)
def _controls(z, n_ctrl, src):  # pragma: no cover - numba
    """Segment k's controls: src[k] + cumsum of softmax(z_k) · (src[k+1] − src[k]), last = src[k+1]."""
    c = np.empty(n_ctrl.sum())
    o = 0
    oc = 0
    for k in range(n_ctrl.shape[0]):
        n = n_ctrl[k]
        zk = z[o:o + n - 1]
        e = np.exp(zk - zk.max())
        inc = (src[k + 1] - src[k]) / e.sum()
        c[oc] = src[k]
        for i in range(n - 1):
            c[oc + i + 1] = c[oc + i] + inc * e[i]
        c[oc + n - 1] = src[k + 1]
        o += n - 1
        oc += n
    return c


@njit(cache=True)
def _chain(z, grad, n_ctrl, src):  # pragma: no cover - numba
    """Gradient in z from the gradient in the controls of :func:`_controls`."""
    out = np.empty(z.shape[0])
    o = 0
    oc = 0
    for k in range(n_ctrl.shape[0]):
        n = n_ctrl[k]
        zk = z[o:o + n - 1]
        e = np.exp(zk - zk.max())
        s = e / e.sum()
        g_inc = np.empty(n - 1)
        acc = 0.0
        for i in range(n - 2, -1, -1):  # c_i depends on inc_j for j < i
            acc += grad[oc + i + 1]
            g_inc[i] = acc * (src[k + 1] - src[k])
        sg = (s * g_inc).sum()
        out[o:o + n - 1] = s * g_inc - s * sg
        o += n - 1
        oc += n
    return out


@dataclass(frozen=True, eq=False)
class RetimeResult:
    """A retiming: the spline, its parameters, and p, ṗ, p̈ at the output frames.

    Attributes:
        spline, z: the timing curve and its parameters.
        t: (T,) output frame times; p, pd, pdd: (T,) source time, ṗ, p̈ there.
        objective: final objective; n_samples: samples used; iterations: L-BFGS iterations;
        seconds: optimization wall time; converged: optimizer success flag.
    """

    spline: TimingSpline
    z: np.ndarray
    t: np.ndarray
    p: np.ndarray
    pd: np.ndarray
    pdd: np.ndarray
    objective: float
    n_samples: int
    iterations: int
    seconds: float
    converged: bool
    message: str = ""
    history: list[float] = field(default_factory=list)


def check_keytimes(src_duration: float, duration: float, keytimes: list[tuple[float, float]],
                   speed_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Validated (out, src) knot arrays including both endpoints (RetimeError explains problems)."""
    if not duration > 0:
        raise RetimeError(f"the output duration must be positive, got {duration}")
    kt = sorted(keytimes)
    src = np.array([0.0] + [s for s, _ in kt] + [src_duration])
    out = np.array([0.0] + [o for _, o in kt] + [duration])
    for s, o in kt:
        if not (0 < s < src_duration):
            raise RetimeError(f"keytime source {s:g} s is outside the clip's (0, {src_duration:g}) s")
        if not (0 < o < duration):
            raise RetimeError(f"keytime output {o:g} s is outside the output's (0, {duration:g}) s")
    if np.any(np.diff(src) <= 0) or np.any(np.diff(out) <= 0):
        raise RetimeError("keytimes must increase in both source and output time (p(t) is monotone)")
    ratio = np.diff(src) / np.diff(out)
    if ratio.max() > speed_max:
        k = int(np.argmax(ratio))
        raise RetimeError(f"output span {out[k]:g}-{out[k + 1]:g} s would need {ratio[k]:.2f}x speed; "
                          f"more than the {speed_max:g}x allowed (speed_max)")
    return out, src


def optimize_timing(obj: BakedObjective, fps: float, src_duration: float, duration: float,
                    keytimes: list[tuple[float, float]] | None = None, *, samples_per_frame: int = 4,
                    knots_per_second: float = 12.0, speed_max: float = 6.0, max_iter: int = 2000
                    ) -> RetimeResult:
    """Minimize MPS06 Eqn. 14 over monotone p(t) with fixed endpoints and keytimes (MPS06 §3.5-3.6).

    Samples at midpoints of S equal output intervals with S ≥ ``samples_per_frame`` per source
    frame at the fastest playback; resampled (finer) when the optimum plays faster. Analytic
    gradient through the B-spline design matrices; L-BFGS-B. Cost per evaluation O(S · K).
    """
    t0 = time.perf_counter()
    out, src = check_keytimes(src_duration, duration, keytimes or [], speed_max)
    spline = TimingSpline.make(out, src, knots_per_second)
    z = np.zeros(spline.n_params)
    history: list[float] = []
    n_frames_src = src_duration * fps
    ratio = float((np.diff(src) / np.diff(out)).max())
    n_s = int(np.ceil(samples_per_frame * n_frames_src * max(ratio, 1.0) * 1.25))
    res = None
    iters = 0
    with single_threaded_blas():
        for _attempt in range(3):
            fun = objective_function(obj, spline, fps, duration, n_s)
            res = minimize(fun, z, jac=True, method="L-BFGS-B",
                           options={"maxiter": max_iter, "maxcor": 10, "ftol": 1e-10, "gtol": 1e-8})
            z = res.x
            iters += int(res.nit)
            history.append(float(res.fun))
            edges = np.linspace(0.0, duration, n_s + 1)
            _, pd_s, _ = spline.evaluate(z, 0.5 * (edges[1:] + edges[:-1]))
            step = pd_s.max() * duration / n_s * fps  # source frames between samples
            if step <= 1.0 / samples_per_frame + 1e-9:
                break
            n_s = int(np.ceil(n_s * step * samples_per_frame * 1.1))
    n_out = round(duration * fps) + 1
    t = np.minimum(np.arange(n_out) / fps, duration)
    p, pd, pdd = spline.evaluate(z, t)
    return RetimeResult(spline=spline, z=z, t=t, p=p, pd=pd, pdd=pdd, objective=float(res.fun), n_samples=n_s,
                        iterations=iters, seconds=time.perf_counter() - t0, converged=bool(res.success),
                        message=str(res.message), history=history)


def objective_function(obj: BakedObjective, spline: TimingSpline, fps: float, duration: float, n_s: int
                       ) -> Callable[[np.ndarray], tuple[float, np.ndarray]]:
    """J(z) of MPS06 Eqn. 14 on ``n_s`` midpoint samples of [0, duration]: (value, gradient).

    One compiled pass over the samples (:func:`_objective_kernel`) plus O(n_params) for the
    softmax/cumsum parameterization; cost O(S · K), no Python per sample.
    """
    edges = np.linspace(0.0, duration, n_s + 1)
    ctrl, w = spline.design(0.5 * (edges[1:] + edges[:-1]))
    dt = duration / n_s
    args = (obj.verts, obj.count, obj.inv_len2, obj.solid, obj.center, obj.theta0, obj.theta, obj.coef, obj.alpha, ctrl, w)

    n_ctrl = np.asarray(spline.n_ctrl, np.int64)

    def fun(z: np.ndarray) -> tuple[float, np.ndarray]:
        zz = np.asarray(z, float)
        val, grad = _objective_kernel(*args, _controls(zz, n_ctrl, spline.src), float(fps), dt)
        return float(val), _chain(zz, grad, n_ctrl, spline.src)

    return fun


# --------------------------------------------------------------------------- end to end


@dataclass(frozen=True, eq=False)
class RetimePlan:
    """Everything precomputed for one clip and one physics setting (reused across timings).

    ``A, B, C`` are the recombined path-dynamics terms under the new gravity / masses; ``original``
    the forces of the unmodified clip (targets of the 'match' objective and torque limits).
    """

    motion: Motion
    body: BodyModel
    terms: DynamicsTerms
    contacts: Contacts
    gravity: np.ndarray
    factors: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    original: OriginalForces
    polygons: FeasiblePolygons
    baked: BakedObjective
    timings: dict[str, float]


def humanoid_foot_corners(humanoid: Any, skeleton: Skeleton) -> dict[int, np.ndarray]:
    """Sole rectangles ``{joint: (4, 3)}`` (joint frame, m) of a humanoid's foot boxes."""
    out = {}
    for name, box in getattr(humanoid, "foot_boxes", {}).items():
        hx, hy, hz = np.asarray(box.size, float) / 2
        local = np.array([[hx, -hy, hz], [hx, -hy, -hz], [-hx, -hy, -hz], [-hx, -hy, hz]])
        w, v = float(box.rotation[0]), np.asarray(box.rotation[1:], float)
        rot = local + 2 * w * np.cross(v, local) + 2 * np.cross(v, np.cross(v, local))
        out[skeleton.index(name)] = np.asarray(box.origin, float) + rot
    return out


def prepare(motion: Motion, opts: RetimeParams | None = None, *, up_axis: str = "y", gravity: np.ndarray | None = None,
            mass: dict[str, float] | None = None, humanoid: Any | None = None,
            contact_intervals: dict[str, list[tuple[float, float]]] | None = None) -> RetimePlan:
    """Dynamics, contacts, original forces, feasible polygons and the baked objective (MPS06 §3.1-3.6).

    Raises ``RetimeError`` when no foot touches the ground (unless ``allow_flight_only``), and
    ``ValueError`` for an unknown unit or an unknown joint in ``mass``.
    """
    opts = opts or RetimeParams()
    tm: dict[str, float] = {}
    up = "xyz".index(up_axis)
    t = time.perf_counter()
    body = body_model_for(motion, kind=opts.body_model, total_mass=opts.total_mass, up_axis=up,
                          humanoid=humanoid)
    factors = mass_factors(body, mass or {})
    terms = dynamics_terms(body, motion)
    tm["dynamics"] = time.perf_counter() - t
    t = time.perf_counter()
    corners = humanoid_foot_corners(humanoid, motion.skeleton) if humanoid is not None else None
    contacts = contacts_for(body, terms.q, motion.fps, mu=opts.friction, height=opts.contact_height,
                            speed=opts.contact_speed, ground=opts.ground_height, intervals=contact_intervals,
                            foot_corners=corners)
    tm["contacts"] = time.perf_counter() - t
    if not contacts.active.any() and not opts.allow_flight_only:
        feet = ", ".join(f.name for f in contacts.feet)
        low = contacts.corner_positions[..., up].min() - opts.ground_height
        raise RetimeError(
            f"no ground contact detected in {motion.name or 'the clip'}: feet ({feet}) never come within "
            f"{opts.contact_height} m of the ground at y={opts.ground_height} (lowest {low:.3f} m above) while "
            f"slower than {opts.contact_speed} m/s. Give contact intervals (retime.contact_intervals in the "
            "config), adjust contact_height/ground_height, or set retime.allow_flight_only: true to retime it "
            "as pure flight (ballistic).")
    g0 = body.default_gravity()
    g = g0 if gravity is None else np.asarray(gravity, dtype=float)
    weight = body.total_mass * float(np.linalg.norm(g0))
    popts = polygon_options(opts)
    t = time.perf_counter()
    A0, B0, C0 = terms.combine(g0)
    original = original_forces(A0, B0, C0, contacts, opts.torque_margin, weight, popts)
    tm["original_forces"] = time.perf_counter() - t
    A, B, C = terms.combine(g, factors)
    polys = feasible_polygons(A, B, C, contacts, original.limits, weight, popts, original_residual=original.tau[:, :N_ROOT])
    tm["polygons"] = polys.seconds
    t = time.perf_counter()
    target = original.tau if opts.objective == "match" else np.zeros_like(original.tau)
    if opts.objective not in ("match", "minimize"):
        raise ValueError(f"unknown objective {opts.objective!r} (match, minimize)")
    tau_scale = np.where(np.arange(len(original.limits)) < N_ROOT, weight, original.limits)
    baked = bake(polys, A, B, C, contacts, target, opts.alpha, opts.beta, tau_scale)
    tm["bake"] = time.perf_counter() - t
    return RetimePlan(motion=motion, body=body, terms=terms, contacts=contacts, gravity=g, factors=factors, A=A, B=B,
                      C=C, original=original, polygons=polys, baked=baked, timings=tm)


def retime_plan(plan: RetimePlan, duration: float, keytimes: list[tuple[float, float]] | None = None,
                opts: RetimeParams | None = None) -> tuple[Motion, RetimeResult]:
    """Optimize the timing of a prepared clip and sample the retimed motion at the source fps."""
    opts = opts or RetimeParams()
    m = plan.motion
    res = optimize_timing(plan.baked, m.fps, m.duration, duration, keytimes, samples_per_frame=opts.samples_per_frame,
                          knots_per_second=opts.knots_per_second, speed_max=opts.speed_max)
    out = replace(sample_motion(m, res.p * m.fps), name=f"{m.name}_retimed", source=None, content_hash="")
    return out, res


def phase_times(contacts: Contacts, res: RetimeResult, fps: float, n: int = 4000) -> dict[str, tuple[float, float]]:
    """Seconds spent in each contact phase ('flight', '<foot> only', 'double'): (source, output).

    The phase of a source frame is its set of feet in contact; output seconds integrate the
    phase of p(t) over ``n`` output samples — the retiming's shift between stances (MPS06 Fig.
    10-11: a leg favoured under sideways gravity or a heavy femur). O(n + F).
    """
    names = [f.name for f in contacts.feet]

    def label(row: np.ndarray) -> str:
        k = int(row.sum())
        return "flight" if k == 0 else "double" if k > 1 else f"{names[int(np.argmax(row))]} only"

    labels = [label(row) for row in contacts.active]
    f = len(labels)
    tt = (np.arange(n) + 0.5) * res.t[-1] / n
    p, _, _ = res.spline.evaluate(res.z, tt)
    frames = np.clip(np.rint(p * fps).astype(int), 0, f - 1)
    out: dict[str, tuple[float, float]] = {}
    for name in dict.fromkeys(labels):
        src = sum(lab == name for lab in labels) / fps
        dur = float(np.isin(frames, [i for i, lab in enumerate(labels) if lab == name]).sum() * res.t[-1] / n)
        out[name] = (src, dur)
    return out


def flight_intervals(active: np.ndarray, fps: float) -> list[tuple[float, float]]:
    """Source-time intervals (s) with no foot in contact, between the last and first contact frames."""
    none = ~active.any(axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], none.astype(np.int8), [0]])))
    return [((s - 1) / fps if s > 0 else 0.0, e / fps if e < len(none) else (len(none) - 1) / fps)
            for s, e in zip(edges[::2], edges[1::2], strict=True)]


def output_time(res: RetimeResult, src_time: float) -> float:
    """The output time at which p(t) = ``src_time`` (bisection on the monotone spline)."""
    lo, hi = 0.0, float(res.spline.out[-1])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if res.spline.evaluate(res.z, np.array([mid]))[0][0] < src_time:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def report(plan: RetimePlan, res: RetimeResult) -> dict[str, Any]:
    """JSON-able report: per output frame timing, torques, contact forces, feasibility; summary.

    Infeasible frames are listed, never hidden: source frames the contact model cannot explain
    (at any timing) and output frames whose (p̈, ṗ²) lies outside its frame's polygon.
    """
    m, obj, cont = plan.motion, plan.baked, plan.contacts
    edges = pyramid_edges(cont, plan.body.up_axis)  # (3, 4)
    frames = []
    outside = []
    for k in range(len(res.t)):
        x = np.array([res.pdd[k], res.pd[k] ** 2])
        i = int(np.clip(np.rint(res.p[k] * m.fps), 0, m.n_frames - 1))
        cp = closest_point(plan.polygons.vertices[i], x) if len(plan.polygons.vertices[i]) else obj.center[i]
        dist = float(np.linalg.norm(x - cp))
        lam = contact_lambda(obj, i, x)
        tau = plan.A[i] * x[0] + plan.B[i] * x[1] + plan.C[i] - cont.basis[i] @ lam
        forces = {}
        for fi, foot in enumerate(cont.feet):
            if cont.active[i, fi]:
                lf = lam[fi * 16:(fi + 1) * 16].reshape(4, 4)
                forces[foot.name] = (edges @ lf.sum(axis=0)).round(4).tolist()
        feasible = dist <= 1e-3 * (1 + np.abs(x).max())
        if not feasible:
            outside.append(k)
        frames.append({"t": round(float(res.t[k]), 6), "source_time": round(float(res.p[k]), 6),
                       "speed": round(float(res.pd[k]), 6), "accel": round(float(res.pdd[k]), 6),
                       "source_frame": i, "feasible": bool(feasible), "distance": round(dist, 6),
                       "torques": tau[N_ROOT:].round(4).tolist(), "root_residual": tau[:N_ROOT].round(4).tolist(),
                       "contact_forces": forces})
    flights = []
    for s0, s1 in flight_intervals(cont.active, m.fps):
        if s0 <= 0.0 or s1 >= m.duration:
            continue
        o0, o1 = output_time(res, s0), output_time(res, s1)
        flights.append({"source": [s0, s1], "output": [o0, o1], "source_duration": s1 - s0,
                        "output_duration": o1 - o0, "ratio": (o1 - o0) / (s1 - s0)})
    polys = plan.polygons
    return {
        "clip": m.name, "frames_in": m.n_frames, "frames_out": len(res.t), "fps": m.fps,
        "duration_in": m.duration, "duration_out": float(res.t[-1]),
        "gravity": plan.gravity.tolist(), "mass_factors": dict(zip(plan.body.skeleton.names,
                                                                   plan.factors.round(6).tolist(), strict=True)),
        "total_mass_kg": plan.body.total_mass,
        "objective": float(res.objective), "converged": res.converged, "iterations": res.iterations,
        "contacts": cont.intervals(m.fps), "contacts_detected": cont.detected, "flights": flights,
        "phase_seconds": {k: {"source": s, "output": o} for k, (s, o) in phase_times(cont, res, m.fps).items()},
        "shortest_feasible_duration": shortest_duration(polys, m.fps),
        "infeasible_source_frames": np.flatnonzero(polys.infeasible).tolist(),
        "original_timing_outside_polygon": np.flatnonzero(~polys.original_inside).tolist(),
        "infeasible_output_frames": outside,
        "root_residual_source": polys.residual.round(4).tolist(),
        "torque_limits": plan.original.limits[N_ROOT:].round(4).tolist(),
        "timings_s": {**plan.timings, "optimize": res.seconds},
        "frames": frames,
    }


def pyramid_edges(cont: Contacts, up_axis: int) -> np.ndarray:
    from motionweb.tasks.contacts import pyramid
    up = np.zeros(3)
    up[up_axis] = 1.0
    return pyramid(up, cont.friction)
