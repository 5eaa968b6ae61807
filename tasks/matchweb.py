"""Match webs: chains of 1-D minima plus bridges, built coarse to fine (design §4, KG04 §3.1-3.2).

Grid convention: cell ``(i, j)`` compares frame ``i`` of clip A (rows, KG04's M1, vertical axis)
with frame ``j`` of clip B (columns, M2). "Top" is ``i + 1``, "right" is ``j + 1``; paths are
monotone: every step is up ``(1, 0)``, right ``(0, 1)`` or diagonal ``(1, 1)``.

Slope rule (KG04 §3.1 "at most k frames of one motion can be mapped to a single frame of the
other"): a path holds at most ``k`` cells in one row or column in a row, i.e. at most ``k − 1``
consecutive steps along one axis (``max_run = k − 1``), which keeps its slope in [1/k, k].

Pieces (single resolution, dense grids, numba-compiled loops):

* :func:`local_minima` — horizontal / vertical 1-D minima (KG04 §3.1), O(Fa·Fb).
* :func:`valid_region` — minima extended along their minimum directions while the value stays
  below ``(1 + a)`` times theirs (KG04 §3.1, Fig. 5), O(Fa·Fb · extension).
* :func:`find_chains` — chains of minima grown up / right / up-right under the slope rule,
  short ones dropped (KG04 §3.2), O(minima).
* :func:`find_bridges` — least-average-cost paths inside the valid region from every chain cell to
  the cells of other chains within Manhattan length L (KG04 §3.2); each search covers only the
  cells reachable from its start inside the valid region: O(chain cells · reached cells · k),
  at most O(chain cells · L² · k).
* :func:`build_web_full` — all of the above on one grid.

:func:`build_web` builds the web at the coarsest rate from a full grid, then refines it rate by
rate (KG04 §3.2, Fig. 8): each chain is padded by one coarse cell and upsampled into a band,
its endpoints move to the smallest cells near the old ones, and an optimal (least total cost,
slope-ruled) path joins them inside the band; each bridge likewise, with endpoints on the refined
chains it joins. Only the cells of the bands are evaluated at the finer rates (cell by cell,
``tasks.distance.cell_distance``, once per cell however many bands overlap it), so a fine level
costs linearly in the cells of its search regions rather than Fa·Fb.
"""

from __future__ import annotations

import math

import numpy as np
from motionweb.store.params import Params
from motionweb.store.web import MatchWeb, empty_cells
from motionweb.tasks.distance import (
    ClipOperands,
    DTypeLike,
    PreparedFeatures,
    cell_distance,
    distance_grid_prepared,
    prepare_operands_pair,
)
from numba import njit


class MatchWebParams(Params):
    """Match webs (design §4, KG04 §3.1-3.2)."""

    valid_a: float = 0.15
    slope_k: int = 3
    min_chain_s: float = 0.25
    bridge_max_s: float = 2.0
    self_band_s: float = 0.25
    keep_grids: bool = False



INF = np.inf

# ----------------------------------------------------------------------------------------------
# parameters
# ----------------------------------------------------------------------------------------------


def max_run(slope_k: int) -> int:
    """Consecutive steps allowed along one axis: ``k − 1`` (k cells per row/column, KG04 §3.1)."""
    if slope_k < 1:
        raise ValueError(f"slope_k must be >= 1, got {slope_k}")
    return int(slope_k) - 1


def min_chain_extent(cfg: MatchWebParams, rate: float) -> int:
    """Frames a chain must span (max of its row and column extents) to be kept (KG04: 0.25 s)."""
    return math.ceil(cfg.min_chain_s * rate - 1e-9)


def bridge_cells(cfg: MatchWebParams, rate: float) -> int:
    """Bridge Manhattan length bound L in cells: bridges satisfy Δi + Δj < L (KG04: 2 s)."""
    return max(1, math.ceil(cfg.bridge_max_s * rate - 1e-9))


def self_band(cfg: MatchWebParams, rate: float) -> int:
    """Half-width in cells of the ignored diagonal band of a self pair (|i − j| ≤ band)."""
    return math.floor(cfg.self_band_s * rate + 1e-9)


# ----------------------------------------------------------------------------------------------
# dense single-resolution pieces
# ----------------------------------------------------------------------------------------------


def _as_grid(grid: np.ndarray) -> np.ndarray:
    """Grids enter the kernels as C-contiguous float32 (one compiled signature each)."""
    return np.ascontiguousarray(grid, dtype=np.float32)


@njit(cache=True)
def _local_minima(g: np.ndarray) -> np.ndarray:
    fa, fb = g.shape
    out = np.zeros((fa, fb), dtype=np.uint8)
    for i in range(fa):
        for j in range(fb):
            v = g[i, j]
            if not v < INF:
                continue
            m = 0
            # horizontal: strict against the left neighbour, non-strict against the right one,
            # so a plateau yields one minimum (its leftmost cell)
            if (j == 0 or v < g[i, j - 1]) and (j == fb - 1 or v <= g[i, j + 1]):
                m |= 1
            if (i == 0 or v < g[i - 1, j]) and (i == fa - 1 or v <= g[i + 1, j]):
                m |= 2
            out[i, j] = m
    return out


