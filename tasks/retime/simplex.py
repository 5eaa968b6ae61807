"""A small dense bounded primal simplex for the feasible-polygon LPs (design §8, MPS06 §3.3).

The polygon sweep solves 16-18 LPs per frame of at most ~36 rows × ~40 columns, each a few
simplex iterations from the previous direction's basis (only the cost changes). HiGHS spends
most of its time there in per-call set-up; this solver keeps the basis and its dense inverse
between calls and runs in compiled code. It solves

    minimize c · x   subject to   row_lo ≤ M x ≤ row_hi,   col_lo ≤ x ≤ col_hi

(bounds may be ±inf) as M x − r = 0 over the n columns and m row activities r, with a dense
explicit basis inverse B⁻¹ (m × m, updated by one Gauss-Jordan step per pivot, refactored every
``REFACTOR`` pivots and when a coefficient changes). Phase 1 minimizes the sum of infeasibilities
(composite simplex: basic values outside their bounds cost ±1, a step stops where the first of
them reaches its bound), phase 2 the cost; Dantzig pricing, Harris's two-pass ratio test, and
Bland's rule after a run of degenerate pivots. Statuses: :data:`OPTIMAL`, :data:`INFEASIBLE`,
:data:`UNBOUNDED`, and :data:`ITERATION_LIMIT` / :data:`NUMERICAL` for the caller to fall back
to HiGHS (``polygons.FrameLP`` does).

Cost: O(m²) per pivot plus O(m · (n + m)) pricing; O(m³) per refactorization.
"""

from __future__ import annotations

import numpy as np
from motionweb.store.numba_cache import njit

OPTIMAL, INFEASIBLE, UNBOUNDED, ITERATION_LIMIT, NUMERICAL = 0, 1, 2, 3, 4
STATUS_NAMES = ("optimal", "infeasible", "unbounded", "iteration limit", "numerical trouble")

BASIC, AT_LOWER, AT_UPPER, AT_ZERO = 0, 1, 2, 3  # state of a variable; AT_ZERO: free and nonbasic
FEAS_TOL = 1e-9  # primal feasibility, relative to 1 + |bound|
DUAL_TOL = 1e-9  # reduced costs, relative to 1 + max |c|
PIVOT_TOL = 1e-9  # smallest |B⁻¹ a_j| entry a ratio test pivots on (rows scaled to max |M_ij| = 1)
REFACTOR = 50  # pivots between refactorizations of B⁻¹
BLAND_AFTER = 30  # consecutive degenerate pivots before switching to Bland's rule


@njit(cache=True)
def _column(M: np.ndarray, j: int, out: np.ndarray) -> None:
    """Column j of [M, −I] into out (m,)."""
    m, n = M.shape
    for i in range(m):
        out[i] = M[i, j] if j < n else 0.0
    if j >= n:
        out[j - n] = -1.0


@njit(cache=True)
def _invert(M: np.ndarray, head: np.ndarray, Binv: np.ndarray) -> bool:
    """B⁻¹ of the basis columns ``head`` of [M, −I] by Gauss-Jordan with partial pivoting; False if singular."""
    m = M.shape[0]
    B = np.zeros((m, m))
    col = np.zeros(m)
    for k in range(m):
        _column(M, head[k], col)
        for i in range(m):
            B[i, k] = col[i]
    for i in range(m):
        for c in range(m):
            Binv[i, c] = 1.0 if i == c else 0.0
    for k in range(m):
        p, best = k, abs(B[k, k])
        for i in range(k + 1, m):
            if abs(B[i, k]) > best:
                p, best = i, abs(B[i, k])
        if best < 1e-11:
            return False
        if p != k:
            for c in range(m):
                t = B[k, c]
                B[k, c] = B[p, c]
                B[p, c] = t
                t = Binv[k, c]
                Binv[k, c] = Binv[p, c]
                Binv[p, c] = t
        piv = B[k, k]
        for c in range(m):
            B[k, c] /= piv
            Binv[k, c] /= piv
        for i in range(m):
            if i != k and B[i, k] != 0.0:
                f = B[i, k]
                for c in range(m):
                    B[i, c] -= f * B[k, c]
                    Binv[i, c] -= f * Binv[k, c]
    return True


