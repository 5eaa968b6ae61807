"""Coarse-to-fine refinement of a match web (KG04 §3.2, Fig. 8; design §4).

Each chain is padded by one coarse cell and upsampled into a band (:func:`upsample_band`), its
endpoints move to the smallest cells near the old ones, and an optimal (least total cost,
slope-ruled) path joins them inside the band; each bridge likewise, with endpoints on the refined
chains it joins. Only cells of the bands are evaluated at the finer rates (run by run along the
rows, ``tasks.distance.distance_row``, once per cell however many bands overlap it), and of each band
only the cells near the old endpoints and those a slope-ruled path between the new ones can cross
(:func:`_crop_to_ends`): the paths are those of the whole band, so a fine level costs linearly in
the cells of its search regions rather than Fa·Fb.
"""

from __future__ import annotations

import math

import numpy as np
from motionweb.store.web import MatchWeb, empty_cells
from motionweb.tasks.distance import PreparedFeatures, distance_row
from motionweb.tasks.matchweb.band import band_backtrack, band_dp, band_index
from motionweb.tasks.matchweb.params import INF, MatchWebParams, max_run, self_band
from motionweb.store.numba_cache import njit


@njit(cache=True, nogil=True)
def upsample_band(cells, s, h, fa, fb):
    """Band of fine cells covering each coarse cell dilated by ``h − 0.5`` coarse cells.

    Coarse cell c covers fine indices [(c − h)·s, (c + h)·s]; returns (row0, lo, hi, off).

    Bounds: rows and columns are clipped to the fa × fb grid; a row no cell covers (cells that do
    not form a connected path) is empty (lo = fb, hi = −1) and counts 0 cells, so ``off`` never
    decreases and every band cell's flat index is below ``off[-1]``; cells all outside the grid
    give a band of no rows.
    """
    n = cells.shape[0]
    r_min = fa
    r_max = -1
    for q in range(n):
        a = max(0, math.floor((cells[q, 0] - h) * s))
        b = min(fa - 1, math.ceil((cells[q, 0] + h) * s))
        c1 = max(0, math.floor((cells[q, 1] - h) * s))
        c2 = min(fb - 1, math.ceil((cells[q, 1] + h) * s))
        if a > b or c1 > c2:
            continue
        r_min = min(r_min, a)
        r_max = max(r_max, b)
    if r_max < r_min:
        return 0, np.empty(0, np.int64), np.empty(0, np.int64), np.zeros(1, np.int64)
    nr = r_max - r_min + 1
    lo = np.full(nr, fb, np.int64)
    hi = np.full(nr, -1, np.int64)
    for q in range(n):
        a = max(0, math.floor((cells[q, 0] - h) * s))
        b = min(fa - 1, math.ceil((cells[q, 0] + h) * s))
        c1 = max(0, math.floor((cells[q, 1] - h) * s))
        c2 = min(fb - 1, math.ceil((cells[q, 1] + h) * s))
        if c1 > c2:
            continue
        for r in range(a, b + 1):
            t = r - r_min
            lo[t] = min(lo[t], c1)
            hi[t] = max(hi[t], c2)
    off = np.zeros(nr + 1, np.int64)
    for t in range(nr):
        off[t + 1] = off[t] + max(0, hi[t] - lo[t] + 1)
    return r_min, lo, hi, off


#: side of the square tiles of the lazily evaluated fine grid of one refinement level
TILE = 32

#: how :func:`_solve` ranks paths: chains by total cost, bridges by average cost (KG04 §3.2). Numbers,
#: not the literals True/False, which numba compiles into a specialisation of each solver apiece.
TOTAL = 0
AVERAGE = 1


