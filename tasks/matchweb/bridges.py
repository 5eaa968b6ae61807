"""Bridges between the chains of a dense grid (KG04 §3.2; design §4).

:func:`find_bridges` — least-average-cost paths inside the valid region from every chain cell to
the cells of other chains within Manhattan length L; each search covers only the cells reachable
from its start inside the valid region: O(chain cells · reached cells · k), at most
O(chain cells · L² · k).
"""

from __future__ import annotations

import numpy as np
from motionweb.tasks.matchweb.band import band_backtrack, band_dp, best_state_avg
from motionweb.tasks.matchweb.minima import as_grid
from motionweb.tasks.matchweb.params import INF, max_run
from motionweb.store.numba_cache import njit


@njit(cache=True, nogil=True)
def _triangle(g, valid, gid, chain_of, c, i0, j0, L, mrun, lo, hi, off, vals, init, flags, src_a, src_b, row_v,
              row_f) -> tuple[int, int]:
    """Fill the band of a bridge search from (i0, j0): the cells (i0 + t, j0 + d), t + d < L,
    that a path can reach from the start (KG04 §3.2: "bridges must be inside the valid region",
    which "makes bridge calculation more efficient because the dynamic programming algorithm
    processes fewer cells").

    A cell is reached when it is valid, not a cell of chain ``c`` (other than the start), inside
    the slope rule's cone from the start (row t, columns t // (mrun + 1) .. mrun + (mrun + 1)·t:
    each run of at most ``mrun`` steps along one axis ends with a step along the other, so no
    slope-ruled path reaches a cell outside it; this halves the triangle), and entered by an up,
    right or diagonal move from a reached cell that is not a terminal (a cell of another chain:
    entered, not left). Every cell of a slope-ruled path from the start is reached (by induction
    along the path), and row t keeps only the span of its reached cells and rows stop at the
    first with none, so the band holds every cell the DP could give a finite cost, and each with
    the same finite-cost neighbours: the search result is unchanged. Cost O(reached cells + their
    row spans), at most O(L²). ``src_a``, ``src_b``, ``row_v``, ``row_f``
    are (L,) scratch rows. Returns (rows, number of reached terminal cells).

    Bounds: writes at most L·(L+1)/2 cells (row t holds columns d ≤ L − 1 − t: the triangle of
    Manhattan length < L) into ``vals``/``init``/``flags`` (L·(L+1)/2 + 1), at most L rows into
    ``lo``/``hi`` and L + 1 into ``off``, and column offsets d < L into the (L,) scratch rows.
    """
    fa, fb = g.shape
    sp, sc = src_a, src_b  # previous / current row: reached and may be left, by column offset d
    pf, pl = 0, -1  # span of the previous row's entries of sp (empty before row 0)
    n = 0
    nterm = 0
    nt = 0
    for t in range(min(L, fa - i0)):
        i = i0 + t
        # the slope rule's cone: a path reaches row t only at columns t // (mrun + 1) .. mrun + (mrun + 1)·t
        dmax = min(fb - 1 - j0, L - 1 - t, mrun + (mrun + 1) * t)
        first = -1
        last = -1
        cf = dmax + 1
        cl = -1
        left = False
        for d in range(max(pf if t > 0 else 0, t // (mrun + 1)), dmax + 1):
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


@njit(cache=True, nogil=True)
def _keep_path(paths, lengths, slot, path, L):
    """Copy ``path`` (n, 2) into ``paths[slot]``, growing ``paths`` (cap, L, 2) by doubling until
    ``slot`` is inside it; returns the buffer holding it (``lengths[u]``: the cells kept in slot u).

    Bounds: a bridge search's path starts at its search's start cell and moves by unit steps up
    or right inside the triangle of Manhattan length < L, so it has at most L cells (checked:
    a longer one raises instead of writing past the row); the buffer is grown past ``slot``, and
    ``lengths`` (≥ slot + 1 entries) bounds the rows copied."""
    n = path.shape[0]
    if n > L:
        raise ValueError("find_bridges: a bridge path longer than its search triangle")
    if slot >= paths.shape[0]:
        cap = paths.shape[0]
        while cap <= slot:
            cap *= 2
        grown = np.empty((cap, L, 2), np.int64)
        for u in range(paths.shape[0]):
            for r in range(lengths[u]):
                grown[u, r, 0] = paths[u, r, 0]
                grown[u, r, 1] = paths[u, r, 1]
        paths = grown
    for r in range(n):
        paths[slot, r, 0] = path[r, 0]
        paths[slot, r, 1] = path[r, 1]
    lengths[slot] = n
    return paths


@njit(cache=True, nogil=True)
def _find_bridges(g, valid, gid, chain_of, cells, offsets, mrun, L):
    """Bounds: each search's band (:func:`_triangle`) holds at most L·(L+1)/2 cells, the size of
    its DP buffers; at most one bridge per target chain and start chain (``touched``, ``slot`` and
    ``lengths``: nch); each kept path has at most L cells (:func:`_keep_path`).

    A target's best path is backtracked when it is found (the DP of its start is at hand then),
    so no search runs twice: each start's triangle and DP once, O(L) per improvement."""
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
    slot = np.empty(nch, np.int64)  # where a touched target's best path is kept
    lengths = np.zeros(nch, np.int64)
    paths = np.empty((max(1, min(nch, 16)), max(1, L), 2), np.int64)
    junctions = []
    out_i = []
    out_j = []
    out_off = [0]
    for c in range(nch):
        nt_touched = 0
        for p in range(offsets[c], offsets[c + 1]):
            i0 = cells[p, 0]
            j0 = cells[p, 1]
            nt, nterm = _triangle(g, valid, gid, chain_of, c, i0, j0, L, mrun, lo, hi, off, vals, init, flags,
                                  src_a, src_b, row_v, row_f)
            if nterm == 0 or not vals[0] < INF:
                continue
            band_dp(lo[:nt], hi[:nt], off[: nt + 1], vals, init, flags, mrun, cost, length, ptr)
            for t in range(nt):
                for j in range(lo[t], hi[t] + 1):
                    k = off[t] + j - lo[t]
                    if flags[k] != 2:
                        continue
                    s, a = best_state_avg(cost, length, k)
                    if s < 0:
                        continue
                    q = gid[i0 + t, j]
                    d = chain_of[q]
                    if a < best_avg[d]:
                        if best_start[d] < 0:
                            touched[nt_touched] = d
                            slot[d] = nt_touched
                            nt_touched += 1
                        best_avg[d] = a
                        best_start[d] = p
                        best_end[d] = q
                        path = band_backtrack(i0, lo[:nt], hi[:nt], off[: nt + 1], ptr, t, j, s, mrun)
                        paths = _keep_path(paths, lengths, slot[d], path, L)
        for u in range(nt_touched):
            d = touched[u]
            p = best_start[d]
            q = best_end[d]
            junctions.append((c, p - offsets[c], d, q - offsets[d]))
            for r in range(lengths[u]):
                out_i.append(paths[u, r, 0])
                out_j.append(paths[u, r, 1])
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
    O(chain cells · L² · k) where the valid region is wide; each start's search runs once (a
    target's best path is backtracked when found, O(L) per improvement).
    """
    g = as_grid(grid)
    fa, fb = g.shape
    cells = np.ascontiguousarray(chain_cells, dtype=np.int64).reshape(-1, 2)
    offsets = np.ascontiguousarray(chain_offsets, dtype=np.int64)
    valid = np.asarray(valid)
    if valid.shape != g.shape:
        raise ValueError(f"the valid region has shape {valid.shape}, the grid {g.shape}")
    if int(max_len) < 0:
        raise ValueError(f"the bridge length bound must be >= 0 cells, got {max_len}")
    if (len(offsets) < 1 or offsets[0] != 0 or offsets[-1] != len(cells) or np.any(np.diff(offsets) < 0)
            or (len(cells) and (cells.min() < 0 or cells[:, 0].max() >= fa or cells[:, 1].max() >= fb))):
        raise ValueError("chain cells and offsets do not describe chains inside the grid")
    gid = np.full((fa, fb), -1, dtype=np.int64)
    gid[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
    chain_of = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets)).astype(np.int64)
    return _find_bridges(g, np.ascontiguousarray(valid, dtype=np.bool_), gid, chain_of, cells, offsets,
                         max_run(slope_k), int(max_len))