@njit(cache=True)
def _basic_values(M: np.ndarray, head: np.ndarray, state: np.ndarray, x: np.ndarray, Binv: np.ndarray) -> None:
    """x_B = −B⁻¹ Σ_nonbasic a_j x_j (the rows read M x − r = 0)."""
    m, n = M.shape
    rhs = np.zeros(m)
    for j in range(n):
        if state[j] != BASIC and x[j] != 0.0:
            for i in range(m):
                rhs[i] -= M[i, j] * x[j]
    for i in range(m):
        if state[n + i] != BASIC:
            rhs[i] += x[n + i]
    for k in range(m):
        s = 0.0
        for i in range(m):
            s += Binv[k, i] * rhs[i]
        x[head[k]] = s


@njit(cache=True)
def _place_nonbasic(lo: np.ndarray, hi: np.ndarray, state: np.ndarray, x: np.ndarray) -> None:
    """Nonbasic variables at their (possibly changed) bounds; a state whose bound is infinite moves."""
    for j in range(len(state)):
        s = state[j]
        if s == BASIC:
            continue
        if s == AT_LOWER and not np.isfinite(lo[j]):
            s = AT_UPPER if np.isfinite(hi[j]) else AT_ZERO
        elif s == AT_UPPER and not np.isfinite(hi[j]):
            s = AT_LOWER if np.isfinite(lo[j]) else AT_ZERO
        elif s == AT_ZERO and (np.isfinite(lo[j]) or np.isfinite(hi[j])):
            s = AT_LOWER if np.isfinite(lo[j]) else AT_UPPER
        state[j] = s
        x[j] = lo[j] if s == AT_LOWER else (hi[j] if s == AT_UPPER else 0.0)


@njit(cache=True)
def _slack_basis(n: int, m: int, lo: np.ndarray, hi: np.ndarray, head: np.ndarray, state: np.ndarray,
                 Binv: np.ndarray) -> None:
    for j in range(n):
        state[j] = AT_LOWER if np.isfinite(lo[j]) else (AT_UPPER if np.isfinite(hi[j]) else AT_ZERO)
    for i in range(m):
        head[i] = n + i
        state[n + i] = BASIC
    for i in range(m):
        for c in range(m):
            Binv[i, c] = -1.0 if i == c else 0.0


