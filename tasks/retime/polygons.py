"""Feasible (p̈, ṗ²) polygons of every frame by small LPs (design §8, MPS06 §3.2-3.4).

* :func:`original_forces` — contact forces λ₀ and torques τ₀ of the original timing (p̈, ṗ²) = (0, 1)
  from an LP minimizing Σλ (root rows relaxed by the smallest residual that works); joint
  torque limits are τ₀'s peaks times a margin (MPS06 §4: limits observed from the motion).
* :func:`feasible_polygons` — per frame, the projection onto (p̈, ṗ²) of the polytope of MPS06
  Eqn. 13 by LPs maximizing a sweep of directions, refined where edges are long (MPS06 §3.3,
  Fig. 4), root rows bounded per row by the original timing's own residual. Only the
  objective changes between directions: the dense bounded simplex of :mod:`.simplex` re-solves
  from the previous direction's basis (a frame's first LP from the previous frame's), a few
  pivots each, HiGHS taking over where it reports trouble (``PolygonParams.lp_solver = "highs"``:
  HiGHS throughout, the reference). Joint rows no contact force enters are 2-D bands in (p̈, ṗ²), cut from the swept polygon
  exactly (:class:`HalfPlanes`) rather than carried through every LP.

Cost: O(F · n_LP) LPs of (3 + nλ) columns and 12 + (joint rows a contact reaches) rows, plus
O(K · rows) per frame for the bands.
"""

from __future__ import annotations

import ctypes
import math
import os
import sys
import threading
import time
from dataclasses import dataclass

import highspy
import numpy as np
from motionweb.tasks.params.retime import PolygonParams
from motionweb.tasks.retime.contacts import Contacts
from motionweb.tasks.retime.simplex import INFEASIBLE, OPTIMAL, UNBOUNDED, DenseLP
from motionweb.store.numba_cache import njit

N_ROOT = 6
INF = highspy.kHighsInf
#: the sweep's directions are turned off the axes by this angle (rad): straight down, up, left and
#: right would each meet a whole edge of the (p̈, ṗ²) box, and which point of it an LP solver returns
#: is arbitrary; turned, the optimum is the edge's end, whatever the solver
TIE_TURN = 0.05
_ROOT_TWICE = np.tile(np.arange(N_ROOT), 2)  # the root rows' two sides


#: the sweep's own constants (not parameters): an edge of the polygon longer than this (in the
#: (p̈, ṗ²) plane) is probed along its normal; a frame whose smallest root residual is above
#: INFEASIBLE_TOL of body weight is one the contact model cannot explain; the clip's own
#: unexplained root wrench may scale in [0, CARRIED_MAX]
EDGE_TOL = 0.5
INFEASIBLE_TOL = 0.05
CARRIED_MAX = 2.0


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
            below :data:`INFEASIBLE_TOL` of body weight (the contact model cannot explain the frame);
            original_inside: (F,) whether (0, 1) is in the polygon.
        n_lps: LPs solved; n_fallback: of them, simplex solves handed to HiGHS (iteration limit,
            numerical trouble); seconds, cpu_seconds: wall and CPU time of this process.
        box: (max |p̈|, max ṗ²) of the box the polygons are clipped to (``PolygonParams``
            pdd_max, speed_max²).
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
    box: tuple[float, float]
    n_fallback: int = 0


# --------------------------------------------------------------------------- LPs


