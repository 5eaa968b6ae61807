"""Slope-ruled dynamic programming on a band: rows with one column interval each (KG04 §3.1-3.2).

Shared by the match webs (bridges, coarse-to-fine refinement) and by registration
(:mod:`motionweb.tasks.register`). Band row ``t`` covers columns ``lo[t]..hi[t]``; cell (t, j) is
flat index ``off[t] + j − lo[t]``. Paths are monotone (up, right, diagonal) with at most
``mrun = k − 1`` consecutive steps along one axis (:func:`motionweb.tasks.matchweb.params.max_run`).
"""

from __future__ import annotations

import numpy as np
from motionweb.tasks.matchweb.params import INF, max_run
from motionweb.store.numba_cache import njit


@njit(cache=True, nogil=True, inline="always")
def band_index(lo: np.ndarray, hi: np.ndarray, off: np.ndarray, t: int, j: int) -> int:
    """Flat index of band cell (t, j), or −1 when it lies outside the band."""
    if t < 0 or t >= lo.shape[0] or j < lo[t] or j > hi[t]:
        return -1
    return off[t] + j - lo[t]


@njit(cache=True, nogil=True)
def band_dp(lo, hi, off, vals, init, flags, mrun, cost, length, ptr) -> None:
    """Least-total-cost monotone paths under the slope rule, on a band.

    Band row ``t`` covers columns ``lo[t]..hi[t]``; cell (t, j) is flat index
    ``off[t] + j − lo[t]``. ``vals``: cell costs (inf = blocked); ``init``: start cost of source
    cells (inf elsewhere); ``flags``: 1 blocked, 2 terminal (may be entered, not left).
    State ``s = r + mrun`` with r > 0 a run of up steps, r < 0 of right steps, 0 after a diagonal
    or at a source. Outputs per (cell, state): total cost, cell count, predecessor state
    (−1 at a source, −2 unreached). O(cells · k) with the predecessors' flat indices carried
    along the rows (no per-cell index search).

    Each state has its own few candidates, taken in a fixed order with a strict ``<`` (ties keep
    the first): state 0 (diagonal) the source, then the diagonal predecessor's states in order;
    up-run 1 the up predecessor's states r ≤ 0 in order, up-run r + 1 its state r; right runs
    likewise from the left neighbour. Each cell's states are found in registers and written once.
    ``tests/naive.ref_band_dp`` is the same rule written out per transition.

    slope_k = 3 (``mrun`` = 2, the default) runs :func:`_band_dp_run2`, the same rule with the five
    states unrolled (~2.1× faster on smooth values, ``bench/band_dp.py``); any other ``mrun`` runs
    :func:`_band_dp_any`.

    Bounds: writes rows ``off[t] .. off[t] + hi[t] − lo[t]`` of ``cost``/``length``/``ptr`` (so at
    most ``off[-1]`` rows: the caller sizes them from the band, ``off[t + 1] = off[t] + hi[t] − lo[t]
    + 1``, empty rows have ``hi < lo``) and states ``0 .. 2·mrun`` (≤ 126, held by the int8 ``ptr``:
    ``params.max_run`` caps slope_k at 64); buffers narrower than that or shorter than ``off[-1]``
    rows raise instead.
    """
    if cost.shape[1] < 2 * mrun + 1 or length.shape[1] < 2 * mrun + 1 or ptr.shape[1] < 2 * mrun + 1:
        raise ValueError("band_dp: buffers narrower than the 2·mrun + 1 states")
    rows = min(cost.shape[0], length.shape[0], ptr.shape[0], vals.shape[0], init.shape[0], flags.shape[0])
    if rows < off[-1]:
        raise ValueError("band_dp: buffers shorter than the band")
    if mrun == 2 and cost.shape[1] == 5 and length.shape[1] == 5 and ptr.shape[1] == 5:
        _band_dp_run2(lo, hi, off, vals, init, flags, cost.reshape(-1), length.reshape(-1), ptr.reshape(-1))
    else:
        _band_dp_any(lo, hi, off, vals, init, flags, mrun, cost, length, ptr)