def local_minima(grid: np.ndarray) -> np.ndarray:
    """1-D local minima of a grid (KG04 §3.1): uint8, bit 1 horizontal, bit 2 vertical.

    A cell is a horizontal minimum when it is below its left neighbour and not above its right
    neighbour (missing neighbours at the border do not count); vertical likewise with the cells
    below and above. Infinite cells (ignored band) are never minima. O(Fa·Fb).
    """
    return _local_minima(_as_grid(grid))


@njit(cache=True)
def _valid_region(g: np.ndarray, minima: np.ndarray, a: float) -> np.ndarray:
    fa, fb = g.shape
    out = np.zeros((fa, fb), dtype=np.bool_)
    for i in range(fa):
        for j in range(fb):
            m = minima[i, j]
            if m == 0:
                continue
            out[i, j] = True
            lim = (1.0 + a) * g[i, j]
            if m & 1:
                jj = j - 1
                while jj >= 0 and g[i, jj] < lim:
                    out[i, jj] = True
                    jj -= 1
                jj = j + 1
                while jj < fb and g[i, jj] < lim:
                    out[i, jj] = True
                    jj += 1
            if m & 2:
                ii = i - 1
                while ii >= 0 and g[ii, j] < lim:
                    out[ii, j] = True
                    ii -= 1
                ii = i + 1
                while ii < fa and g[ii, j] < lim:
                    out[ii, j] = True
                    ii += 1
    return out


def valid_region(grid: np.ndarray, minima: np.ndarray, a: float) -> np.ndarray:
    """The valid region (KG04 §3.1, Fig. 5): bool (Fa, Fb).

    Every minimum is extended along the direction(s) in which it is a minimum until a cell whose
    value is at least ``(1 + a)`` times the minimum's is reached (that cell excluded).
    """
    return _valid_region(_as_grid(grid), np.ascontiguousarray(minima, dtype=np.uint8), float(a))


@njit(cache=True)
def _find_chains(g: np.ndarray, minima: np.ndarray, mrun: int, min_extent: int):
    fa, fb = g.shape
    used = np.zeros((fa, fb), dtype=np.bool_)
    n_min = 0
    for i in range(fa):
        for j in range(fb):
            if minima[i, j] != 0:
                n_min += 1
    ci = np.empty(n_min, dtype=np.int32)
    cj = np.empty(n_min, dtype=np.int32)
    offsets = np.zeros(n_min + 1, dtype=np.int64)
    n_chains = 0
    w = 0
    for i in range(fa):
        for j in range(fb):
            if minima[i, j] == 0 or used[i, j]:
                continue
            start = w
            ci[w] = i
            cj[w] = j
            w += 1
            used[i, j] = True
            ii = i
            jj = j
            r = 0  # >0: run of up steps, <0: run of right steps, 0: after a diagonal
            while True:
                best = INF
                bi = -1
                bj = -1
                br = 0
                if (ii + 1 < fa and jj + 1 < fb and minima[ii + 1, jj + 1] != 0 and not used[ii + 1, jj + 1]
                        and g[ii + 1, jj + 1] < best):
                    best = g[ii + 1, jj + 1]
                    bi, bj, br = ii + 1, jj + 1, 0
                nr = r + 1 if r > 0 else 1
                if (nr <= mrun and ii + 1 < fa and minima[ii + 1, jj] != 0 and not used[ii + 1, jj]
                        and g[ii + 1, jj] < best):
                    best = g[ii + 1, jj]
                    bi, bj, br = ii + 1, jj, nr
                nr = r - 1 if r < 0 else -1
                if (-nr <= mrun and jj + 1 < fb and minima[ii, jj + 1] != 0 and not used[ii, jj + 1]
                        and g[ii, jj + 1] < best):
                    best = g[ii, jj + 1]
                    bi, bj, br = ii, jj + 1, nr
                if bi < 0:
                    break
                ci[w] = bi
                cj[w] = bj
                w += 1
                used[bi, bj] = True
                ii, jj, r = bi, bj, br
            if max(ii - i, jj - j) >= min_extent:
                n_chains += 1
                offsets[n_chains] = w
            else:  # too short: release its minima for later chains
                for t in range(start, w):
                    used[ci[t], cj[t]] = False
                w = start
    cells = np.empty((w, 2), dtype=np.int32)
    cells[:, 0] = ci[:w]
    cells[:, 1] = cj[:w]
    return cells, offsets[: n_chains + 1].copy()


def find_chains(grid: np.ndarray, minima: np.ndarray, slope_k: int, min_extent: int) -> tuple[np.ndarray, np.ndarray]:
    """Chains of 1-D minima (KG04 §3.2): ``(cells (N, 2) int32, offsets (C + 1,) int64)``.

    Minima are visited in row-major order; each one not yet on a chain starts a chain (so every
    minimum with no minimum to its left, below or below-left starts one, as in KG04), grown by
    repeatedly taking the smallest unused minimum among the top, right and top-right cells that the
    slope rule allows. Chains spanning fewer than ``min_extent`` frames (max of row and column
    extents) are dropped and their minima released. O(Fa·Fb) scan plus O(minima) growth.
    """
    return _find_chains(_as_grid(grid), np.ascontiguousarray(minima, dtype=np.uint8),
                        max_run(slope_k), int(min_extent))


# ----------------------------------------------------------------------------------------------
# slope-ruled dynamic programming on a band (rows with one column interval each)
# ----------------------------------------------------------------------------------------------