class FrameLP:
    """One LP of MPS06 Eqn. 13 for a frame: columns [p̈, ṗ², s, λ], maximize.

    Rows: root rows −s ≤ A p̈ + B ṗ² − N λ + C ≤ s; joint rows |A p̈ + B ṗ² − N λ + C| ≤ limits
    (left out when ``limits`` is None: they would be free rows), only those of the mask ``rows``
    (nv − 6,) when given. Solved by the dense warm-started simplex of :mod:`.simplex`
    (``opts.lp_solver == "simplex"``, falling back to HiGHS on an iteration limit or numerical
    trouble) or by HiGHS (``"highs"``, one instance ``highs`` reused across frames).
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, N: np.ndarray, limits: np.ndarray | None,
                 opts: PolygonParams, highs: highspy.Highs | None = None, lam_upper: np.ndarray | None = None,
                 rows: np.ndarray | None = None):
        nv, nl = N.shape
        self.nl = nl
        ncol = 3 + nl
        keep = np.arange(N_ROOT, nv) if rows is None else N_ROOT + np.flatnonzero(rows)  # joint rows kept
        if limits is None:
            keep = keep[:0]
        lim = np.zeros(0) if limits is None else limits[keep]
        # dense constraint matrix: root upper (6), root lower (6), joints
        r = np.concatenate([_ROOT_TWICE, keep])
        M = np.empty((len(r), ncol))
        M[:, 0] = A[r]
        M[:, 1] = B[r]
        M[:, 2] = 0.0
        M[:N_ROOT, 2] = -1.0
        M[N_ROOT:2 * N_ROOT, 2] = 1.0
        M[:, 3:] = -N[r]
        lo = -C[r]
        hi = lo.copy()
        lo[:N_ROOT] = -INF
        hi[N_ROOT:2 * N_ROOT] = INF
        lo[2 * N_ROOT:] -= lim
        hi[2 * N_ROOT:] += lim
        lo[~np.isfinite(lo)] = -INF
        hi[~np.isfinite(hi)] = INF
        self.M, self.row_lo, self.row_hi = M, lo, hi
        self.col_lo = np.concatenate([[-opts.pdd_max, 0.0, 0.0], np.zeros(nl)])
        self.col_hi = np.concatenate([[opts.pdd_max, opts.speed_max**2, INF],
                                      np.full(nl, INF) if lam_upper is None else lam_upper])
        self.cost = np.zeros(ncol)
        self.opts = opts
        self._all = np.arange(ncol, dtype=np.int32)
        self.n_solved = 0
        self.n_fallback = 0  # simplex solves handed to HiGHS
        self.highs = highs
        if opts.lp_solver not in ("simplex", "highs"):
            raise ValueError(f"unknown LP solver {opts.lp_solver!r} (simplex or highs)")
        self.dense = DenseLP(M, self.col_lo, self.col_hi, lo, hi, maximize=True) if opts.lp_solver == "simplex" else None
        if self.dense is None:
            self._pass_model()
        else:
            self.cost = self.dense.cost  # one cost vector for both

    def basis(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The simplex's current basis (None with HiGHS), to start an LP of the same shape from."""
        return None if self.dense is None else self.dense.basis()

    def start_from(self, basis: tuple[np.ndarray, np.ndarray] | None) -> None:
        """Start the next solve from ``basis`` (:meth:`basis` of a like LP: the previous frame's with the
        same contacts and rows); ignored with HiGHS, when None or when the shapes differ."""
        if self.dense is not None and basis is not None:
            self.dense.start_from(basis)

    def _pass_model(self) -> None:
        """The LP as it stands into the HiGHS instance (passModel replaces the previous frame's)."""
        h = self.highs = self.highs or new_highs()
        lp = highspy.HighsLp()
        M = self.M
        lp.num_col_, lp.num_row_ = M.shape[1], M.shape[0]
        lp.col_cost_ = self.cost.copy()
        lp.col_lower_, lp.col_upper_ = self.col_lo, self.col_hi
        lp.row_lower_, lp.row_upper_ = self.row_lo, self.row_hi
        nz = M != 0
        lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
        lp.a_matrix_.start_ = np.concatenate([[0], np.cumsum(nz.sum(axis=0))]).astype(np.int32)
        rows, cols = np.nonzero(nz.T)
        lp.a_matrix_.index_ = cols.astype(np.int32)
        lp.a_matrix_.value_ = M.T[rows, cols]
        lp.sense_ = highspy.ObjSense.kMaximize
        h.passModel(lp)

    def _highs_solve(self) -> np.ndarray | None:
        self.highs.run()
        if self.highs.getModelStatus() != highspy.HighsModelStatus.kOptimal:
            return None
        return np.asarray(self.highs.getSolution().col_value)

    def solve(self, cost: np.ndarray) -> np.ndarray | None:
        """Maximize ``cost · x`` (costs of the columns past ``len(cost)`` unchanged); x or None if infeasible."""
        k = len(cost)
        self.cost[:k] = cost
        self.n_solved += 1
        if self.dense is None:
            self.highs.changeColsCost(k, self._all[:k], np.asarray(cost, dtype=float))
            return self._highs_solve()
        st = self.dense.solve()
        if st == OPTIMAL:
            return self.dense.solution.copy()
        if st in (INFEASIBLE, UNBOUNDED):
            return None
        return self._fallback()

    def _fallback(self) -> np.ndarray | None:
        """The LP as it stands by HiGHS (the simplex hit its iteration limit or numerical trouble)."""
        self.n_fallback += 1
        self._pass_model()
        return self._highs_solve()

    def solve_many(self, costs: np.ndarray, stop_at_none: bool = False) -> list[np.ndarray | None]:
        """:meth:`solve` for each row of ``costs`` (B, k) in turn, each from the previous basis (the
        simplex runs them in one compiled call); stops after the first None when ``stop_at_none``."""
        if self.dense is None:
            out: list[np.ndarray | None] = []
            for c in costs:
                out.append(self.solve(c))
                if stop_at_none and out[-1] is None:
                    break
            return out
        X, status = self.dense.solve_sequence(costs, stop_at_none)
        self.n_solved += len(X)
        out = [x if st == OPTIMAL else None for x, st in zip(X, status)]
        if len(status) and status[-1] not in (OPTIMAL, INFEASIBLE, UNBOUNDED):
            out[-1] = self._fallback()
            if len(out) < len(costs) and not (stop_at_none and out[-1] is None):
                out += self.solve_many(costs[len(out):], stop_at_none)
        return out

    def _set_col_bounds(self, j: int, lo: float, hi: float) -> None:
        self.col_lo[j], self.col_hi[j] = lo, hi
        if self.dense is None:
            self.highs.changeColBounds(j, lo, hi)
        else:
            self.dense.set_col_bounds(j, lo, hi)

    def set_residual_bound(self, upper: float | np.ndarray) -> None:
        """Bound the root residual: |row i| ≤ upper (a scalar, or one bound per root row).

        Per-row bounds scale the residual column's coefficients (row i: |r_i| ≤ w_i s, s ≤ max).
        """
        up = np.broadcast_to(np.asarray(upper, dtype=float), (N_ROOT,))
        top = max(float(up.max()), 1e-300)
        for r in range(N_ROOT):
            for row, v in ((r, -up[r] / top), (N_ROOT + r, up[r] / top)):
                if self.M[row, 2] != v:
                    self.M[row, 2] = v
                    if self.dense is None:
                        self.highs.changeCoeff(row, 2, v)
                    else:
                        self.dense.set_coeff(row, 2, v)
        self._set_col_bounds(2, 0.0, top)

    def fix_timing(self, x: tuple[float, float] | None) -> None:
        o = self.opts
        if x is None:
            self._set_col_bounds(0, -o.pdd_max, o.pdd_max)
            self._set_col_bounds(1, 0.0, o.speed_max**2)
        else:
            self._set_col_bounds(0, x[0], x[0])
            self._set_col_bounds(1, x[1], x[1])