@njit(cache=True, nogil=True)
def _mark_tiles(cells, offsets, s, h, fa, fb, index) -> None:
    """Mark (``index[ti, tj] = 0``) the TILE×TILE tiles that the bands of ragged paths touch.

    Bounds: band rows and columns lie in the fa × fb grid (:func:`upsample_band`), so the tiles
    marked lie in the ⌈fa/TILE⌉ × ⌈fb/TILE⌉ ``index``.
    """
    for p in range(offsets.shape[0] - 1):
        row0, lo, hi, _ = upsample_band(cells[offsets[p]:offsets[p + 1]], s, h, fa, fb)
        for t in range(lo.shape[0]):
            ti = (row0 + t) // TILE
            for tj in range(lo[t] // TILE, hi[t] // TILE + 1):
                index[ti, tj] = 0


@njit(cache=True, nogil=True)
def _alloc_tiles(index):
    """Number the marked tiles; returns their value pool, NaN (not evaluated yet) everywhere."""
    n = 0
    for ti in range(index.shape[0]):
        for tj in range(index.shape[1]):
            if index[ti, tj] >= 0:
                index[ti, tj] = n
                n += 1
    return np.full((n, TILE, TILE), np.nan)


@njit(cache=True, nogil=True)
def _eval_band(row0, lo, hi, off, index, pool, left, left_y, na, right, right_y, nb, band, out) -> None:
    """Distance values on a band's cells (inf inside the ignored self band |i − j| ≤ band).

    Each cell is evaluated once per level: its value is kept in the tile ``pool`` and the bands
    of chains and bridges that overlap read it from there. A band row is walked one tile at a
    time, so the tile is looked up once per TILE columns rather than once per cell, and each run
    of cells not evaluated yet is evaluated by one call (:func:`_fill_run`; the values, from
    :func:`~motionweb.tasks.distance.distance_row`, are the bytes of
    :func:`~motionweb.tasks.distance.cell_distance`).

    Bounds: writes ``out[off[t] .. off[t] + hi[t] − lo[t]]`` (``off[-1]`` cells, ``out``'s size) and
    the pool tiles that :func:`_mark_tiles` numbered for the same band (index ≥ 0); a row's
    columns ``j .. jend`` lie in one tile (``jend ≤ j0 + TILE − 1``).
    """
    for t in range(lo.shape[0]):
        i = row0 + t
        ti = i // TILE
        ri = i - ti * TILE
        base = off[t] - lo[t]
        j = lo[t]
        while j <= hi[t]:
            tj = j // TILE
            j0 = tj * TILE
            jend = min(hi[t], j0 + TILE - 1)
            tix = index[ti, tj]
            if _copy_run(pool, tix, ri, j - j0, jend - j0, out, base + j):  # a cell not evaluated yet
                row = pool[tix, ri]
                u = j
                while u <= jend:  # each run of cells not evaluated yet, in one call
                    if not math.isnan(row[u - j0]):
                        u += 1
                        continue
                    w = u
                    while w < jend and math.isnan(row[w + 1 - j0]):
                        w += 1
                    _fill_run(row, j0, i, u, w, band, left, left_y, na, right, right_y, nb)
                    u = w + 1
                _copy_run(pool, tix, ri, j - j0, jend - j0, out, base + j)
            j = jend + 1


@njit(cache=True, nogil=True, inline="always")
def _copy_run(pool, tix, ri, a, b, out, o) -> bool:
    """Copy columns ``a .. b`` of row ``ri`` of tile ``tix`` to ``out[o .. o + b − a]``; whether a
    copied value was NaN (a cell not evaluated yet). The tile is indexed in place, not through a
    view of its row, with unsigned indices (all ≥ 0), which spare numba's negative-index
    wraparound on each cell.

    Bounds: the caller's (:func:`_eval_band`): a ≤ b are columns of the tile, ``tix`` one of its
    pool's tiles, o + b − a < ``out``'s size.
    """
    nan = False
    ut = np.uint64(tix)
    ur = np.uint64(ri)
    ua = np.uint64(a)
    uo = np.uint64(o)
    for u in range(np.uint64(b - a + 1)):
        x = pool[ut, ur, ua + u]
        out[uo + u] = x
        nan |= x != x
    return nan


@njit(cache=True, nogil=True)
def _fill_run(row, j0, i, u, w, band, left, left_y, na, right, right_y, nb) -> None:
    """Values of cells (i, u … w) into ``row[u − j0 … w − j0]`` (one tile row; KG04 §3.1 eq. 1 at
    the finer levels of §3.2): inf inside the ignored self band |i − j| ≤ ``band`` (design §4),
    :func:`~motionweb.tasks.distance.distance_row` on the run's parts either side of it.

    Bounds: u ≤ w lie in the tile's columns j0 … j0 + TILE − 1 (:func:`_eval_band`); the self
    band's cells b0 … b1 and the two parts either side are sub-runs of u … w.
    """
    b0 = w + 1  # the run's cells in the self band: b0 … b1 (none: b0 = w + 1, b1 = w)
    b1 = w
    if band >= 0 and max(u, i - band) <= min(w, i + band):
        b0 = max(u, i - band)
        b1 = min(w, i + band)
    for jj in range(b0, b1 + 1):
        row[jj - j0] = INF
    for part in range(2):  # the cells before the self band's, then those after them
        s = u if part == 0 else b1 + 1
        e = b0 - 1 if part == 0 else w
        if s <= e:
            distance_row(left, left_y, na, right, right_y, nb, i, s, e - s + 1, row, s - j0)


@njit(cache=True, nogil=True)
def _near_band(row0, lo, hi, ci, cj, radius):
    """The band cells within Chebyshev distance ``radius`` of (ci, cj), as a band of their own
    (row0, lo, hi, off): rows and column intervals of the band clipped to the square.

    Bounds: at most the band's rows; an emptied row has hi < lo and counts no cell.
    """
    nr = lo.shape[0]
    t_lo = max(0, math.floor(ci - radius) - row0)
    t_hi = min(nr - 1, math.ceil(ci + radius) - row0)
    j_lo = math.floor(cj - radius)
    j_hi = math.ceil(cj + radius)
    m = max(0, t_hi - t_lo + 1)
    nlo = np.empty(m, np.int64)
    nhi = np.empty(m, np.int64)
    noff = np.zeros(m + 1, np.int64)
    for u in range(m):
        nlo[u] = max(lo[t_lo + u], j_lo)
        nhi[u] = min(hi[t_lo + u], j_hi)
        noff[u + 1] = noff[u] + max(0, nhi[u] - nlo[u] + 1)
    return row0 + t_lo, nlo, nhi, noff


@njit(cache=True, nogil=True)
def _least_near(row0, lo, hi, off, ci, cj, radius, index, pool, left, left_y, na, right, right_y, nb, band):
    """The band cell of least value within Chebyshev ``radius`` of (ci, cj), the first in row
    order on ties, as a one-element array of its flat index (empty when every such cell is inf
    or there is none). Only those cells are evaluated (:func:`_eval_band` on :func:`_near_band`).
    """
    nrow0, nlo, nhi, noff = _near_band(row0, lo, hi, ci, cj, radius)
    vals = np.empty(noff[-1], np.float64)
    _eval_band(nrow0, nlo, nhi, noff, index, pool, left, left_y, na, right, right_y, nb, band, vals)
    best = INF
    out = np.zeros(0, np.int64)
    for u in range(nlo.shape[0]):
        for j in range(nlo[u], nhi[u] + 1):
            v = vals[noff[u] + j - nlo[u]]
            if v < best:
                best = v
                out = np.array([_flat_index(row0, lo, hi, off, nrow0 + u, j)], np.int64)
    return out


@njit(cache=True, nogil=True)
def _dp_buffers(n, mrun):
    """Scratch of :func:`_solve` for bands of up to ``n`` cells: (cost, length, ptr, init, flags).

    ``flags`` is all zeros (no blocked or terminal cell) and stays so: :func:`_solve` only reads it.
    """
    ns = 2 * mrun + 1
    return (np.empty((n, ns), np.float64), np.empty((n, ns), np.int32), np.empty((n, ns), np.int8),
            np.empty(n, np.float64), np.zeros(n, np.uint8))


@njit(cache=True, nogil=True)
def _solve(row0, lo, hi, off, vals, sources, targets, mrun, by_average, buf):
    """Best slope-ruled path in a band from any source to any target, by total or average cost.

    Returns its cells (n, 2) (absolute), or an empty array when no target is reachable. ``buf``:
    :func:`_dp_buffers` of at least the band's cells, reused from band to band (a refinement
    solves one band per chain and per bridge, ~10⁴ bridges on a pair of long takes); its first
    ``off[-1]`` rows are written before they are read, so what an earlier band left there does
    not matter.

    Bounds: band_dp writes the first ``off[-1]`` rows of the buffers, which hold at least that
    many (checked: a smaller ``buf`` raises); ``sources``/``targets`` are flat indices of band
    cells (< ``off[-1]``).
    """
    n = off[-1]
    cost, length, ptr, init, flags = buf
    if init.shape[0] < n:
        raise ValueError("_solve: scratch smaller than the band")
    ns = 2 * mrun + 1
    for k in range(n):
        init[k] = INF
    for k in sources:
        init[k] = vals[k]
    band_dp(lo, hi, off, vals, init, flags, mrun, cost, length, ptr)
    best = INF
    bk = -1
    bs = 0
    for k in targets:
        for s in range(ns):
            if length[k, s] == 0:
                continue
            v = cost[k, s] / length[k, s] if by_average == AVERAGE else cost[k, s]
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


@njit(cache=True, nogil=True)
def _fit(buf, n, mrun):
    """``buf`` when it holds ``n`` cells, else new buffers of twice that (amortised growth)."""
    if buf[3].shape[0] >= n:
        return buf
    return _dp_buffers(2 * n, mrun)


@njit(cache=True, nogil=True)
def _fit_values(vbuf, n):
    """``vbuf`` when it holds ``n`` values, else a new buffer of twice that."""
    if vbuf.shape[0] >= n:
        return vbuf
    return np.empty(2 * n, np.float64)


@njit(cache=True, nogil=True, inline="always")
def _flat_index(row0, lo, hi, off, i, j) -> int:
    return band_index(lo, hi, off, i - row0, j)


@njit(cache=True, nogil=True)
def _solve_between(row0, lo, hi, off, sources, targets, mrun, by_average, buf, vbuf, index, pool, left, left_y, na,
                   right, right_y, nb, band):
    """:func:`_solve` from ``sources`` to ``targets`` (flat indices of the band) on the part of the
    band a path between them can cross (:func:`_crop_to_ends`), whose cells alone are evaluated:
    the same path as on the whole band. Returns (path (n, 2), its cells' values (n,) float32, and
    the scratch ``buf``/``vbuf``, grown when the band needed more)."""
    row0, lo, hi, off, src, dst = _crop_to_ends(row0, lo, hi, off, sources, targets, mrun)
    if src.shape[0] == 0 or dst.shape[0] == 0:
        return np.zeros((0, 2), np.int32), np.zeros(0, np.float32), buf, vbuf
    buf = _fit(buf, off[-1], mrun)
    vbuf = _fit_values(vbuf, off[-1])
    vals = vbuf[:off[-1]]
    _eval_band(row0, lo, hi, off, index, pool, left, left_y, na, right, right_y, nb, band, vals)
    path = _solve(row0, lo, hi, off, vals, src, dst, mrun, by_average, buf)
    pv = np.empty(path.shape[0], np.float32)
    for u in range(path.shape[0]):  # band cells (band_backtrack checks): no search, no bounds test
        t = path[u, 0] - row0
        pv[u] = vals[off[t] + path[u, 1] - lo[t]]
    return path, pv, buf, vbuf


@njit(cache=True, nogil=True)
def _refine_chains(cells, offsets, s, h, radius, fa, fb, index, pool, left, left_y, na, right, right_y, nb, band,
                   mrun):
    """Refine every chain (KG04 Fig. 8); returns (cells, values, offsets, new id of each chain)."""
    nch = offsets.shape[0] - 1
    new_id = np.full(nch, -1, np.int64)
    out_c = []
    out_v = []
    n_out = 0
    buf = _dp_buffers(0, mrun)
    vbuf = np.empty(0, np.float64)
    for p in range(nch):
        cc = cells[offsets[p]:offsets[p + 1]]
        row0, lo, hi, off = upsample_band(cc, s, h, fa, fb)
        i0 = cc[0, 0] * s
        j0 = cc[0, 1] * s
        i1 = cc[-1, 0] * s
        j1 = cc[-1, 1] * s
        # the new ends: the least cells near the old ones (KG04 Fig. 8 step 3)
        src = _least_near(row0, lo, hi, off, i0, j0, radius, index, pool, left, left_y, na, right, right_y, nb, band)
        dst = _least_near(row0, lo, hi, off, i1, j1, radius, index, pool, left, left_y, na, right, right_y, nb, band)
        path, pv, buf, vbuf = _solve_between(row0, lo, hi, off, src, dst, mrun, np.int64(TOTAL), buf, vbuf, index, pool, left,
                                             left_y, na, right, right_y, nb, band)
        if path.shape[0] == 0:  # fall back on the upsampled endpoints themselves
            k0 = _flat_index(row0, lo, hi, off, math.floor(i0 + 0.5), math.floor(j0 + 0.5))
            k1 = _flat_index(row0, lo, hi, off, math.floor(i1 + 0.5), math.floor(j1 + 0.5))
            if k0 >= 0 and k1 >= 0:
                path, pv, buf, vbuf = _solve_between(row0, lo, hi, off, np.array([k0]), np.array([k1]), mrun, np.int64(TOTAL),
                                                     buf, vbuf, index, pool, left, left_y, na, right, right_y, nb,
                                                     band)
        if path.shape[0] == 0:
            continue
        new_id[p] = n_out
        n_out += 1
        out_c.append(path)
        out_v.append(pv)
    return _concat_cells(out_c), _concat_values(out_v), _offsets_of(out_c), new_id


@njit(cache=True, nogil=True)
def _concat_cells(parts):
    """Bounds: the output is sized to the parts' total length. Copied element by element: numba's
    slice assignment brings its shape-mismatch message's string formatting into the compiled code
    (seconds of compilation per process, tasks/warm.py)."""
    n = 0
    for x in parts:
        n += x.shape[0]
    out = np.empty((n, 2), np.int32)
    n = 0
    for x in parts:
        for i in range(x.shape[0]):
            out[n + i, 0] = x[i, 0]
            out[n + i, 1] = x[i, 1]
        n += x.shape[0]
    return out


@njit(cache=True, nogil=True)
def _concat_values(parts):
    """Bounds: the output is sized to the parts' total length."""
    n = 0
    for x in parts:
        n += x.shape[0]
    out = np.empty(n, np.float32)
    n = 0
    for x in parts:
        for i in range(x.shape[0]):
            out[n + i] = x[i]
        n += x.shape[0]
    return out


@njit(cache=True, nogil=True)
def _offsets_of(parts):
    out = np.zeros(len(parts) + 1, np.int64)
    for q in range(len(parts)):
        out[q + 1] = out[q] + parts[q].shape[0]
    return out


@njit(cache=True, nogil=True, inline="always")
def _rows_window(path, r0, r1):
    """[q0, q1): the cells of ``path`` with rows in r0..r1, found by bisection.

    A refined path (:func:`~motionweb.tasks.matchweb.band.band_backtrack`) is monotone: its rows
    never decrease, so those cells are one contiguous run. O(log n) instead of a scan of the path
    (a long take's chain has thousands of cells and ~10⁴ bridges look into it per level).
    """
    a = 0
    b = path.shape[0]
    while a < b:  # first q with row >= r0
        m = (a + b) // 2
        if path[m, 0] < r0:
            a = m + 1
        else:
            b = m
    q0 = a
    b = path.shape[0]
    while a < b:  # first q with row > r1
        m = (a + b) // 2
        if path[m, 0] <= r1:
            a = m + 1
        else:
            b = m
    return q0, a


@njit(cache=True, nogil=True)
def _path_cells_near(row0, lo, hi, off, path, ci, cj, radius):
    """Band indices of the cells of ``path`` within Chebyshev ``radius`` of (ci, cj), in path order.

    Only the run of cells whose rows lie within ``radius`` (plus one row each side, so the test
    below decides, not the rounding of the window's ends) is tested: the same cells as a scan of
    the whole path (``tests/naive.ref_path_cells_near``), since the path's rows are monotone.

    Bounds: at most one per cell of the run, into scratch of the run's length.
    """
    q0, q1 = _rows_window(path, math.floor(ci - radius) - 1, math.ceil(ci + radius) + 1)
    n = 0
    tmp = np.empty(q1 - q0, np.int64)
    for q in range(q0, q1):
        if abs(path[q, 0] - ci) <= radius and abs(path[q, 1] - cj) <= radius:
            k = _flat_index(row0, lo, hi, off, path[q, 0], path[q, 1])
            if k >= 0:
                tmp[n] = k
                n += 1
    return tmp[:n].copy()


@njit(cache=True, nogil=True)
def _position(path, i, j) -> int:
    """Index of the first cell (i, j) of the monotone ``path``, or −1 (bisection on the rows)."""
    q0, q1 = _rows_window(path, i, i)
    for q in range(q0, q1):
        if path[q, 1] == j:
            return q
    return -1


@njit(cache=True, nogil=True, inline="always")
def _band_cell(row0, lo, off, k):
    """(row, column) of band cell ``k`` (flat index < ``off[-1]``), by bisection on ``off``."""
    a = 0
    b = lo.shape[0] - 1
    while a < b:  # last row t with off[t] <= k
        m = (a + b + 1) // 2
        if off[m] <= k:
            a = m
        else:
            b = m - 1
    return row0 + a, lo[a] + k - off[a]


@njit(cache=True, nogil=True)
def _crop_to_ends(row0, lo, hi, off, sources, targets, mrun):
    """The part of a band that a slope-ruled path from a source to a target can cross, with the
    sources and targets as its flat indices (in their order; those on no such path dropped).

    Paths are monotone (up, right, diagonal) with at most ``mrun`` steps in a row along one axis,
    so a path from (i0, j0) reaches (i0 + d, j) only for ``j0 + d // (mrun + 1) ≤ j ≤ j0 + mrun +
    (mrun + 1)·d`` (each run of ≤ mrun up steps ends with a step that moves right; likewise for
    columns), and reaches a target (i1, j1) from (i1 − d, j) only for ``j1 − mrun − (mrun + 1)·d ≤
    j ≤ j1 − d // (mrun + 1)``. Each row keeps the hull of what the sources' cones allow, within
    the hull of what the targets' cones allow, within the rectangle from the lowest source to the
    highest target. A cell cut off is reached from no source or reaches no target. Every
    predecessor of a kept cell that lies on a source-to-target path lies on one too, so is kept:
    such cells get the same costs, lengths and predecessors as in the whole band, the targets
    the same values, and :func:`_solve` returns the same path, while evaluating and searching
    ~half of a bridge band's cells (measured on long takes).

    Bounds: each row's interval is the band's clipped (an emptied row has hi < lo and counts no
    cell), so ``off`` grows by at most the band's cells; the index arrays are sized by the inputs.
    """
    nr = lo.shape[0]
    big = 1 << 62
    si = np.empty(sources.shape[0], np.int64)
    sj = np.empty(sources.shape[0], np.int64)
    ti = np.empty(targets.shape[0], np.int64)
    tj = np.empty(targets.shape[0], np.int64)
    r0 = big
    c0 = big
    r1 = -1
    c1 = -1
    for q in range(sources.shape[0]):
        si[q], sj[q] = _band_cell(row0, lo, off, sources[q])
        r0 = min(r0, si[q])
        c0 = min(c0, sj[q])
    for q in range(targets.shape[0]):
        ti[q], tj[q] = _band_cell(row0, lo, off, targets[q])
        r1 = max(r1, ti[q])
        c1 = max(c1, tj[q])
    t0 = max(0, r0 - row0)
    t1 = min(nr - 1, r1 - row0)
    if t1 < t0 or c1 < c0:
        e = np.zeros(0, np.int64)
        return row0, e, e, np.zeros(1, np.int64), e, e
    m = t1 - t0 + 1
    clo = np.empty(m, np.int64)
    chi = np.empty(m, np.int64)
    coff = np.zeros(m + 1, np.int64)
    for u in range(m):
        i = row0 + t0 + u
        a = max(lo[t0 + u], c0)
        b = min(hi[t0 + u], c1)
        slo = big  # hull of the sources' cones on row i
        shi = -1
        for q in range(si.shape[0]):
            d = i - si[q]
            if d >= 0:
                slo = min(slo, sj[q] + d // (mrun + 1))
                shi = max(shi, sj[q] + mrun + (mrun + 1) * d)
        tlo = big  # hull of the targets' reverse cones on row i
        thi = -1
        for q in range(ti.shape[0]):
            d = ti[q] - i
            if d >= 0:
                tlo = min(tlo, tj[q] - mrun - (mrun + 1) * d)
                thi = max(thi, tj[q] - d // (mrun + 1))
        clo[u] = max(a, max(slo, tlo))
        chi[u] = min(b, min(shi, thi))
        coff[u + 1] = coff[u] + max(0, chi[u] - clo[u] + 1)
    crow0 = row0 + t0
    return (crow0, clo, chi, coff, _recount(crow0, clo, chi, coff, si, sj),
            _recount(crow0, clo, chi, coff, ti, tj))


@njit(cache=True, nogil=True)
def _recount(crow0, clo, chi, coff, rows, cols):
    """Flat indices in the cropped band (``crow0, clo, chi, coff``) of the cells (rows[q], cols[q])
    that lie in it, in their order. Bounds: at most one per input, into an array as long."""
    idx = np.empty(rows.shape[0], np.int64)
    n = 0
    for q in range(rows.shape[0]):
        kk = band_index(clo, chi, coff, rows[q] - crow0, cols[q])
        if kk >= 0:
            idx[n] = kk
            n += 1
    return idx[:n].copy()


@njit(cache=True, nogil=True)
def _refine_bridges(old_cells, old_offsets, bridges, b_cells, b_offsets, new_id, new_cells, new_offsets,
                    s, h, radius, fa, fb, index, pool, left, left_y, na, right, right_y, nb, band, mrun):
    """Refine every bridge whose chains survived; returns (junctions, cells, values, offsets)."""
    junctions = []
    out_c = []
    out_v = []
    buf = _dp_buffers(0, mrun)
    vbuf = np.empty(0, np.float64)
    for b in range(bridges.shape[0]):
        p = bridges[b, 0]
        q = bridges[b, 2]
        np_ = new_id[p]
        nq = new_id[q]
        if np_ < 0 or nq < 0:
            continue
        cc = b_cells[b_offsets[b]:b_offsets[b + 1]]
        row0, lo, hi, off = upsample_band(cc, s, h, fa, fb)
        sp = new_cells[new_offsets[np_]:new_offsets[np_ + 1]]
        dp = new_cells[new_offsets[nq]:new_offsets[nq + 1]]
        a = old_offsets[p] + bridges[b, 1]
        c = old_offsets[q] + bridges[b, 3]
        src = _path_cells_near(row0, lo, hi, off, sp, old_cells[a, 0] * s, old_cells[a, 1] * s, radius)
        dst = _path_cells_near(row0, lo, hi, off, dp, old_cells[c, 0] * s, old_cells[c, 1] * s, radius)
        if src.shape[0] == 0 or dst.shape[0] == 0:
            continue
        path, pv, buf, vbuf = _solve_between(row0, lo, hi, off, src, dst, mrun, np.int64(AVERAGE), buf, vbuf, index, pool, left,
                                             left_y, na, right, right_y, nb, band)
        if path.shape[0] == 0:
            continue
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
               self_pair: bool, pad: float = 1.0, counts: dict[str, int] | None = None) -> MatchWeb:
    """One coarse-to-fine step (KG04 §3.2, Fig. 8) from ``web`` to ``rate``.

    (1-2) each chain is padded by ``pad`` coarse cells and upsampled into a band, and only the
    band's cells are evaluated; (3) the new endpoints are the smallest cells within one coarse
    cell (``ceil(s)`` fine cells) of the upsampled old ones; (4) the least-total-cost slope-ruled
    path in the band joins them. Each bridge is refined likewise inside its own band, from any
    cell of its refined from-chain to any cell of its refined to-chain within one coarse cell of
    the upsampled old junctions, keeping the least-average path. Chains or bridges with no
    feasible path are dropped (with their bridges). Each search runs on the part of its band that
    a slope-ruled path from its sources to its targets can cross (:func:`_crop_to_ends`, the same
    path as on the whole band), whose cells are evaluated once, on first use, into TILE×TILE tiles
    allocated for the tiles the bands touch (chain and bridge bands overlap, ~2× on real webs).
    Cost: O(union of cropped band cells · P) for the values plus O(cropped band cells · k) for the
    DPs and O(Fa·Fb / TILE²) for the tile index — linear in the search regions. With ``counts``,
    its ``"evaluated"`` is increased by the cells whose values were computed (bench/index_scale.py).
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
    if counts is not None:
        counts["evaluated"] = counts.get("evaluated", 0) + int(np.count_nonzero(~np.isnan(pool)))
    return MatchWeb(rate=rate, shape=(fa, fb), paths_cells=pc, paths_values=pv, paths_offsets=po, bridges=jn,
                    bridges_cells=bc, bridges_values=bv, bridges_offsets=bo, self_pair=self_pair)