@njit(cache=True)
def band_index(lo: np.ndarray, hi: np.ndarray, off: np.ndarray, t: int, j: int) -> int:
    if t < 0 or t >= lo.shape[0] or j < lo[t] or j > hi[t]:
        return -1
    return off[t] + j - lo[t]


@njit(cache=True)
def band_dp(lo, hi, off, vals, init, flags, mrun, cost, length, ptr) -> None:
    """Least-total-cost monotone paths under the slope rule, on a band.

    Band row ``t`` covers columns ``lo[t]..hi[t]``; cell (t, j) is flat index
    ``off[t] + j − lo[t]``. ``vals``: cell costs (inf = blocked); ``init``: start cost of source
    cells (inf elsewhere); ``flags``: 1 blocked, 2 terminal (may be entered, not left).
    State ``s = r + mrun`` with r > 0 a run of up steps, r < 0 of right steps, 0 after a diagonal
    or at a source. Outputs per (cell, state): total cost, cell count, predecessor state
    (−1 at a source, −2 unreached). O(cells · k) with the predecessors' flat indices carried
    along the rows (no per-cell index search).
    """
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
            for s in range(ns):
                cost[k, s] = INF
                length[k, s] = 0
                ptr[k, s] = -2
            v = vals[k]
            if not v < INF or flags[k] == 1:
                continue
            if init[k] < INF:
                cost[k, c0] = init[k]
                length[k, c0] = 1
                ptr[k, c0] = -1
            if plo <= j - 1 <= phi and flags[pbase + j - 1] != 2:
                kd = pbase + j - 1
                for s in range(ns):
                    c = cost[kd, s] + v
                    if c < cost[k, c0]:
                        cost[k, c0] = c
                        length[k, c0] = length[kd, s] + 1
                        ptr[k, c0] = s
            if mrun > 0:
                if plo <= j <= phi and flags[pbase + j] != 2:
                    kv = pbase + j
                    # up: any state but a full run of up steps enters state r + 1 (r > 0) or 1
                    for s in range(ns):
                        r = s - c0
                        nr = r + 1 if r > 0 else 1
                        if nr > mrun:
                            continue
                        c = cost[kv, s] + v
                        if c < cost[k, c0 + nr]:
                            cost[k, c0 + nr] = c
                            length[k, c0 + nr] = length[kv, s] + 1
                            ptr[k, c0 + nr] = s
                if j > lo[t] and flags[k - 1] != 2:
                    kh = k - 1
                    for s in range(ns):
                        r = s - c0
                        nr = r - 1 if r < 0 else -1
                        if -nr > mrun:
                            continue
                        c = cost[kh, s] + v
                        if c < cost[k, c0 + nr]:
                            cost[k, c0 + nr] = c
                            length[k, c0 + nr] = length[kh, s] + 1
                            ptr[k, c0 + nr] = s


@njit(cache=True)
def band_backtrack(row0, lo, hi, off, ptr, t, j, s, mrun) -> np.ndarray:
    """Cells (n, 2) (absolute rows) of the path ending at band cell (t, j) in state s."""
    c0 = mrun
    n = 0
    ti = np.empty(lo.shape[0] + (hi.max() - lo.min()) + 2, dtype=np.int64)
    tj = np.empty_like(ti)
    while True:
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


@njit(cache=True)
def best_state_total(cost, k) -> int:
    best = 0
    for s in range(cost.shape[1]):
        if cost[k, s] < cost[k, best]:
            best = s
    return best


@njit(cache=True)
def _best_state_avg(cost, length, k) -> tuple[int, float]:
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


# ----------------------------------------------------------------------------------------------
# bridges (dense)
# ----------------------------------------------------------------------------------------------


@njit(cache=True)
def _triangle(g, valid, gid, chain_of, c, i0, j0, L, lo, hi, off, vals, init, flags, src_a, src_b, row_v,
              row_f) -> tuple[int, int]:
    """Fill the band of a bridge search from (i0, j0): the cells (i0 + t, j0 + d), t + d < L,
    that a path can reach from the start (KG04 §3.2: "bridges must be inside the valid region",
    which "makes bridge calculation more efficient because the dynamic programming algorithm
    processes fewer cells").

    A cell is reached when it is valid, not a cell of chain ``c`` (other than the start), and
    entered by an up, right or diagonal move from a reached cell that is not a terminal (a cell of
    another chain: entered, not left). Row t keeps only the span of its reached cells and rows stop
    at the first with none, so the band's rows and intervals hold every cell the DP could give a
    finite cost (the slope rule only removes more): the search result is unchanged. Cost
    O(reached cells + their row spans), at most O(L²). ``src_a``, ``src_b``, ``row_v``, ``row_f``
    are (L,) scratch rows. Returns (rows, number of reached terminal cells).
    """
    fa, fb = g.shape
    sp, sc = src_a, src_b  # previous / current row: reached and may be left, by column offset d
    pf, pl = 0, -1  # span of the previous row's entries of sp (empty before row 0)
    n = 0
    nterm = 0
    nt = 0
    for t in range(min(L, fa - i0)):
        i = i0 + t
        dmax = min(fb - 1 - j0, L - 1 - t)
        first = -1
        last = -1
        cf = dmax + 1
        cl = -1
        left = False
        for d in range(pf if t > 0 else 0, dmax + 1):
            below = (pf <= d <= pl and sp[d]) or (pf <= d - 1 <= pl and sp[d - 1])
            if not (left or below or (t == 0 and d == 0)):
                if d > pl + 1:  # only a move from the left could reach further cells
                    break
                sc[d] = False
                row_v[d] = INF
                row_f[d] = 0
                continue
            j = j0 + d
            v = g[i, j] if valid[i, j] else INF
            f = 0
            q = gid[i, j]
            if q >= 0:
                if chain_of[q] == c:
                    if t > 0 or d > 0:
                        f = 1
                elif v < INF:
                    f = 2
            row_v[d] = v
            row_f[d] = f
            reached = v < INF and f != 1
            sc[d] = reached and f != 2
            left = sc[d]
            if reached:
                if first < 0:
                    first = d
                last = d
                if f == 2:
                    nterm += 1
            if sc[d]:
                cf = min(cf, d)
                cl = d
        if first < 0:
            break
        lo[t] = j0 + first
        hi[t] = j0 + last
        off[t] = n
        for d in range(first, last + 1):
            vals[n] = row_v[d]
            flags[n] = row_f[d]
            init[n] = INF
            n += 1
        nt = t + 1
        sp, sc = sc, sp
        pf, pl = cf, cl
        if pl < pf:
            break
    off[nt] = n
    if n > 0:
        init[0] = vals[0]
    return nt, nterm