_BANNER_LOCK = threading.Lock()
_banner_shown = False


def _quiet_highs() -> highspy.Highs:
    """A ``highspy.Highs`` whose construction prints nothing (MPS06 §3.3's LPs are ours to report).

    HiGHS prints its banner ("Running HiGHS 1.x … Copyright") from the C++ constructor of the
    first instance a process makes, before any option (``output_flag``, ``log_to_console``) can be
    set; later instances print nothing. That first one is made with file descriptor 1 pointed at
    /dev/null (C stdio flushed before it is restored), under a lock."""
    global _banner_shown
    if _banner_shown:
        return highspy.Highs()
    with _BANNER_LOCK:
        if _banner_shown:
            return highspy.Highs()
        sys.stdout.flush()
        try:
            saved, null = os.dup(1), os.open(os.devnull, os.O_WRONLY)
        except OSError:  # no stdout to guard
            return highspy.Highs()
        try:
            os.dup2(null, 1)
            h = highspy.Highs()
            ctypes.CDLL(None).fflush(None)
        finally:
            os.dup2(saved, 1)
            os.close(saved)
            os.close(null)
        _banner_shown = True
        return h


def new_highs() -> highspy.Highs:
    """A HiGHS instance set up for the tiny, often re-solved LPs of MPS06 §3.3 (reused across frames)."""
    h = _quiet_highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("log_to_console", False)
    h.setOptionValue("presolve", "off")  # tiny LPs re-solved from the previous basis
    h.setOptionValue("threads", 1)  # HiGHS's worker pool only adds synchronization here (7x on 2 busy cores)
    # a new direction changes costs only: the basis stays primal feasible, so primal simplex
    # re-optimizes from it (1.7x fewer ms per direction than dual simplex)
    h.setOptionValue("simplex_strategy", 4)
    return h