@njit(cache=True, nogil=True)
def _band_dp_any(lo, hi, off, vals, init, flags, mrun, cost, length, ptr) -> None:
    """:func:`band_dp` for any ``mrun``, the states in loops (KG04 §3.1-3.2)."""
    ns = 2 * mrun + 1
    c0 = mrun
    for t in range(lo.shape[0]):
        # previous row's interval (empty for the first row)
        plo = lo[t - 1] if t > 0 else 0
        phi = hi[t - 1] if t > 0 else -1
        pbase = off[t - 1] - plo if t > 0 else 0
        base = off[t] - lo[t]
        for j in range(lo[t], hi[t] + 1):
            k = base + j
            v = vals[k]
            if not v < INF or flags[k] == 1:
                for s in range(ns):
                    cost[k, s] = INF
                    length[k, s] = 0
                    ptr[k, s] = -2
                continue
            # diagonal (and source) → state c0
            bc = INF
            bl = 0
            bp = -2
            if init[k] < INF:
                bc = init[k]
                bl = 1
                bp = -1
            if plo <= j - 1 <= phi and flags[pbase + j - 1] != 2:
                kd = pbase + j - 1
                for s in range(ns):
                    c = cost[kd, s] + v
                    if c < bc:
                        bc = c
                        bl = length[kd, s] + 1
                        bp = s
            cost[k, c0] = bc
            length[k, c0] = bl
            ptr[k, c0] = bp
            if mrun == 0:
                continue
            # up: states r ≤ 0 → run 1; run r → r + 1 (≤ mrun)
            if plo <= j <= phi and flags[pbase + j] != 2:
                kv = pbase + j
                bc = INF
                bl = 0
                bp = -2
                for s in range(c0 + 1):
                    c = cost[kv, s] + v
                    if c < bc:
                        bc = c
                        bl = length[kv, s] + 1
                        bp = s
                cost[k, c0 + 1] = bc
                length[k, c0 + 1] = bl
                ptr[k, c0 + 1] = bp
                for s in range(c0 + 1, ns - 1):
                    c = cost[kv, s] + v
                    if c < INF:
                        cost[k, s + 1] = c
                        length[k, s + 1] = length[kv, s] + 1
                        ptr[k, s + 1] = s
                    else:
                        cost[k, s + 1] = INF
                        length[k, s + 1] = 0
                        ptr[k, s + 1] = -2
            else:
                for s in range(c0 + 1, ns):
                    cost[k, s] = INF
                    length[k, s] = 0
                    ptr[k, s] = -2
            # right: states r ≥ 0 → run −1; run r < 0 → r − 1 (≥ −mrun)
            if j > lo[t] and flags[k - 1] != 2:
                kh = k - 1
                bc = INF
                bl = 0
                bp = -2
                for s in range(c0, ns):
                    c = cost[kh, s] + v
                    if c < bc:
                        bc = c
                        bl = length[kh, s] + 1
                        bp = s
                cost[k, c0 - 1] = bc
                length[k, c0 - 1] = bl
                ptr[k, c0 - 1] = bp
                for s in range(1, c0):
                    c = cost[kh, s] + v
                    if c < INF:
                        cost[k, s - 1] = c
                        length[k, s - 1] = length[kh, s] + 1
                        ptr[k, s - 1] = s
                    else:
                        cost[k, s - 1] = INF
                        length[k, s - 1] = 0
                        ptr[k, s - 1] = -2
            else:
                for s in range(c0):
                    cost[k, s] = INF
                    length[k, s] = 0
                    ptr[k, s] = -2


@njit(cache=True, nogil=True, inline="always")
def _better(bc, bp, c, s):
    """The candidate (cost c, predecessor state s) if it is strictly cheaper than the best so far
    (bc, bp), else the best so far: taken in candidate order, ties keep the first."""
    if c < bc:
        return c, s
    return bc, bp


@njit(cache=True, nogil=True, inline="always")
def _length(length, q, p):
    """Cells of the path ending in a state whose predecessor state is ``p`` at the cell whose
    states start at flat index ``q``: that state's length + 1; 1 at a source (p = −1), 0 unreached
    (p = −2). The load is made whatever ``p`` (of state 0 then: ``q`` is always a cell's index)."""
    n = length[q + np.uint64(max(p, 0))] + 1
    return n if p >= 0 else (1 if p == -1 else 0)