@njit(cache=True)
def simplex(M: np.ndarray, lo: np.ndarray, hi: np.ndarray, cost: np.ndarray, head: np.ndarray, state: np.ndarray,
            x: np.ndarray, Binv: np.ndarray, pivots: np.ndarray, max_iter: int) -> tuple[int, int]:
    """Minimize cost · x[:n] subject to M x[:n] − x[n:] = 0, lo ≤ x ≤ hi, from the basis (head, state).

    Args:
        M: (m, n) constraint matrix (rows best scaled to max |M_ij| = 1).
        lo, hi: (n + m,) bounds of the columns then of the rows' activities (±inf allowed).
        cost: (n,) costs of the columns (rows cost 0).
        head: (m,) indices of the basic variables; state: (n + m,) BASIC / AT_LOWER / AT_UPPER /
            AT_ZERO — both updated in place to the final basis (a warm start for the next call).
        x: (n + m,) values, written.
        Binv: (m, m) B⁻¹ of ``head``, updated in place.
        pivots: (1,) pivots since B⁻¹ was last computed from scratch (−1: recompute it first).
        max_iter: iteration budget.

    Returns:
        (status, iterations). A singular starting basis is replaced by the slack basis.

    Bounds: writes ``x``/``state`` (n + m,), ``head`` (m,) and ``Binv`` (m, m) at indices below
    those sizes (``head`` holds variable indices < n + m); :class:`DenseLP` sizes them.
    """
    m, n = M.shape
    nt = n + m
    for j in range(nt):
        if lo[j] > hi[j]:
            return INFEASIBLE, 0
    if pivots[0] < 0 or pivots[0] >= REFACTOR:
        if not _invert(M, head, Binv):
            _slack_basis(n, m, lo, hi, head, state, Binv)
        pivots[0] = 0
    _place_nonbasic(lo, hi, state, x)
    _basic_values(M, head, state, x, Binv)
    cmax = 1.0
    for j in range(n):
        cmax = max(cmax, abs(cost[j]))
    ftol = np.empty(nt)
    for j in range(nt):
        b = 0.0
        if np.isfinite(lo[j]):
            b = abs(lo[j])
        if np.isfinite(hi[j]):
            b = max(b, abs(hi[j]))
        ftol[j] = FEAS_TOL * (1.0 + b)
    cb = np.zeros(m)
    y = np.zeros(m)
    alpha = np.zeros(m)
    col = np.zeros(m)
    degenerate = 0
    checked = True  # x_B was recomputed from B⁻¹ since the last pivot
    it = 0
    while it < max_iter:
        # phase: infeasible basic values cost ±1 (phase 1), else the true costs (phase 2)
        phase1 = False
        for k in range(m):
            j = head[k]
            if x[j] < lo[j] - ftol[j]:
                cb[k] = -1.0
                phase1 = True
            elif x[j] > hi[j] + ftol[j]:
                cb[k] = 1.0
                phase1 = True
            else:
                cb[k] = 0.0
        if not phase1:
            for k in range(m):
                j = head[k]
                cb[k] = cost[j] if j < n else 0.0
        dtol = DUAL_TOL * (1.0 if phase1 else cmax)
        for i in range(m):
            s = 0.0
            for k in range(m):
                s += cb[k] * Binv[k, i]
            y[i] = s
        # pricing (Dantzig; Bland's smallest index after a run of degenerate pivots)
        bland = degenerate >= BLAND_AFTER
        q, best, qdir = -1, 0.0, 0.0
        for j in range(nt):
            s = state[j]
            if s == BASIC or (s != AT_ZERO and hi[j] - lo[j] <= 0.0):
                continue
            if j < n:
                d = 0.0 if phase1 else cost[j]
                for i in range(m):
                    d -= y[i] * M[i, j]
            else:
                d = y[j - n]
            if d < -dtol and s != AT_UPPER:
                dr = 1.0
            elif d > dtol and s != AT_LOWER:
                dr = -1.0
            else:
                continue
            if bland:
                q, best, qdir = j, abs(d), dr
                break
            if abs(d) > best:
                q, best, qdir = j, abs(d), dr
        if q < 0:
            if not checked:  # confirm with x_B recomputed from B⁻¹ (drift of the updates)
                _basic_values(M, head, state, x, Binv)
                checked = True
                continue
            return (INFEASIBLE if phase1 else OPTIMAL), it
        checked = False
        # column of the entering variable: x_B moves by −qdir · t · alpha
        _column(M, q, col)
        for k in range(m):
            s = 0.0
            for i in range(m):
                s += Binv[k, i] * col[i]
            alpha[k] = s
        # Harris ratio test, pass 1: the largest step with bounds relaxed by their tolerance
        tmax = np.inf
        for k in range(m):
            rate = -qdir * alpha[k]
            if abs(rate) <= PIVOT_TOL:
                continue
            j = head[k]
            if rate < 0.0:  # decreasing: stops at lo (feasible) or at hi (above it, phase 1)
                if x[j] > hi[j] + ftol[j]:
                    lim = (x[j] - hi[j] + ftol[j]) / -rate
                elif x[j] >= lo[j] - ftol[j] and np.isfinite(lo[j]):
                    lim = (x[j] - lo[j] + ftol[j]) / -rate
                else:
                    continue
            else:
                if x[j] < lo[j] - ftol[j]:
                    lim = (lo[j] - x[j] + ftol[j]) / rate
                elif x[j] <= hi[j] + ftol[j] and np.isfinite(hi[j]):
                    lim = (hi[j] - x[j] + ftol[j]) / rate
                else:
                    continue
            tmax = min(tmax, lim)
        span = hi[q] - lo[q]
        # pass 2: among the steps within tmax, the largest pivot (Bland: the smallest index)
        r, rbest, t, leave_upper = -1, 0.0, 0.0, False
        if tmax < np.inf:
            for k in range(m):
                rate = -qdir * alpha[k]
                if abs(rate) <= PIVOT_TOL:
                    continue
                j = head[k]
                if rate < 0.0:
                    if x[j] > hi[j] + ftol[j]:
                        tk, up = (x[j] - hi[j]) / -rate, True
                    elif x[j] >= lo[j] - ftol[j] and np.isfinite(lo[j]):
                        tk, up = (x[j] - lo[j]) / -rate, False
                    else:
                        continue
                else:
                    if x[j] < lo[j] - ftol[j]:
                        tk, up = (lo[j] - x[j]) / rate, False
                    elif x[j] <= hi[j] + ftol[j] and np.isfinite(hi[j]):
                        tk, up = (hi[j] - x[j]) / rate, True
                    else:
                        continue
                if tk > tmax:
                    continue
                if bland:
                    if r < 0 or j < head[r]:
                        r, rbest, t, leave_upper = k, abs(rate), tk, up
                elif abs(rate) > rbest:
                    r, rbest, t, leave_upper = k, abs(rate), tk, up
        it += 1
        if np.isfinite(span) and span <= tmax:  # the entering variable reaches its other bound first
            for k in range(m):
                x[head[k]] -= qdir * span * alpha[k]
            state[q] = AT_UPPER if qdir > 0 else AT_LOWER
            x[q] = hi[q] if qdir > 0 else lo[q]
            degenerate = 0
            continue
        if r < 0:
            if phase1:  # cannot happen in exact arithmetic: an infeasible basic value blocks
                return NUMERICAL, it
            return UNBOUNDED, it
        t = max(t, 0.0)
        degenerate = degenerate + 1 if t * rbest <= 1e-12 else 0
        for k in range(m):
            x[head[k]] -= qdir * t * alpha[k]
        x[q] += qdir * t
        out = head[r]
        state[out] = AT_UPPER if leave_upper else AT_LOWER
        x[out] = hi[out] if leave_upper else lo[out]
        if lo[out] == hi[out]:
            state[out] = AT_LOWER
        head[r] = q
        state[q] = BASIC
        # B⁻¹ update: one Gauss-Jordan step on pivot alpha[r]
        piv = alpha[r]
        for c in range(m):
            Binv[r, c] /= piv
        for k in range(m):
            if k != r and alpha[k] != 0.0:
                f = alpha[k]
                for c in range(m):
                    Binv[k, c] -= f * Binv[r, c]
        pivots[0] += 1
        if pivots[0] >= REFACTOR:
            if not _invert(M, head, Binv):
                return NUMERICAL, it
            _basic_values(M, head, state, x, Binv)
            pivots[0] = 0
    return ITERATION_LIMIT, it