@njit(cache=True)
def _find_bridges(g, valid, gid, chain_of, cells, offsets, mrun, L):
    nch = offsets.shape[0] - 1
    ncell = L * (L + 1) // 2 + 1
    ns = 2 * mrun + 1
    lo = np.empty(L, np.int64)
    hi = np.empty(L, np.int64)
    off = np.empty(L + 1, np.int64)
    vals = np.empty(ncell, np.float64)
    init = np.empty(ncell, np.float64)
    flags = np.empty(ncell, np.uint8)
    src_a = np.zeros(L, np.bool_)
    src_b = np.zeros(L, np.bool_)
    row_v = np.empty(L, np.float64)
    row_f = np.empty(L, np.uint8)
    cost = np.empty((ncell, ns), np.float64)
    length = np.empty((ncell, ns), np.int32)
    ptr = np.empty((ncell, ns), np.int8)
    best_avg = np.full(nch, INF)
    best_start = np.full(nch, -1, np.int64)
    best_end = np.full(nch, -1, np.int64)  # global chain-cell index of the junction on the target
    touched = np.empty(nch, np.int64)
    junctions = []
    out_i = []
    out_j = []
    out_off = [0]
    for c in range(nch):
        nt_touched = 0
        for p in range(offsets[c], offsets[c + 1]):
            i0 = cells[p, 0]
            j0 = cells[p, 1]
            nt, nterm = _triangle(g, valid, gid, chain_of, c, i0, j0, L, lo, hi, off, vals, init, flags,
                                  src_a, src_b, row_v, row_f)
            if nterm == 0 or not vals[0] < INF:
                continue
            band_dp(lo[:nt], hi[:nt], off[: nt + 1], vals, init, flags, mrun, cost, length, ptr)
            for t in range(nt):
                for j in range(lo[t], hi[t] + 1):
                    k = off[t] + j - lo[t]
                    if flags[k] != 2:
                        continue
                    s, a = _best_state_avg(cost, length, k)
                    if s < 0:
                        continue
                    q = gid[i0 + t, j]
                    d = chain_of[q]
                    if a < best_avg[d]:
                        if best_start[d] < 0:
                            touched[nt_touched] = d
                            nt_touched += 1
                        best_avg[d] = a
                        best_start[d] = p
                        best_end[d] = q
        for u in range(nt_touched):
            d = touched[u]
            p = best_start[d]
            q = best_end[d]
            i0 = cells[p, 0]
            j0 = cells[p, 1]
            nt, nterm = _triangle(g, valid, gid, chain_of, c, i0, j0, L, lo, hi, off, vals, init, flags,
                                  src_a, src_b, row_v, row_f)
            band_dp(lo[:nt], hi[:nt], off[: nt + 1], vals, init, flags, mrun, cost, length, ptr)
            t = cells[q, 0] - i0
            k = off[t] + cells[q, 1] - lo[t]
            s, a = _best_state_avg(cost, length, k)
            path = band_backtrack(i0, lo[:nt], hi[:nt], off[: nt + 1], ptr, t, cells[q, 1], s, mrun)
            junctions.append((c, p - offsets[c], d, q - offsets[d]))
            for r in range(path.shape[0]):
                out_i.append(path[r, 0])
                out_j.append(path[r, 1])
            out_off.append(len(out_i))
            best_avg[d] = INF
            best_start[d] = -1
            best_end[d] = -1
    nb = len(junctions)
    br = np.empty((nb, 4), np.int64)
    for b in range(nb):
        br[b, 0], br[b, 1], br[b, 2], br[b, 3] = junctions[b]
    bc = np.empty((len(out_i), 2), np.int32)
    for r in range(len(out_i)):
        bc[r, 0] = out_i[r]
        bc[r, 1] = out_j[r]
    bo = np.empty(len(out_off), np.int64)
    for r in range(len(out_off)):
        bo[r] = out_off[r]
    return br, bc, bo