def _lp_cost(nl: int, pdd: float = 0.0, pd2: float = 0.0, s: float = 0.0, lam: float = 0.0) -> np.ndarray:
    return np.concatenate([[pdd, pd2, s], np.full(nl, lam)])


def original_forces(A: np.ndarray, B: np.ndarray, C: np.ndarray, contacts: Contacts, margin: float,
                    weight: float, opts: PolygonParams) -> OriginalForces:
    """Contact forces and torques of the original timing, and torque limits (MPS06 §3.2, §4).

    Per frame one LP at (p̈, ṗ²) = (0, 1) without torque limits minimizing W·s + Σλ (W large:
    the root residual s first). Limits: ``margin`` × the peak |τ₀| of each joint's dofs, at least
    2 % of the largest. O(F) LPs.
    """
    f, nv = A.shape
    nl_all = contacts.basis.shape[2]
    tau = np.zeros((f, nv))
    lam = np.zeros((f, nl_all))
    res = np.zeros(f)
    big = 1e3 / max(weight, 1e-9)  # W·s dominates Σλ
    highs = new_highs()
    prev = None
    for i in range(f):
        cols = contacts.columns(i)
        N = contacts.basis[i][:, cols]
        lp = FrameLP(A[i], B[i], C[i], N, None, opts, highs)
        lp.fix_timing((0.0, 1.0))
        lp.start_from(prev)  # the previous frame's optimal basis (when its contacts were the same)
        x = lp.solve(_lp_cost(len(cols), s=-big * weight, lam=-1.0))
        prev = lp.basis()
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


def _dedupe(points: list[tuple[float, float, np.ndarray]], tol: float) -> list[tuple[float, float, np.ndarray]]:
    """Points (x, y, λ) without those within ``tol`` of the last kept one (and of the first, cyclically)."""
    out: list[tuple[float, float, np.ndarray]] = []
    for p in points:
        if not out or math.hypot(p[0] - out[-1][0], p[1] - out[-1][1]) > tol:
            out.append(p)
    if len(out) > 1 and math.hypot(out[0][0] - out[-1][0], out[0][1] - out[-1][1]) <= tol:
        out.pop()
    return out


def _points(xs: list[np.ndarray | None]) -> list[tuple[float, float, np.ndarray]]:
    return [(float(x[0]), float(x[1]), x[3:]) for x in xs if x is not None]