@njit(cache=True)
def simplex_sequence(M: np.ndarray, lo: np.ndarray, hi: np.ndarray, cost: np.ndarray, sign: float, costs: np.ndarray,
                     head: np.ndarray, state: np.ndarray, x: np.ndarray, Binv: np.ndarray, pivots: np.ndarray,
                     max_iter: int, stop_at_first: bool, out: np.ndarray, status: np.ndarray) -> int:
    """:func:`simplex` for each row of ``costs`` in turn, each from the previous one's basis.

    Row b's (k,) costs replace cost[:k] (kept in ``cost`` afterwards); the objective is
    sign · cost. Writes the column values of solve b into out[b] (B, n) and its status into
    status[b]. Stops after an iteration limit or numerical trouble, and after the first solve that
    is not optimal when ``stop_at_first``. Returns the number of solves run; ``x`` and the basis
    are those of the last.

    Bounds: writes cost[:k] (k ≤ n, checked by :meth:`DenseLP.solve_sequence`), rows b < B of
    ``out`` (B, n) and ``status`` (B,).
    """
    n = M.shape[1]
    k = costs.shape[1]
    signed = np.empty(n)
    for b in range(costs.shape[0]):
        for j in range(k):
            cost[j] = costs[b, j]
        for j in range(n):
            signed[j] = sign * cost[j]
        st, _ = simplex(M, lo, hi, signed, head, state, x, Binv, pivots, max_iter)
        status[b] = st
        for j in range(n):
            out[b, j] = x[j]
        if st == ITERATION_LIMIT or st == NUMERICAL or (stop_at_first and st != OPTIMAL):
            return b + 1
    return costs.shape[0]