@njit(cache=True, nogil=True)
def _band_dp_run2(lo, hi, off, vals, init, flags, cost, length, ptr) -> None:
    """:func:`band_dp` for ``mrun`` = 2 (slope_k = 3, the default; KG04 §3.1-3.2): states 0-1 right
    runs of 2 and 1, 2 diagonal/source, 3-4 up runs of 1 and 2, on flat ``cost``/``length``/``ptr``
    ((cells · 5,), cell k's states at 5k .. 5k + 4).

    The same candidates in the same order as :func:`_band_dp_any`, unrolled: each predecessor's five
    costs are read once into registers (the up predecessor of cell j is the diagonal one of
    j + 1, and the left neighbour's states are the ones just found), each state is chosen by
    :func:`_better` on costs alone, and its length is read from the chosen predecessor state
    afterwards (:func:`_length`). A blocked or terminal predecessor counts as one with every state
    unreached, which is what reading a blocked cell's states gives, so the outputs are the same
    bytes (``tests/tasks/test_kernel_bounds.py``). Flat indices are taken as unsigned: numba then
    skips the negative-index wraparound on each of the ~25 reads and writes of a cell. O(cells).

    Bounds: every index is 5k + s with k < ``off[-1]`` a band cell (or its row's predecessor
    row's cell, also < ``off[-1]``; 0, a cell too, where there is no predecessor) and s ≤ 4;
    :func:`band_dp` checked that the buffers hold ``off[-1]`` cells of 5 states.
    """
    u1, u2, u3, u4 = np.uint64(1), np.uint64(2), np.uint64(3), np.uint64(4)  # unsigned + signed is signed
    for t in range(lo.shape[0]):
        plo = lo[t - 1] if t > 0 else 0
        phi = hi[t - 1] if t > 0 else -1
        pbase = off[t - 1] - plo if t > 0 else 0
        base = off[t] - lo[t]
        # the diagonal predecessor (t − 1, j − 1) of the row's first cell: its states' index, costs
        qd = np.uint64(0)
        dc0 = dc1 = dc2 = dc3 = dc4 = INF
        j = lo[t]
        if plo <= j - 1 <= phi and flags[pbase + j - 1] != 2:
            qd = np.uint64(5 * (pbase + j - 1))
            dc0, dc1, dc2, dc3, dc4 = cost[qd], cost[qd + u1], cost[qd + u2], cost[qd + u3], cost[qd + u4]
        # the left neighbour's states 1-4 (none at the row's first cell)
        qh = np.uint64(0)
        hc1 = hc2 = hc3 = hc4 = INF
        for j in range(lo[t], hi[t] + 1):
            k = np.uint64(base + j)
            # the up predecessor (t − 1, j)
            qu = np.uint64(0)
            uc0 = uc1 = uc2 = uc3 = uc4 = INF
            if plo <= j <= phi and flags[pbase + j] != 2:
                qu = np.uint64(5 * (pbase + j))
                uc0, uc1, uc2, uc3, uc4 = cost[qu], cost[qu + u1], cost[qu + u2], cost[qu + u3], cost[qu + u4]
            v = vals[k]
            o = np.uint64(5) * k
            if not v < INF or flags[k] == 1:
                for s in range(5):
                    cost[o + np.uint64(s)] = INF
                    length[o + np.uint64(s)] = 0
                    ptr[o + np.uint64(s)] = -2
                hc1 = hc2 = hc3 = hc4 = INF
            else:
                # state 2: the source, then the diagonal predecessor's states 0-4
                c2, p2 = INF, -2
                if init[k] < INF:
                    c2, p2 = init[k], -1
                c2, p2 = _better(c2, p2, dc0 + v, 0)
                c2, p2 = _better(c2, p2, dc1 + v, 1)
                c2, p2 = _better(c2, p2, dc2 + v, 2)
                c2, p2 = _better(c2, p2, dc3 + v, 3)
                c2, p2 = _better(c2, p2, dc4 + v, 4)
                # state 3 (up run 1): the up predecessor's states 0-2; state 4: its state 3
                c3, p3 = _better(INF, -2, uc0 + v, 0)
                c3, p3 = _better(c3, p3, uc1 + v, 1)
                c3, p3 = _better(c3, p3, uc2 + v, 2)
                c4, p4 = _better(INF, -2, uc3 + v, 3)
                # state 1 (right run 1): the left neighbour's states 2-4; state 0: its state 1
                c1, p1 = _better(INF, -2, hc2 + v, 2)
                c1, p1 = _better(c1, p1, hc3 + v, 3)
                c1, p1 = _better(c1, p1, hc4 + v, 4)
                c0, p0 = _better(INF, -2, hc1 + v, 1)
                cost[o], cost[o + u1], cost[o + u2], cost[o + u3], cost[o + u4] = c0, c1, c2, c3, c4
                length[o] = _length(length, qh, p0)
                length[o + u1] = _length(length, qh, p1)
                length[o + u2] = _length(length, qd, p2)
                length[o + u3] = _length(length, qu, p3)
                length[o + u4] = _length(length, qu, p4)
                ptr[o], ptr[o + u1], ptr[o + u2], ptr[o + u3], ptr[o + u4] = p0, p1, p2, p3, p4
                if flags[k] == 2:  # terminal: entered, never left
                    hc1 = hc2 = hc3 = hc4 = INF
                else:
                    qh = o
                    hc1, hc2, hc3, hc4 = c1, c2, c3, c4
            qd = qu
            dc0, dc1, dc2, dc3, dc4 = uc0, uc1, uc2, uc3, uc4


