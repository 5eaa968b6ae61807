"""Shortest paths with exactly m-2 edges, or unconstrained, over the warp DAG (HDP07 §3.3, eqs. 3-4)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from motionweb.store.numba_cache import njit

# Shortest paths (HDP07 §3.3)


@njit(cache=True)
def _fixed_length_kernel(table, lo, hi):  # pragma: no cover - compiled
    """Layered DP c_p(j,k) = min_i c_{p-1}(i,j) + f(i,j,k) over the allowed windows [lo_p, hi_p].

    Bounds: writes window offsets k − lo[p] < W = max(hi − lo + 1) of its (W, s) layers and
    (layers, W, s) backpointers; backpointers 1..s fit int8 (s ≤ 127) and windows lie in
    0..n − 1, both checked by :func:`fixed_length_path`.
    """
    _n, s, _ = table.shape
    n_layers = lo.shape[0]
    width = 0
    for p in range(n_layers):
        width = max(width, hi[p] - lo[p] + 1)
    back = np.zeros((n_layers, width, s), dtype=np.int8)
    prev = np.full((width, s), np.inf)
    cur = np.full((width, s), np.inf)
    # layer 0: vertices (0, k), cost 0 (HDP07 eq. 3)
    for k in range(lo[0], hi[0] + 1):
        if 1 <= k <= s:
            prev[k - lo[0], k - 1] = 0.0
    for p in range(1, n_layers):
        cur[:, :] = np.inf
        for k in range(lo[p], hi[p] + 1):
            for b in range(1, s + 1):
                j = k - b
                if j < lo[p - 1] or j > hi[p - 1]:
                    continue
                best = np.inf
                arg = 0
                for a in range(1, s + 1):
                    v = prev[j - lo[p - 1], a - 1] + table[j, a - 1, b - 1]
                    if v < best:
                        best = v
                        arg = a
                cur[k - lo[p], b - 1] = best
                back[p, k - lo[p], b - 1] = arg
        prev, cur = cur, prev
    return prev, back


@njit(cache=True)
def _dag_kernel(table):  # pragma: no cover - compiled
    """Unconstrained DAG shortest path over vertices (k - b, k) in increasing k.

    Bounds: writes its own (n, s) outputs; backpointers 1..s fit int8 (s ≤ 127, checked by
    :func:`dag_path`)."""
    n, s, _ = table.shape
    cost = np.full((n, s), np.inf)
    back = np.zeros((n, s), dtype=np.int8)
    for k in range(1, n):
        for b in range(1, s + 1):
            j = k - b
            if j < 0:
                break
            if j == 0:
                cost[k, b - 1] = 0.0
                continue
            best = np.inf
            arg = 0
            for a in range(1, s + 1):
                if j - a < 0:
                    break
                v = cost[j, a - 1] + table[j, a - 1, b - 1]
                if v < best:
                    best = v
                    arg = a
            cost[k, b - 1] = best
            back[k, b - 1] = arg
    return cost, back


#: largest skip: the kernels keep backpointers 1..skip as int8
MAX_SKIP = 127


def _check_skip(s: int) -> None:
    if not 1 <= s <= MAX_SKIP:
        raise ValueError(f"skip must be in 1..{MAX_SKIP} (int8 backpointers), got {s}")


def feasible_windows(n: int, m: int, skip: int, keys: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """Bounds lo[q] <= y[q] <= hi[q] (q = 0..m-1) implied by the step limits 1..s and the keytimes.

    ``keys`` are (input frame, output frame) pairs, endpoints included. Raises ValueError naming
    the violated constraint when no path exists.
    """
    q = np.arange(m)
    lo = np.zeros(m, dtype=np.int64)
    hi = np.full(m, n - 1, dtype=np.int64)
    for f, o in keys:
        after = q >= o
        lo = np.maximum(lo, np.where(after, f + (q - o), f - skip * (o - q)))
        hi = np.minimum(hi, np.where(after, f + skip * (q - o), f - (o - q)))
    bad = np.flatnonzero(lo > hi)
    if len(bad):
        raise ValueError(
            f"no warp of {n} working input frames into {m} output frames with skip <= {skip} passes "
            f"through keytimes {list(keys)} (first conflict at output frame {int(bad[0])})"
        )
    return lo, hi


def fixed_length_path(table: np.ndarray, m: int, lo: np.ndarray | None = None,
                      hi: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Shortest path with exactly m-2 edges from a vertex (0, ·) to a vertex (·, n-1) (HDP07 eqs. 3-4).

    ``lo``/``hi`` (m,) bound y[q] (keytimes, the §3.3 band); they default to the reachable range.
    O(m W s²) for windows of width W <= n; backpointers are int8. Returns (path (m,), cost);
    the cost is inf when the windows admit no path.
    """
    n, s, _ = table.shape
    if m < 2:
        raise ValueError(f"the output needs at least 2 frames, got {m}")
    _check_skip(s)
    if lo is None or hi is None:
        lo, hi = feasible_windows(n, m, s, [(0, 0), (n - 1, m - 1)])
    lo = np.ascontiguousarray(lo, dtype=np.int64)
    hi = np.ascontiguousarray(hi, dtype=np.int64)
    if lo.shape != (m,) or hi.shape != (m,):
        raise ValueError(f"the windows lo/hi must have one bound per output frame ({m}), got {lo.shape} and {hi.shape}")
    if np.any(lo < 0) or np.any(hi > n - 1):
        raise ValueError(f"the windows must lie in the input's frames 0..{n - 1}")
    if lo[0] != 0 or hi[0] != 0 or lo[-1] != n - 1 or hi[-1] != n - 1:
        raise ValueError("the path must start on frame 0 and end on the last frame")
    if m == 2:
        return np.array([0, n - 1]), (0.0 if n - 1 <= s else np.inf)
    last, back = _fixed_length_kernel(np.ascontiguousarray(table, dtype=np.float64), lo[1:], hi[1:])
    row = last[(n - 1) - lo[-1]]
    b = int(np.argmin(row)) + 1
    cost = float(row[b - 1])
    if not np.isfinite(cost):
        return np.zeros(0, dtype=np.int64), np.inf
    path = np.empty(m, dtype=np.int64)
    path[m - 1] = n - 1
    k = n - 1
    for layer in range(m - 2, 0, -1):  # layer of vertex (y[layer], y[layer+1]) in lo[1:] indexing
        a = int(back[layer, k - lo[layer + 1], b - 1])
        k -= b
        path[layer] = k
        b = a
    path[0] = k - b
    return path, cost