class DenseLP:
    """An LP  min/max c · x  s.t. row_lo ≤ M x ≤ row_hi, col_lo ≤ x ≤ col_hi  kept with its basis.

    Each :meth:`solve` starts from the previous call's basis (after a change of costs or bounds
    only, from its inverse too), so a sweep of objectives over one constraint set costs a few
    pivots per LP. Rows are scaled to max |M_ij| = 1 internally; ``x`` and the objective are in
    the caller's units.

    Args:
        M: (m, n) dense constraint matrix; col_lo, col_hi: (n,); row_lo, row_hi: (m,) (±inf allowed).
        maximize: maximize instead of minimize.
        max_iter: iteration budget per solve (default 50 · (m + n)).
    """

    def __init__(self, M: np.ndarray, col_lo: np.ndarray, col_hi: np.ndarray, row_lo: np.ndarray,
                 row_hi: np.ndarray, maximize: bool = False, max_iter: int | None = None):
        M = np.asarray(M, dtype=float)
        m, n = M.shape
        big = np.abs(M).max(axis=1) if n else np.zeros(m)
        self.scale = np.where(big > 0, 1.0 / np.where(big > 0, big, 1.0), 1.0)  # (m,)
        self.M = np.ascontiguousarray(M * self.scale[:, None])
        self.lo = np.concatenate([np.asarray(col_lo, float), np.asarray(row_lo, float) * self.scale])
        self.hi = np.concatenate([np.asarray(col_hi, float), np.asarray(row_hi, float) * self.scale])
        self.cost = np.zeros(n)
        self.sign = -1.0 if maximize else 1.0
        self.head = np.zeros(m, np.int64)
        self.state = np.zeros(n + m, np.int8)
        self.x = np.zeros(n + m)
        self.Binv = np.zeros((m, m))
        _slack_basis(n, m, self.lo, self.hi, self.head, self.state, self.Binv)
        self.pivots = np.zeros(1, np.int64)
        self.max_iter = max_iter if max_iter is not None else 50 * (m + n)
        self.status = OPTIMAL
        self.iterations = 0

    @property
    def shape(self) -> tuple[int, int]:
        return self.M.shape

    def set_cost(self, cost: np.ndarray, start: int = 0) -> None:
        """Costs of columns start, start + 1, … (the others unchanged)."""
        self.cost[start:start + len(cost)] = cost

    def set_col_bounds(self, j: int, lo: float, hi: float) -> None:
        self.lo[j], self.hi[j] = lo, hi

    def set_coeff(self, i: int, j: int, value: float) -> None:
        """M[i, j] = value (the basis is kept; its inverse is recomputed at the next solve)."""
        self.M[i, j] = value * self.scale[i]
        self.pivots[0] = -1

    def solve(self) -> int:
        """Optimize from the current basis; the status (``x``, ``objective`` valid when OPTIMAL)."""
        st, it = simplex(self.M, self.lo, self.hi, self.sign * self.cost, self.head, self.state, self.x, self.Binv,
                         self.pivots, self.max_iter)
        if st in (ITERATION_LIMIT, NUMERICAL):  # next time, start over from the slack basis
            self._restart()
        self.status, self.iterations = int(st), int(it)
        return self.status

    def solve_sequence(self, costs: np.ndarray, stop_at_first: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Optimize for each row of ``costs`` (B, k) — the costs of columns 0..k−1, the others kept —
        in turn, each from the previous basis. Returns (x (b, n), status (b,)) of the b ≤ B solves
        run: the sequence stops after an iteration limit or numerical trouble (the basis then
        restarts from the slacks), and at the first non-optimal solve when ``stop_at_first``."""
        costs = np.ascontiguousarray(costs, dtype=float)
        if costs.ndim != 2 or costs.shape[1] > self.M.shape[1]:
            raise ValueError(f"costs must be (B, k) with k <= {self.M.shape[1]} columns, got shape {costs.shape}")
        out = np.empty((len(costs), self.M.shape[1]))
        status = np.empty(len(costs), np.int64)
        b = simplex_sequence(self.M, self.lo, self.hi, self.cost, self.sign, costs, self.head, self.state, self.x,
                             self.Binv, self.pivots, self.max_iter, stop_at_first, out, status)
        if b and status[b - 1] in (ITERATION_LIMIT, NUMERICAL):
            self._restart()
        if b:
            self.status = int(status[b - 1])
        return out[:b], status[:b]

    def basis(self) -> tuple[np.ndarray, np.ndarray]:
        """(head, state) copies of the current basis."""
        return self.head.copy(), self.state.copy()

    def start_from(self, basis: tuple[np.ndarray, np.ndarray]) -> None:
        """Start the next solve from ``basis`` of an LP of the same shape (ignored otherwise); its
        inverse is computed then, and a basis singular here is replaced by the slacks."""
        head, state = basis
        if head.shape == self.head.shape and state.shape == self.state.shape:
            self.head[:] = head
            self.state[:] = state
            self.pivots[0] = -1

    def _restart(self) -> None:
        m, n = self.M.shape
        _slack_basis(n, m, self.lo, self.hi, self.head, self.state, self.Binv)
        self.pivots[0] = 0

    @property
    def solution(self) -> np.ndarray:
        """(n,) column values of the last solve."""
        return self.x[:self.M.shape[1]]

    @property
    def objective(self) -> float:
        return float(self.cost @ self.solution)