@njit(cache=True, nogil=True)
def band_backtrack(row0, lo, hi, off, ptr, t, j, s, mrun) -> np.ndarray:
    """Cells (n, 2) (absolute rows) of the path ending at band cell (t, j) in state s.

    Bounds: writes at most t + 1 + (j − min lo) ≤ rows + (max hi − min lo) + 1 cells, the length of
    a monotone unit-step path inside the band, into scratch of rows + (max hi − min lo) + 2; a
    predecessor chain not made by :func:`band_dp` that would run longer raises instead of writing
    past it.
    """
    c0 = mrun
    n = 0
    ti = np.empty(lo.shape[0] + (hi.max() - lo.min()) + 2, dtype=np.int64)
    tj = np.empty_like(ti)
    while True:
        if n >= ti.shape[0] or t < 0 or t >= lo.shape[0] or j < lo[t] or j > hi[t]:
            raise ValueError("band_backtrack: the predecessor chain leaves the band")
        ti[n] = t
        tj[n] = j
        n += 1
        k = off[t] + j - lo[t]
        p = ptr[k, s]
        if p < 0:
            break
        r = s - c0
        if r == 0:
            t -= 1
            j -= 1
        elif r > 0:
            t -= 1
        else:
            j -= 1
        s = p
    out = np.empty((n, 2), dtype=np.int32)
    for q in range(n):
        out[q, 0] = row0 + ti[n - 1 - q]
        out[q, 1] = tj[n - 1 - q]
    return out


@njit(cache=True, nogil=True, inline="always")
def best_state_total(cost, k) -> int:
    """State of least total cost at flat cell ``k`` (``cost``: (cells, 2·mrun + 1))."""
    best = 0
    for s in range(cost.shape[1]):
        if cost[k, s] < cost[k, best]:
            best = s
    return best


@njit(cache=True, nogil=True, inline="always")
def best_state_avg(cost, length, k) -> tuple[int, float]:
    """(state, average cost) of least average cost at flat cell ``k``; (−1, inf) when unreached."""
    best = -1
    bv = INF
    for s in range(cost.shape[1]):
        if length[k, s] > 0:
            a = cost[k, s] / length[k, s]
            if a < bv:
                bv = a
                best = s
    return best, bv


def band_buffers(ncells: int, mrun: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Output buffers of :func:`band_dp` for ``ncells`` cells: cost, length, predecessor state."""
    ns = 2 * mrun + 1
    return (np.empty((ncells, ns), np.float64), np.empty((ncells, ns), np.int32),
            np.empty((ncells, ns), np.int8))


def optimal_path(grid: np.ndarray, start: tuple[int, int], end: tuple[int, int], slope_k: int,
                 mask: np.ndarray | None = None) -> np.ndarray | None:
    """Least-total-cost slope-ruled path from ``start`` to ``end`` (cells (n, 2)), or None.

    The time alignment of KG04 §3.1 by dynamic programming, optionally restricted to ``mask``
    (e.g. the valid region). O(cells of the rectangle · k).
    """
    (i0, j0), (i1, j1) = start, end
    if i1 < i0 or j1 < j0:
        return None
    sub = np.asarray(grid[i0:i1 + 1, j0:j1 + 1], dtype=np.float64)
    if mask is not None:
        sub = np.where(mask[i0:i1 + 1, j0:j1 + 1], sub, np.inf)
    nr, nc = sub.shape
    lo = np.full(nr, j0, np.int64)
    hi = np.full(nr, j1, np.int64)
    off = np.arange(nr + 1, dtype=np.int64) * nc
    vals = np.ascontiguousarray(sub.reshape(-1))
    init = np.full(len(vals), np.inf)
    init[0] = vals[0]
    mrun = max_run(slope_k)
    cost, length, ptr = band_buffers(len(vals), mrun)
    band_dp(lo, hi, off, vals, init, np.zeros(len(vals), np.uint8), mrun, cost, length, ptr)
    k = len(vals) - 1
    s = best_state_total(cost, k)
    if not cost[k, s] < np.inf:
        return None
    return band_backtrack(i0, lo, hi, off, ptr, nr - 1, j1, s, mrun)