def dag_path(table: np.ndarray) -> tuple[np.ndarray, float]:
    """Unconstrained shortest path from a vertex (0, ·) to a vertex (·, n-1): O(n s²) (HDP07 §3.3).

    Returns (path, cost); an empty path and inf when no path of finite cost exists."""
    n, _s, _ = table.shape
    if n < 2:
        raise ValueError("the input needs at least 2 frames")
    _check_skip(_s)
    cost, back = _dag_kernel(np.ascontiguousarray(table, dtype=np.float64))
    b = int(np.argmin(cost[n - 1])) + 1
    total = float(cost[n - 1, b - 1])
    if not np.isfinite(total):  # no path: the backpointers hold 0 there (the walk back would not end)
        return np.zeros(0, dtype=np.int64), np.inf
    out = [n - 1]
    k = n - 1
    while k - b > 0:
        a = int(back[k, b - 1])
        k -= b
        out.append(k)
        b = a
    out.append(0)
    return np.array(out[::-1], dtype=np.int64), total


def path_cost(table: np.ndarray, path: np.ndarray) -> float:
    """HDP07 eq. 1 for a path, read from a score table."""
    y = np.asarray(path)
    if len(y) < 3:
        return 0.0
    return float(table[y[1:-1], y[1:-1] - y[:-2] - 1, y[2:] - y[1:-1] - 1].sum())


# ----------------------------------------------------------------------------------------------------------