def sweep_polygon(lp: FrameLP, opts: PolygonParams) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (K, 2) counter-clockwise and their λ (K, nλ) by direction sweep + refinement.

    Directions start straight down (−ṗ², turned by ``TIE_TURN``) and turn counter-clockwise (MPS06
    Fig. 4), solved in one :meth:`FrameLP.solve_many`; then in rounds, every edge longer than
    :data:`EDGE_TOL` is probed along its outward normal (one ``solve_many`` per round), and the new
    vertex is kept when it lies beyond the edge. The polygon found is inside the true projection.
    O(max_lps) LPs.
    """
    nl = lp.nl
    angles = -np.pi / 2 + TIE_TURN + 2 * np.pi * np.arange(opts.directions) / opts.directions
    # λ costs are 0 after the residual LP: change the (p̈, ṗ², s) costs only
    xs = lp.solve_many(np.stack([np.cos(angles), np.sin(angles), np.zeros(len(angles))], axis=1), stop_at_none=True)
    if len(xs) < opts.directions or xs[-1] is None:
        return np.zeros((0, 2)), np.zeros((0, nl))
    tol = 1e-7 * (opts.pdd_max + opts.speed_max**2)
    pts = _dedupe(_points(xs), tol)
    budget = opts.max_lps - opts.directions
    changed = True
    while changed and budget > 0 and len(pts) > 1:
        changed = False
        probes: list[tuple[float, float, float, float]] = []  # edge start, outward unit normal
        for k in range(len(pts)):
            x0, y0, _ = pts[k]
            x1, y1, _ = pts[(k + 1) % len(pts)]
            ex, ey = x1 - x0, y1 - y0
            length = math.hypot(ex, ey)
            if length <= EDGE_TOL:
                continue
            if len(probes) == budget:
                break
            probes.append((x0, y0, ey / length, -ex / length))  # the normal of a counter-clockwise edge
        if not probes:
            break
        budget -= len(probes)
        xs = lp.solve_many(np.array([(nx, ny, 0.0) for _, _, nx, ny in probes]))
        new = [x for (x0, y0, nx, ny), x in zip(probes, xs)
               if x is not None and nx * (x[0] - x0) + ny * (x[1] - y0) > 1e-6 * (1 + max(abs(x0), abs(y0)))]
        if new:
            changed = True
            allp = pts + _points(new)
            cx = sum(p[0] for p in allp) / len(allp)
            cy = sum(p[1] for p in allp) / len(allp)
            allp.sort(key=lambda p: math.atan2(p[1] - cy, p[0] - cx))
            pts = _dedupe(allp, tol)
    verts = np.array([(p[0], p[1]) for p in pts]).reshape(len(pts), 2)
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
    return 0.5 * float(x[:-1] @ y[1:] - x[1:] @ y[:-1] + x[-1] * y[0] - x[0] * y[-1])


def closest_point(v: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The point of convex polygon ``v`` (K, 2, counter-clockwise) closest to ``x`` (2,)."""
    if len(v) == 1:
        return v[0].copy()
    e = np.concatenate([v[1:], v[:1]]) - v
    if len(v) >= 3 and polygon_area(v) > 1e-12:
        cross = e[:, 0] * (x[1] - v[:, 1]) - e[:, 1] * (x[0] - v[:, 0])
        if np.all(cross >= 0):
            return x.copy()
    ee = np.maximum((e * e).sum(axis=1), 1e-300)
    t = np.clip(((x - v) * e).sum(axis=1) / ee, 0, 1)
    proj = v + t[:, None] * e
    return proj[np.argmin(((proj - x) ** 2).sum(axis=1))]


#: a timing meets its target when at most this share of its output frames lies outside their polygon
MET_OUTSIDE_FRACTION = 0.1