def find_bridges(grid: np.ndarray, valid: np.ndarray, chain_cells: np.ndarray, chain_offsets: np.ndarray,
                 slope_k: int, max_len: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bridges between chains (KG04 §3.2): ``(junctions (B, 4), cells (M, 2), offsets (B + 1,))``.

    For each chain C and each of its cells, a slope-ruled least-total-cost DP runs over the cells
    up and right of it with Manhattan length below ``max_len``, inside the valid region; cells of
    C are blocked and cells of other chains end a path (entered, not left). Among all paths from C
    reaching a chain C', the one with the least average cell value is kept as the bridge C → C'
    (so at most one bridge per ordered pair). Junction rows are
    ``(from_chain, index in from_chain, to_chain, index in to_chain)``.
    Each search runs on the cells reachable from its start inside the valid region only (see
    :func:`_triangle`; KG04 §3.2: the valid region "makes bridge calculation more efficient"), and
    starts that reach no other chain skip the DP: cost O(chain cells · reached cells · k), at most
    O(chain cells · L² · k) where the valid region is wide.
    """
    g = _as_grid(grid)
    fa, fb = g.shape
    cells = np.ascontiguousarray(chain_cells, dtype=np.int64).reshape(-1, 2)
    offsets = np.ascontiguousarray(chain_offsets, dtype=np.int64)
    gid = np.full((fa, fb), -1, dtype=np.int64)
    gid[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
    chain_of = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets)).astype(np.int64)
    return _find_bridges(g, np.ascontiguousarray(valid, dtype=np.bool_), gid, chain_of, cells, offsets,
                         max_run(slope_k), int(max_len))


# ----------------------------------------------------------------------------------------------
# full single-resolution build
# ----------------------------------------------------------------------------------------------


def mask_self_band(grid: np.ndarray, band: int) -> np.ndarray:
    """A copy of ``grid`` with cells |i − j| ≤ band set to +inf (the ignored self-pair diagonal)."""
    g = np.array(grid, copy=True)
    fa, fb = g.shape
    for d in range(-band, band + 1):
        if -fa < d < fb:
            idx = np.arange(max(0, -d), min(fa, fb - d))
            g[idx, idx + d] = np.inf
    return g


def _values_at(grid: np.ndarray, cells: np.ndarray) -> np.ndarray:
    if len(cells) == 0:
        return np.zeros(0, np.float32)
    return np.asarray(grid[cells[:, 0], cells[:, 1]], dtype=np.float32)


def build_web_full(grid: np.ndarray, rate: float, cfg: MatchWebParams, self_pair: bool) -> MatchWeb:
    """Match web from a full grid at one rate (KG04 §3.1-3.2; design §4 steps 1-4).

    Self pairs ignore the band |i − j| ≤ ``self_band_s·rate``. Cost: O(Fa·Fb) for minima and the
    valid region, plus the bridge search (see :func:`find_bridges`); memory O(Fa·Fb).
    """
    g = _as_grid(grid)
    if self_pair:
        g = mask_self_band(g, self_band(cfg, rate))
    minima = local_minima(g)
    valid = valid_region(g, minima, cfg.valid_a)
    cells, offsets = find_chains(g, minima, cfg.slope_k, min_chain_extent(cfg, rate))
    br, bcells, boff = find_bridges(g, valid, cells, offsets, cfg.slope_k, bridge_cells(cfg, rate))
    return MatchWeb(
        rate=rate, shape=g.shape, paths_cells=cells, paths_values=_values_at(g, cells), paths_offsets=offsets,
        bridges=br, bridges_cells=bcells, bridges_values=_values_at(g, bcells), bridges_offsets=boff,
        self_pair=self_pair, grid=np.asarray(grid) if cfg.keep_grids else None,
    )


# ----------------------------------------------------------------------------------------------
# coarse to fine (KG04 §3.2, Fig. 8)
# ----------------------------------------------------------------------------------------------


@njit(cache=True)
def upsample_band(cells, s, h, fa, fb):
    """Band of fine cells covering each coarse cell dilated by ``h − 0.5`` coarse cells.

    Coarse cell c covers fine indices [(c − h)·s, (c + h)·s]; returns (row0, lo, hi, off).
    """
    n = cells.shape[0]
    r_min = fa
    r_max = -1
    for q in range(n):
        a = max(0, math.floor((cells[q, 0] - h) * s))
        b = min(fa - 1, math.ceil((cells[q, 0] + h) * s))
        r_min = min(r_min, a)
        r_max = max(r_max, b)
    nr = r_max - r_min + 1
    lo = np.full(nr, fb, np.int64)
    hi = np.full(nr, -1, np.int64)
    for q in range(n):
        a = max(0, math.floor((cells[q, 0] - h) * s))
        b = min(fa - 1, math.ceil((cells[q, 0] + h) * s))
        c1 = max(0, math.floor((cells[q, 1] - h) * s))
        c2 = min(fb - 1, math.ceil((cells[q, 1] + h) * s))
        for r in range(a, b + 1):
            t = r - r_min
            lo[t] = min(lo[t], c1)
            hi[t] = max(hi[t], c2)
    off = np.zeros(nr + 1, np.int64)
    for t in range(nr):
        off[t + 1] = off[t] + hi[t] - lo[t] + 1
    return r_min, lo, hi, off


#: side of the square tiles of the lazily evaluated fine grid of one refinement level
TILE = 32


@njit(cache=True)
def _mark_tiles(cells, offsets, s, h, fa, fb, index) -> None:
    """Mark (``index[ti, tj] = 0``) the TILE×TILE tiles that the bands of ragged paths touch."""
    for p in range(offsets.shape[0] - 1):
        row0, lo, hi, _ = upsample_band(cells[offsets[p]:offsets[p + 1]], s, h, fa, fb)
        for t in range(lo.shape[0]):
            ti = (row0 + t) // TILE
            for tj in range(lo[t] // TILE, hi[t] // TILE + 1):
                index[ti, tj] = 0


@njit(cache=True)
def _alloc_tiles(index):
    """Number the marked tiles; returns their value pool, NaN (not evaluated yet) everywhere."""
    n = 0
    for ti in range(index.shape[0]):
        for tj in range(index.shape[1]):
            if index[ti, tj] >= 0:
                index[ti, tj] = n
                n += 1
    return np.full((n, TILE, TILE), np.nan)


@njit(cache=True)
def _eval_band(row0, lo, hi, off, index, pool, left, left_y, na, right, right_y, nb, band, out) -> None:
    """Distance values on a band's cells (inf inside the ignored self band |i − j| ≤ band).

    Each cell is evaluated once per level: its value is kept in the tile ``pool`` and the bands
    of chains and bridges that overlap read it from there.
    """
    for t in range(lo.shape[0]):
        i = row0 + t
        ti = i // TILE
        ri = i - ti * TILE
        for j in range(lo[t], hi[t] + 1):
            tile = pool[index[ti, j // TILE]]
            v = tile[ri, j % TILE]
            if math.isnan(v):
                if band >= 0 and abs(i - j) <= band:
                    v = INF
                else:
                    v = cell_distance(left, left_y, na, right, right_y, nb, i, j)
                tile[ri, j % TILE] = v
            out[off[t] + j - lo[t]] = v


@njit(cache=True)
def _near_cells(row0, lo, hi, off, ci, cj, radius):
    """Flat indices of band cells within Chebyshev distance ``radius`` of (ci, cj)."""
    nr = lo.shape[0]
    t_lo = max(0, math.floor(ci - radius) - row0)
    t_hi = min(nr - 1, math.ceil(ci + radius) - row0)
    j_lo = math.floor(cj - radius)
    j_hi = math.ceil(cj + radius)
    n = 0
    for t in range(t_lo, t_hi + 1):
        n += max(0, min(hi[t], j_hi) - max(lo[t], j_lo) + 1)
    out = np.empty(n, np.int64)
    n = 0
    for t in range(t_lo, t_hi + 1):
        for j in range(max(lo[t], j_lo), min(hi[t], j_hi) + 1):
            out[n] = off[t] + j - lo[t]
            n += 1
    return out


@njit(cache=True)
def _solve(row0, lo, hi, off, vals, sources, targets, mrun, by_average):
    """Best slope-ruled path in a band from any source to any target, by total or average cost.

    Returns its cells (n, 2) (absolute), or an empty array when no target is reachable.
    """
    n = off[-1]
    ns = 2 * mrun + 1
    init = np.full(n, INF)
    for k in sources:
        init[k] = vals[k]
    cost = np.empty((n, ns), np.float64)
    length = np.empty((n, ns), np.int32)
    ptr = np.empty((n, ns), np.int8)
    band_dp(lo, hi, off, vals, init, np.zeros(n, np.uint8), mrun, cost, length, ptr)
    best = INF
    bk = -1
    bs = 0
    for k in targets:
        for s in range(ns):
            if length[k, s] == 0:
                continue
            v = cost[k, s] / length[k, s] if by_average else cost[k, s]
            if v < best:
                best = v
                bk = k
                bs = s
    if bk < 0:
        return np.zeros((0, 2), np.int32)
    t = 0
    while off[t + 1] <= bk:
        t += 1
    return band_backtrack(row0, lo, hi, off, ptr, t, lo[t] + bk - off[t], bs, mrun)


@njit(cache=True)
def _argmin_of(vals, idx):
    best = INF
    out = np.zeros(0, np.int64)
    for k in idx:
        if vals[k] < best:
            best = vals[k]
            out = np.array([k], np.int64)
    return out


@njit(cache=True)
def _flat_index(row0, lo, hi, off, i, j) -> int:
    return band_index(lo, hi, off, i - row0, j)


@njit(cache=True)
def _refine_chains(cells, offsets, s, h, radius, fa, fb, index, pool, left, left_y, na, right, right_y, nb, band,
                   mrun):
    """Refine every chain (KG04 Fig. 8); returns (cells, values, offsets, new id of each chain)."""
    nch = offsets.shape[0] - 1
    new_id = np.full(nch, -1, np.int64)
    out_c = []
    out_v = []
    n_out = 0
    for p in range(nch):
        cc = cells[offsets[p]:offsets[p + 1]]
        row0, lo, hi, off = upsample_band(cc, s, h, fa, fb)
        vals = np.empty(off[-1], np.float64)
        _eval_band(row0, lo, hi, off, index, pool, left, left_y, na, right, right_y, nb, band, vals)
        i0 = cc[0, 0] * s
        j0 = cc[0, 1] * s
        i1 = cc[-1, 0] * s
        j1 = cc[-1, 1] * s
        src = _argmin_of(vals, _near_cells(row0, lo, hi, off, i0, j0, radius))
        dst = _argmin_of(vals, _near_cells(row0, lo, hi, off, i1, j1, radius))
        path = _solve(row0, lo, hi, off, vals, src, dst, mrun, False)
        if path.shape[0] == 0:  # fall back on the upsampled endpoints themselves
            k0 = _flat_index(row0, lo, hi, off, math.floor(i0 + 0.5), math.floor(j0 + 0.5))
            k1 = _flat_index(row0, lo, hi, off, math.floor(i1 + 0.5), math.floor(j1 + 0.5))
            if k0 >= 0 and k1 >= 0:
                path = _solve(row0, lo, hi, off, vals, np.array([k0]), np.array([k1]), mrun, False)
        if path.shape[0] == 0:
            continue
        pv = np.empty(path.shape[0], np.float32)
        for q in range(path.shape[0]):
            pv[q] = vals[_flat_index(row0, lo, hi, off, path[q, 0], path[q, 1])]
        new_id[p] = n_out
        n_out += 1
        out_c.append(path)
        out_v.append(pv)
    return _concat_cells(out_c), _concat_values(out_v), _offsets_of(out_c), new_id


@njit(cache=True)
def _concat_cells(parts):
    n = 0
    for x in parts:
        n += x.shape[0]
    out = np.empty((n, 2), np.int32)
    n = 0
    for x in parts:
        out[n:n + x.shape[0]] = x
        n += x.shape[0]
    return out


@njit(cache=True)
def _concat_values(parts):
    n = 0
    for x in parts:
        n += x.shape[0]
    out = np.empty(n, np.float32)
    n = 0
    for x in parts:
        out[n:n + x.shape[0]] = x
        n += x.shape[0]
    return out


@njit(cache=True)
def _offsets_of(parts):
    out = np.zeros(len(parts) + 1, np.int64)
    for q in range(len(parts)):
        out[q + 1] = out[q] + parts[q].shape[0]
    return out


@njit(cache=True)
def _path_cells_near(row0, lo, hi, off, path, ci, cj, radius):
    """Band indices of the cells of ``path`` within Chebyshev ``radius`` of (ci, cj)."""
    n = 0
    tmp = np.empty(path.shape[0], np.int64)
    for q in range(path.shape[0]):
        if abs(path[q, 0] - ci) <= radius and abs(path[q, 1] - cj) <= radius:
            k = _flat_index(row0, lo, hi, off, path[q, 0], path[q, 1])
            if k >= 0:
                tmp[n] = k
                n += 1
    return tmp[:n].copy()


@njit(cache=True)
def _position(path, i, j) -> int:
    for q in range(path.shape[0]):
        if path[q, 0] == i and path[q, 1] == j:
            return q
    return -1


@njit(cache=True)
def _refine_bridges(old_cells, old_offsets, bridges, b_cells, b_offsets, new_id, new_cells, new_offsets,
                    s, h, radius, fa, fb, index, pool, left, left_y, na, right, right_y, nb, band, mrun):
    """Refine every bridge whose chains survived; returns (junctions, cells, values, offsets)."""
    junctions = []
    out_c = []
    out_v = []
    for b in range(bridges.shape[0]):
        p = bridges[b, 0]
        q = bridges[b, 2]
        np_ = new_id[p]
        nq = new_id[q]
        if np_ < 0 or nq < 0:
            continue
        cc = b_cells[b_offsets[b]:b_offsets[b + 1]]
        row0, lo, hi, off = upsample_band(cc, s, h, fa, fb)
        vals = np.empty(off[-1], np.float64)
        _eval_band(row0, lo, hi, off, index, pool, left, left_y, na, right, right_y, nb, band, vals)
        sp = new_cells[new_offsets[np_]:new_offsets[np_ + 1]]
        dp = new_cells[new_offsets[nq]:new_offsets[nq + 1]]
        a = old_offsets[p] + bridges[b, 1]
        c = old_offsets[q] + bridges[b, 3]
        src = _path_cells_near(row0, lo, hi, off, sp, old_cells[a, 0] * s, old_cells[a, 1] * s, radius)
        dst = _path_cells_near(row0, lo, hi, off, dp, old_cells[c, 0] * s, old_cells[c, 1] * s, radius)
        if src.shape[0] == 0 or dst.shape[0] == 0:
            continue
        path = _solve(row0, lo, hi, off, vals, src, dst, mrun, True)
        if path.shape[0] == 0:
            continue
        pv = np.empty(path.shape[0], np.float32)
        for u in range(path.shape[0]):
            pv[u] = vals[_flat_index(row0, lo, hi, off, path[u, 0], path[u, 1])]
        ia = _position(sp, path[0, 0], path[0, 1])
        ic = _position(dp, path[-1, 0], path[-1, 1])
        junctions.append((np_, np.int64(ia), nq, np.int64(ic)))
        out_c.append(path)
        out_v.append(pv)
    jn = np.empty((len(junctions), 4), np.int64)
    for u in range(len(junctions)):
        jn[u, 0], jn[u, 1], jn[u, 2], jn[u, 3] = junctions[u]
    return jn, _concat_cells(out_c), _concat_values(out_v), _offsets_of(out_c)


def refine_web(web: MatchWeb, pa: PreparedFeatures, pb: PreparedFeatures, rate: float, cfg: MatchWebParams,
               self_pair: bool, pad: float = 1.0) -> MatchWeb:
    """One coarse-to-fine step (KG04 §3.2, Fig. 8) from ``web`` to ``rate``.

    (1-2) each chain is padded by ``pad`` coarse cells and upsampled into a band, and only the
    band's cells are evaluated; (3) the new endpoints are the smallest cells within one coarse
    cell (``ceil(s)`` fine cells) of the upsampled old ones; (4) the least-total-cost slope-ruled
    path in the band joins them. Each bridge is refined likewise inside its own band, from any
    cell of its refined from-chain to any cell of its refined to-chain within one coarse cell of
    the upsampled old junctions, keeping the least-average path. Chains or bridges with no
    feasible path are dropped (with their bridges). The union of all bands is evaluated once, each
    cell on first use, into TILE×TILE tiles allocated for the tiles the bands touch (chain and
    bridge bands overlap, ~2× on real webs). Cost: O(union of band cells · P) for the values plus
    O(band cells · k) for the DPs and O(Fa·Fb / TILE²) for the tile index — linear in the search
    regions.
    """
    fa, fb = pa.n_frames, pb.n_frames
    s = float(rate / web.rate)
    h = 0.5 + float(pad)
    radius = math.ceil(s)
    mrun = max_run(cfg.slope_k)
    band_w = self_band(cfg, rate) if self_pair else -1
    old_cells = web.paths_cells.astype(np.int64)
    old_bcells = web.bridges_cells.astype(np.int64)
    index = np.full((-(-fa // TILE), -(-fb // TILE)), -1, np.int64)
    _mark_tiles(old_cells, web.paths_offsets, s, h, fa, fb, index)
    _mark_tiles(old_bcells, web.bridges_offsets, s, h, fa, fb, index)
    pool = _alloc_tiles(index)
    feats = (index, pool, pa.left, pa.left_y, pa.norms, pb.right, pb.right_y, pb.norms)
    pc, pv, po, new_id = _refine_chains(old_cells, web.paths_offsets, s, h, radius, fa, fb, *feats, band_w, mrun)
    if web.n_bridges:
        jn, bc, bv, bo = _refine_bridges(old_cells, web.paths_offsets, web.bridges, old_bcells, web.bridges_offsets,
                                         new_id, pc.astype(np.int64), po, s, h, radius, fa, fb, *feats, band_w, mrun)
    else:
        jn, bc, bv, bo = np.zeros((0, 4), np.int64), empty_cells(), np.zeros(0, np.float32), np.zeros(1, np.int64)
    return MatchWeb(rate=rate, shape=(fa, fb), paths_cells=pc, paths_values=pv, paths_offsets=po, bridges=jn,
                    bridges_cells=bc, bridges_values=bv, bridges_offsets=bo, self_pair=self_pair)


def build_web(fa_by_rate: dict[float, np.ndarray], fb_by_rate: dict[float, np.ndarray], weights: np.ndarray,
              cfg: MatchWebParams, self_pair: bool, dtype: DTypeLike = np.float32) -> MatchWeb:
    """Match web between clips A and B, coarse to fine across the rates given (KG04 §3.2, Fig. 8).

    ``fa_by_rate[r]``: (F_r, P, 3) clouds of A at r Hz (``tasks.features.clip_features``), same
    rates for B; the highest rate is the working rate of the result. See :func:`build_web_operands`,
    which this calls after preparing both clips (O((Fa + Fb)·P) per rate).
    """
    oa = {float(r): ClipOperands.of(f, weights, dtype) for r, f in fa_by_rate.items()}
    ob = {float(r): oa[float(r)] if f is fa_by_rate.get(r) else ClipOperands.of(f, weights, dtype)
          for r, f in fb_by_rate.items()}
    return build_web_operands(oa, ob, cfg, self_pair)


def build_web_operands(oa_by_rate: dict[float, ClipOperands], ob_by_rate: dict[float, ClipOperands],
                       cfg: MatchWebParams, self_pair: bool) -> MatchWeb:
    """Match web from per-clip operands (``tasks.distance.ClipOperands``, prepared once per clip
    and rate, e.g. once per index worker; KG04 §3.2, Fig. 8).

    The coarsest level evaluates its full grid (O(Fa·Fb·P) at the coarsest rate, 1/9 of the
    working-rate cost for 10 → 30 Hz) and runs :func:`build_web_full`; every finer level
    evaluates only the cells of the padded, upsampled chains and bridges (:func:`refine_web`).
    Per level the pair's shared vertical shift finishes the operands (O((Fa + Fb)·P)). With
    ``cfg.keep_grids`` the full grid at the working rate is also computed and kept (O(Fa·Fb)
    memory).
    """
    rates = sorted(oa_by_rate)
    if sorted(ob_by_rate) != rates or not rates:
        raise ValueError(f"clips A and B must have features at the same rates, got {sorted(oa_by_rate)} "
                         f"and {sorted(ob_by_rate)}")
    r0 = rates[0]
    grid0 = distance_grid_prepared(*prepare_operands_pair(oa_by_rate[r0], ob_by_rate[r0]))
    web = build_web_full(grid0, r0, cfg.model_copy(update={"keep_grids": False}), self_pair)
    for r in rates[1:]:
        pa, pb = prepare_operands_pair(oa_by_rate[r], ob_by_rate[r])
        web = refine_web(web, pa, pb, r, cfg, self_pair)
        if cfg.keep_grids and r == rates[-1]:
            web.grid = distance_grid_prepared(pa, pb)
    if cfg.keep_grids and len(rates) == 1:
        web.grid = grid0
    return web
