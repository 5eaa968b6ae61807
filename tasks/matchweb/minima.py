"""Dense single-resolution pieces of a match web (KG04 §3.1-3.2; design §4).

Grid convention: cell ``(i, j)`` compares frame ``i`` of clip A (rows, KG04's M1, vertical axis)
with frame ``j`` of clip B (columns, M2). "Top" is ``i + 1``, "right" is ``j + 1``; paths are
monotone: every step is up ``(1, 0)``, right ``(0, 1)`` or diagonal ``(1, 1)``.

* :func:`local_minima` — horizontal / vertical 1-D minima (KG04 §3.1), O(Fa·Fb).
* :func:`valid_region` — minima extended along their minimum directions while the value stays
  below ``(1 + a)`` times theirs (KG04 §3.1, Fig. 5), O(Fa·Fb · extension).
* :func:`find_chains` — chains of minima grown up / right / up-right under the slope rule,
  short ones dropped (KG04 §3.2), O(minima).
* :func:`mask_self_band` — the ignored diagonal band of a self pair.
"""

from __future__ import annotations

import numpy as np
from motionweb.tasks.matchweb.params import INF, max_run
from motionweb.store.numba_cache import njit


def as_grid(grid: np.ndarray) -> np.ndarray:
    """Grids enter the kernels as C-contiguous float32 (one compiled signature each)."""
    return np.ascontiguousarray(grid, dtype=np.float32)


def _same_shape(minima: np.ndarray, g: np.ndarray) -> np.ndarray:
    """``minima`` as C-contiguous uint8, checked to have the grid's shape (the kernels index both alike)."""
    m = np.ascontiguousarray(minima, dtype=np.uint8)
    if m.shape != g.shape:
        raise ValueError(f"the minima have shape {m.shape}, the grid {g.shape}")
    return m


@njit(cache=True, nogil=True)
def _local_minima(g: np.ndarray) -> np.ndarray:
    """Bounds: writes only the cells of its own (Fa, Fb) output, the grid's shape."""
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
    return _local_minima(as_grid(grid))


@njit(cache=True, nogil=True)
def _valid_region(g: np.ndarray, minima: np.ndarray, a: float) -> np.ndarray:
    """Bounds: writes only cells of its own (Fa, Fb) output; each extension stops at the grid's
    border (``minima`` has the grid's shape, checked by :func:`valid_region`)."""
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
    g = as_grid(grid)
    return _valid_region(g, _same_shape(minima, g), float(a))


@njit(cache=True, nogil=True)
def _find_chains(g: np.ndarray, minima: np.ndarray, mrun: int, min_extent: int):
    """Bounds: writes at most N chain cells and N + 1 offsets for the N minima counted first: each
    write takes a minimum not yet used, and a dropped chain releases exactly the cells it wrote."""
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
    for t in range(w):  # element by element: no slice assignment's message formatting compiled
        cells[t, 0] = ci[t]
        cells[t, 1] = cj[t]
    return cells, offsets[: n_chains + 1].copy()


def find_chains(grid: np.ndarray, minima: np.ndarray, slope_k: int, min_extent: int) -> tuple[np.ndarray, np.ndarray]:
    """Chains of 1-D minima (KG04 §3.2): ``(cells (N, 2) int32, offsets (C + 1,) int64)``.

    Minima are visited in row-major order; each one not yet on a chain starts a chain (so every
    minimum with no minimum to its left, below or below-left starts one, as in KG04), grown by
    repeatedly taking the smallest unused minimum among the top, right and top-right cells that the
    slope rule allows. Chains spanning fewer than ``min_extent`` frames (max of row and column
    extents) are dropped and their minima released. O(Fa·Fb) scan plus O(minima) growth.
    """
    g = as_grid(grid)
    return _find_chains(g, _same_shape(minima, g), max_run(slope_k), int(min_extent))


def mask_self_band(grid: np.ndarray, band: int) -> np.ndarray:
    """A copy of ``grid`` with cells |i − j| ≤ band set to +inf (the ignored self-pair diagonal)."""
    g = np.array(grid, copy=True)
    fa, fb = g.shape
    for d in range(-band, band + 1):
        if -fa < d < fb:
            idx = np.arange(max(0, -d), min(fa, fb - d))
            g[idx, idx + d] = np.inf
    return g