def timing_distances(polys: FeasiblePolygons, fps: float, p: np.ndarray, pd: np.ndarray,
                     pdd: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far each output frame of a timing lies from its feasible polygon (MPS06 §3.3).

    ``p`` (T,) source seconds, ``pd``, ``pdd`` (T,) ṗ and p̈: the frame is checked against its
    nearest source frame's polygon (against the fan centre where that polygon is empty) and is
    inside within 1e-3 · (1 + max |(p̈, ṗ²)|). Returns (T,) source frames, distances, inside.
    O(T · K), one compiled pass (:func:`_frame_distances`; ``tests/naive.py`` holds the loop over
    :func:`closest_point` it equals).
    """
    n = len(polys.vertices)
    frames = np.clip(np.rint(np.asarray(p) * fps).astype(np.int64), 0, n - 1)
    sizes = np.fromiter((len(v) for v in polys.vertices), np.int64, n)
    offsets = np.zeros(n + 1, np.int64)
    np.cumsum(sizes, out=offsets[1:])
    flat = (np.concatenate([np.asarray(v, np.float64).reshape(-1, 2) for v in polys.vertices])
            if offsets[-1] else np.zeros((0, 2)))
    pd = np.asarray(pd, np.float64)
    pdd = np.asarray(pdd, np.float64)
    dist = _frame_distances(flat, offsets, np.asarray(polys.center, np.float64), frames, pdd, pd)
    scale = 1 + np.maximum(np.abs(pdd), pd ** 2)
    return frames, dist, dist <= 1e-3 * scale


@njit(cache=True, nogil=True)
def _frame_distances(flat: np.ndarray, offsets: np.ndarray, center: np.ndarray, frames: np.ndarray,
                     pdd: np.ndarray, pd: np.ndarray) -> np.ndarray:
    """(T,) distance of each (p̈_k, ṗ_k²) to the polygon of source frame ``frames[k]``: polygon i
    is ``flat[offsets[i]:offsets[i + 1]]`` (K_i, 2), counter-clockwise; an empty one stands for
    its fan centre ``center[i]`` (F, 2). The same arithmetic as :func:`closest_point`; the
    distance is √(dx² + dy²) in plain arithmetic.

    Bounds: reads flat rows offsets[i] .. offsets[i + 1] − 1 and center[i] for i = frames[k];
    :func:`timing_distances` builds ``offsets`` (F + 1,) from the polygons and clips frames to
    0 .. F − 1; writes out[k] for k < T only."""
    out = np.empty(len(frames))
    for k in range(len(frames)):
        i = frames[k]
        x0 = pdd[k]
        x1 = pd[k] ** 2
        a = offsets[i]
        b = offsets[i + 1]
        nk = b - a
        if nk == 0:
            c0, c1 = center[i, 0], center[i, 1]
        elif nk == 1:
            c0, c1 = flat[a, 0], flat[a, 1]
        else:
            inside = False
            if nk >= 3:
                s1 = 0.0
                s2 = 0.0
                for j in range(nk - 1):
                    s1 += flat[a + j, 0] * flat[a + j + 1, 1]
                    s2 += flat[a + j + 1, 0] * flat[a + j, 1]
                area = 0.5 * (s1 - s2 + flat[b - 1, 0] * flat[a, 1] - flat[a, 0] * flat[b - 1, 1])
                if area > 1e-12:
                    inside = True
                    for j in range(nk):
                        jn = a + (j + 1) % nk
                        e0 = flat[jn, 0] - flat[a + j, 0]
                        e1 = flat[jn, 1] - flat[a + j, 1]
                        if not (e0 * (x1 - flat[a + j, 1]) - e1 * (x0 - flat[a + j, 0]) >= 0):
                            inside = False
                            break
            if inside:
                c0, c1 = x0, x1
            else:
                best = np.inf
                c0, c1 = flat[a, 0], flat[a, 1]
                for j in range(nk):
                    jn = a + (j + 1) % nk
                    v0 = flat[a + j, 0]
                    v1 = flat[a + j, 1]
                    e0 = flat[jn, 0] - v0
                    e1 = flat[jn, 1] - v1
                    ee = max(e0 * e0 + e1 * e1, 1e-300)
                    t = min(max(((x0 - v0) * e0 + (x1 - v1) * e1) / ee, 0.0), 1.0)
                    q0 = v0 + t * e0
                    q1 = v1 + t * e1
                    d = (q0 - x0) ** 2 + (q1 - x1) ** 2
                    if d < best:
                        best = d
                        c0, c1 = q0, q1
        dx = x0 - c0
        dy = x1 - c1
        # plain arithmetic, not a BLAS dot (whose use of FMA differs between BLAS builds)
        out[k] = np.sqrt(dx * dx + dy * dy)
    return out


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Indices of the convex hull of ``points`` (n, 2), counter-clockwise (Andrew's monotone chain).

    Collinear and repeated points are dropped; fewer than 3 distinct points give those points. O(n log n).
    """
    order = sorted(range(len(points)), key=lambda k: (points[k, 0], points[k, 1]))

    def cross(o: int, a: int, b: int) -> float:
        return float((points[a, 0] - points[o, 0]) * (points[b, 1] - points[o, 1])
                     - (points[a, 1] - points[o, 1]) * (points[b, 0] - points[o, 0]))

    def chain(seq: list[int]) -> list[int]:
        out: list[int] = []
        for k in seq:
            while len(out) >= 2 and cross(out[-2], out[-1], k) <= 1e-12:
                out.pop()
            out.append(k)
        return out

    lower, upper = chain(order), chain(order[::-1])
    hull = lower[:-1] + upper[:-1]
    if not hull:  # a single point
        hull = order[:1]
    return np.array(hull, dtype=np.int64)


@dataclass(frozen=True)
class HalfPlanes:
    """The joint-torque rows no contact force enters, as 2-D bands lo ≤ g · (p̈, ṗ²) ≤ hi.

    A joint that no contact's Jacobian reaches (arms, spine, head: every joint but the legs' in
    contact) has the row |A p̈ + B ṗ² + C| ≤ limit, free of λ: a band in the (p̈, ṗ²) plane. Cut
    exactly from the polygon (:meth:`clip`) instead of kept in every LP, they shrink the CMU
    skeleton's LPs from 102 to 36 rows (flight frames: 12).
    """

    g: np.ndarray  # (m, 2)
    lo: np.ndarray  # (m,)
    hi: np.ndarray  # (m,)

    @staticmethod
    def of(A: np.ndarray, B: np.ndarray, C: np.ndarray, limits: np.ndarray, free: np.ndarray) -> HalfPlanes:
        """The bands of the joint rows ``free`` (nv − 6,) bool of one frame's A, B, C (nv,), limits (nv,)."""
        r = N_ROOT + np.flatnonzero(free)
        return HalfPlanes(np.stack([A[r], B[r]], axis=1), -limits[r] - C[r], limits[r] - C[r])

    def violation(self, x: np.ndarray) -> float:
        """How far the point x (2,) lies outside the bands (0 inside), in torque units."""
        if not len(self.g):
            return 0.0
        y = self.g @ x
        return float(max(0.0, (y - self.hi).max(), (self.lo - y).max()))

    def clip(self, v: np.ndarray, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The convex polygon v (K, 2, counter-clockwise; K ≤ 2: a segment or point) cut by every
        band, with λ (K, nλ) interpolated linearly along cut edges (a convex combination of feasible
        λ stays feasible: the constraints are linear). O(K · m) to test, O(K) per cutting band."""
        if not len(self.g) or not len(v):
            return v, lam
        ends = np.abs(np.concatenate([self.lo, self.hi]))
        scale = 1e-9 * (1.0 + ends[np.isfinite(ends)].max(initial=0.0))
        y = v @ self.g.T  # (K, m)
        over = ((y - self.hi) > scale).any(axis=0) | ((self.lo - y) > scale).any(axis=0)
        for k in np.flatnonzero(over):
            for a, b in ((self.g[k], self.hi[k]), (-self.g[k], -self.lo[k])):
                v, lam = _cut(v, lam, a, b, scale)
                if not len(v):
                    return v, lam
        return v, lam


def _cut(v: np.ndarray, lam: np.ndarray, a: np.ndarray, b: float, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Sutherland-Hodgman: the part of polygon v (K, 2) with a · x ≤ b, λ interpolated."""
    s = v @ a - b
    if (s <= tol).all():
        return v, lam
    if len(v) == 1:
        return v[:0], lam[:0]
    pv, pl = [], []
    edges = [(0, 1)] if len(v) == 2 else [(k, (k + 1) % len(v)) for k in range(len(v))]  # a segment: one edge
    for k0, k1 in edges:
        if s[k0] <= tol:
            pv.append(v[k0])
            pl.append(lam[k0])
        if (s[k0] <= tol) != (s[k1] <= tol):
            t = s[k0] / (s[k0] - s[k1])
            pv.append(v[k0] + t * (v[k1] - v[k0]))
            pl.append(lam[k0] + t * (lam[k1] - lam[k0]))
    if len(v) == 2 and s[1] <= tol:
        pv.append(v[1])
        pl.append(lam[1])
    if not pv:
        return v[:0], lam[:0]
    return np.array(pv), np.array(pl).reshape(len(pv), lam.shape[1])


def feasible_polygons(A: np.ndarray, B: np.ndarray, C: np.ndarray, contacts: Contacts, limits: np.ndarray,
                      weight: float, opts: PolygonParams) -> FeasiblePolygons:
    """Feasible (p̈, ṗ²) polygons of every frame (MPS06 §3.3) with λ at vertices and centre (§3.4).

    Mocap is never exactly consistent with the body model: the original timing leaves a root
    wrench ρ ((F, 6), signed, under the original physics: ``OriginalForces.tau``'s root rows) that no contact
    explains (a flight whose momentum is not exactly ballistic, a centre of pressure just off the
    sole). Given ``contacts.carrying(ρ)`` it is carried along as one more contact column that may scale but not turn: the root
    rows become |A p̈ + B ṗ² − N λ − μ ρ + C| ≤ ``root_tolerance``·weight with 0 ≤ μ ≤ :data:`CARRIED_MAX`
    (:meth:`Contacts.carrying`; the error of a mass model scales with the motion's accelerations
    and gravity, so a flight under half gravity at ṗ² = ½ has μ = ½). The original timing is
    feasible (μ = 1) while a retimed flight must still change its momentum as gravity does — a
    slack |ρ| + tol instead would let a flight play at any speed its error allows. Where no timing meets that bound
    (changed physics), every row gets 1.05 s* + ``root_tolerance``·weight with s* the smallest uniform
    residual over the box (an LP). Then the
    direction sweep; when the original timing (0, 1) is feasible but outside the sweep's inner
    hull, it joins the vertices (a feasible point: the hull stays inside the feasible set). Then
    the centre (0, 1) — or, when outside, its closest polygon point pulled 5 % toward the
    vertex mean — and its min-Σλ forces. Flight frames (no contact) give a thin polygon around the
    ballistic segment or point. Cost O(F · max_lps) LPs of (3 + nλ) columns.
    """
    t0, c0 = time.perf_counter(), time.process_time()
    f = A.shape[0]
    nl_all = contacts.basis.shape[2]
    verts, lams = [], []
    center = np.zeros((f, 2))
    clam = np.zeros((f, nl_all))
    res = np.zeros(f)
    tol = np.zeros((f, N_ROOT))
    inside = np.zeros(f, bool)
    n_lps = n_fallback = 0
    highs = new_highs()
    prev = None
    for i in range(f):
        cols = contacts.columns(i)
        N = contacts.basis[i][:, cols]
        upper = np.full(len(cols), INF)
        if contacts.carried:
            upper[-1] = CARRIED_MAX
        free = ~(N[N_ROOT:] != 0).any(axis=1)  # joint rows no contact force enters: bands, cut exactly
        bands = HalfPlanes.of(A[i], B[i], C[i], limits, free)
        lp = FrameLP(A[i], B[i], C[i], N, limits, opts, highs, upper, rows=~free)
        lp.start_from(prev)  # the previous frame's residual LP's optimal basis (when of the same shape)
        x = lp.solve(_lp_cost(len(cols), s=-1.0))
        prev = lp.basis()
        if x is not None and bands.violation(x[:2]) > 0:  # the relaxation's optimum is not the frame's
            whole = FrameLP(A[i], B[i], C[i], N, limits, opts, highs, upper)
            x = whole.solve(_lp_cost(len(cols), s=-1.0))
            n_lps, n_fallback = n_lps + 1, n_fallback + whole.n_fallback
            lp = FrameLP(A[i], B[i], C[i], N, limits, opts, highs, upper, rows=~free)
        res[i] = x[2] if x is not None else np.inf
        tol[i] = opts.root_tolerance * weight
        lp.set_residual_bound(tol[i])
        v, lv = bands.clip(*sweep_polygon(lp, opts))
        if not len(v):
            tol[i] = 1.05 * res[i] + opts.root_tolerance * weight
            lp.set_residual_bound(tol[i])
            v, lv = bands.clip(*sweep_polygon(lp, opts))
        o = np.array([0.0, 1.0])
        cp = closest_point(v, o) if len(v) else o
        inside[i] = bool(len(v) and abs(cp[0]) <= 1e-8 and abs(cp[1] - 1.0) <= 1e-8 + 1e-5)  # np.allclose(cp, o)
        xc = None
        if not inside[i] and bands.violation(o) <= 0:  # the sweep's inner hull may miss the original timing
            lp.fix_timing((0.0, 1.0))
            xc = lp.solve(_lp_cost(len(cols), lam=-1.0))
            if xc is not None:
                keep = convex_hull(np.vstack([v, o[None]]))
                v, lv = np.vstack([v, o[None]])[keep], np.vstack([lv, xc[None, 3:]])[keep]
                inside[i], cp = True, o
        c = cp if inside[i] else cp + 0.05 * (v.mean(axis=0) - cp)
        if xc is None:
            lp.fix_timing((float(c[0]), float(c[1])))
            xc = lp.solve(_lp_cost(len(cols), lam=-1.0))
        if xc is None:  # numerically on the boundary: use the nearest vertex
            k = int(np.argmin(((v - c) ** 2).sum(axis=1)))
            c, xl = v[k], lv[k]
        else:
            xl = xc[3:]
        full = np.zeros((len(v), nl_all))
        full[:, cols] = lv
        center[i] = c
        clam[i, cols] = xl
        verts.append(v)
        lams.append(full)
        n_lps += lp.n_solved
        n_fallback += lp.n_fallback
    infeasible = res > INFEASIBLE_TOL * weight
    return FeasiblePolygons(vertices=verts, lambdas=lams, center=center, center_lambda=clam, residual=res,
                            tolerance=tol, infeasible=infeasible, original_inside=inside, n_lps=n_lps,
                            seconds=time.perf_counter() - t0, cpu_seconds=time.process_time() - c0,
                            n_fallback=n_fallback, box=(opts.pdd_max, opts.speed_max ** 2))
