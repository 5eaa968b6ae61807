"""Registration of the motions of a match graph in time (KG04 §4.1; design §6).

KG04 §4.1, step by step:

1. Dijkstra from the query (node 0) over the match graph with the edge costs; every edge not on
   the shortest-path tree is discarded (:func:`shortest_path_tree`).
2. For each tree edge, a new time alignment between its two segments by dynamic programming
   (least total cell value, KG04 §3.1) from their first frames to their last frames, restricted
   to the valid region and to the slope rule (:func:`align_segments`).
3. An endpoint-interpolating, strictly increasing curve through each alignment
   (:func:`monotone_knots` + monotone PCHIP, :class:`EdgeAlignment`).
4. Composition along the tree: every query frame u is walked down its shortest path, each edge's
   curve turning a frame of the parent into a frame of the child.
5. One N-dimensional strictly increasing time-warp curve s(u) through these correspondences
   (:class:`Registration`), parameterised by the query frame u itself: the query's coordinate is
   the identity and every other coordinate is a composition of strictly increasing curves, so
   all N coordinates increase strictly with u and no further reparameterisation is needed.

Valid region on a segment grid. KG04 defines it on the full grid of two clips (1-D minima
extended while below ``(1 + a)`` times the minimum, :func:`tasks.matchweb.minima.valid_region`). Here
only the DP's search region is evaluated — a band of Chebyshev radius ``ceil(band_s · rate)``
around the edge's web path (``MatchEdge.cells``) joined to the rectangle's corners, or the whole
segment rectangle when that band would cover half of it — and the valid region is computed on that region, its border
playing the grid border (a missing neighbour does not count, as in ``local_minima``): every
full-grid minimum inside the region is still a minimum and extends exactly as on the full grid
up to the region's border; cells on the border can become extra minima, so the region is at worst
slightly more permissive there. The two corners are always allowed (merged nodes may end a few
frames off a minimum). Where no slope-ruled path stays in the valid region (KG04 would call the
motions dissimilar, but the search accepted the edge) the DP is rerun with the slope rule alone
and the edge is flagged (``Alignment.in_valid_region``).

Cost: Dijkstra O(E log V); per tree edge O(B·(P + k)) time and O(B·k) memory for B cells of the
search region (B ≈ (n + m)(2r + 1) for a band around segments of n and m frames, n·m when dense)
and P points per cloud, so memory grows linearly with segment length; composition and the final
fit O(U·N) for U query frames and N nodes.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from motionweb.tasks.distance import (
    PreparedFeatures,
    distance_cells,
    distance_prepared,
    prepare_features,
    vertical_shift,
)
from motionweb.tasks.matchgraph import MatchGraph, Segment
from motionweb.tasks.matchweb.band import band_backtrack, band_buffers, band_dp, band_index, best_state_total
from motionweb.tasks.matchweb.params import INF, MatchWebParams, max_run
from motionweb.tasks.matchweb.refine import upsample_band
from motionweb.store.numba_cache import njit
from scipy.interpolate import PchipInterpolator

# ----------------------------------------------------------------------------------------------
# search regions: the rectangle, or a band around the web path
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Band:
    """Cells of an n×m segment grid, row ``t`` holding columns ``lo[t]..hi[t]`` (flat index
    ``off[t] + j − lo[t]``), the layout of ``tasks.matchweb.band``'s DP. Rows are frames of the
    parent segment, columns frames of the child, both counted from the segment start."""

    lo: np.ndarray
    hi: np.ndarray
    off: np.ndarray
    n_cols: int

    @property
    def n_rows(self) -> int:
        return len(self.lo)

    @property
    def n_cells(self) -> int:
        return int(self.off[-1])

    @classmethod
    def rectangle(cls, n: int, m: int) -> Band:
        """The whole n×m grid (the dense DP)."""
        return cls(np.zeros(n, np.int64), np.full(n, m - 1, np.int64), np.arange(n + 1, dtype=np.int64) * m, m)

    @classmethod
    def around(cls, path: np.ndarray, n: int, m: int, radius: int) -> Band:
        """Cells within Chebyshev distance ``radius`` of ``path``, a unit-step monotone path from
        (0, 0) to (n − 1, m − 1) (KG04 Fig. 8's padded search region at one rate)."""
        row0, lo, hi, off = upsample_band(np.ascontiguousarray(path, dtype=np.int64), 1.0, float(radius), n, m)
        if row0 != 0 or len(lo) != n or lo[0] != 0 or hi[-1] != m - 1:
            raise ValueError("the guide path must run from (0, 0) to (n - 1, m - 1)")
        return cls(lo, hi, off, m)

    def cells(self) -> np.ndarray:
        """(n_cells, 2) (row, column) of every cell in flat order."""
        rows = np.repeat(np.arange(self.n_rows), self.hi - self.lo + 1)
        cols = np.arange(self.n_cells) - self.off[rows] + self.lo[rows]
        return np.stack([rows, cols], axis=1)


def _rasterize(points: np.ndarray) -> np.ndarray:
    """Unit-step cells along the polyline through monotone integer ``points`` (both ends kept)."""
    p = np.asarray(points, dtype=np.int64)
    step = np.diff(p, axis=0)
    d = step.max(axis=1)
    keep = d > 0
    p0, step, d = p[:-1][keep], step[keep], d[keep]
    seg = np.repeat(np.arange(len(d)), d)
    k = np.arange(int(d.sum())) - np.repeat(np.cumsum(d) - d, d)
    pts = p0[seg] + step[seg] * (k / d[seg])[:, None]
    return np.vstack([np.floor(pts + 0.5).astype(np.int64), p[-1:]])


def guide_path(cells: np.ndarray, n: int, m: int) -> np.ndarray:
    """Unit-step monotone path from (0, 0) to (n − 1, m − 1) following ``cells`` (relative to the
    segment starts) where they lie inside the n×m rectangle, joined to the corners by straight
    lines; the straight diagonal when no cell lies inside."""
    c = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
    c = c[(c[:, 0] >= 0) & (c[:, 0] < n) & (c[:, 1] >= 0) & (c[:, 1] < m)]
    return _rasterize(np.vstack([[[0, 0]], c, [[n - 1, m - 1]]]))


# ----------------------------------------------------------------------------------------------
# valid region and DP on a band (KG04 §3.1)
# ----------------------------------------------------------------------------------------------


@njit(cache=True)
def _band_valid(lo, hi, off, vals, a):
    """Bounds: writes only band cells (flat index ``off[t] + j − lo[t]`` with lo[t] ≤ j ≤ hi[t], or
    :func:`band_index` ≥ 0), all below ``off[-1]``, the size of its output."""
    out = np.zeros(off[-1], np.bool_)
    for t in range(lo.shape[0]):
        for j in range(lo[t], hi[t] + 1):
            k = off[t] + j - lo[t]
            v = vals[k]
            if not v < INF:
                continue
            kl = band_index(lo, hi, off, t, j - 1)
            kr = band_index(lo, hi, off, t, j + 1)
            kb = band_index(lo, hi, off, t - 1, j)
            ka = band_index(lo, hi, off, t + 1, j)
            horiz = (kl < 0 or v < vals[kl]) and (kr < 0 or v <= vals[kr])
            vert = (kb < 0 or v < vals[kb]) and (ka < 0 or v <= vals[ka])
            if not (horiz or vert):
                continue
            out[k] = True
            lim = (1.0 + a) * v
            if horiz:
                jj = j - 1
                while jj >= lo[t] and vals[off[t] + jj - lo[t]] < lim:
                    out[off[t] + jj - lo[t]] = True
                    jj -= 1
                jj = j + 1
                while jj <= hi[t] and vals[off[t] + jj - lo[t]] < lim:
                    out[off[t] + jj - lo[t]] = True
                    jj += 1
            if vert:
                for step in (-1, 1):
                    tt = t + step
                    while True:
                        kk = band_index(lo, hi, off, tt, j)
                        if kk < 0 or not vals[kk] < lim:
                            break
                        out[kk] = True
                        tt += step
    return out


def band_valid_region(band: Band, vals: np.ndarray, a: float) -> np.ndarray:
    """The valid region (KG04 §3.1, Fig. 5) of a band: bool (n_cells,).

    Same rule as :func:`tasks.matchweb.minima.valid_region` (and the same result on the rectangle), with
    the band's border as the grid border. O(cells · extension).
    """
    return _band_valid(band.lo, band.hi, band.off, np.ascontiguousarray(vals, dtype=np.float64), float(a))


def band_alignment(band: Band, vals: np.ndarray, slope_k: int) -> np.ndarray | None:
    """Least-total-cost slope-ruled monotone path from (0, 0) to (n − 1, m − 1) through the finite
    cells of ``vals`` (flat band values, inf = blocked): cells (K, 2) relative, or None.

    The time alignment of KG04 §3.1 by dynamic programming (``tasks.matchweb.band.band_dp``): at most
    ``slope_k`` cells in one row or column in a row. O(cells · k) time and memory.
    """
    v = np.ascontiguousarray(vals, dtype=np.float64)
    mrun = max_run(slope_k)
    nc = band.n_cells
    init = np.full(nc, INF)
    init[0] = v[0]
    cost, length, ptr = band_buffers(nc, mrun)
    band_dp(band.lo, band.hi, band.off, v, init, np.zeros(nc, np.uint8), mrun, cost, length, ptr)
    s = best_state_total(cost, nc - 1)
    if not cost[nc - 1, s] < INF:
        return None
    return band_backtrack(0, band.lo, band.hi, band.off, ptr, band.n_rows - 1, band.n_cols - 1, s, mrun)


@dataclass(frozen=True)
class Alignment:
    """A time alignment of segments a and b (KG04 §3.1).

    ``cells`` (K, 2) int: (frame of a's clip, frame of b's clip), absolute frames, from
    (a.start, b.start) to (a.end, b.end); ``cost`` its average cell value; ``in_valid_region``
    False when only the slope rule could be kept; ``n_cells`` cells evaluated (band or rectangle).
    """

    cells: np.ndarray
    cost: float
    in_valid_region: bool
    n_cells: int


def align_segments(pa: PreparedFeatures, pb: PreparedFeatures, seg_a: Segment, seg_b: Segment,
                   guide_cells: np.ndarray, cfg: MatchWebParams, radius: int | None) -> Alignment:
    """Time alignment of ``seg_a`` with ``seg_b`` by DP in the valid region (KG04 §3.1, §4.1).

    ``pa``, ``pb``: prepared clouds of the two segments' frames only (row 0 = ``seg_a.start``);
    ``guide_cells`` (K, 2): the edge's web path, absolute (frame of a, frame of b). The search
    region is a band of Chebyshev ``radius`` around the guide (:func:`guide_path`), or the whole
    rectangle when ``radius`` is None or the band would cover half of it; rectangle values come
    from the GEMM grid, band values cell by cell. O(B·(P + k)) time, O(B·k) memory for B cells.
    """
    n, m = seg_a.n_frames, seg_b.n_frames
    rel = np.asarray(guide_cells, dtype=np.int64).reshape(-1, 2) - [seg_a.start, seg_b.start]
    band = None if radius is None else Band.around(guide_path(rel, n, m), n, m, radius)
    if band is None or 2 * band.n_cells >= n * m:
        band = Band.rectangle(n, m)
        vals = distance_prepared(pa, pb, slice(0, n), slice(0, m)).reshape(-1)
    else:
        rc = band.cells()
        vals = distance_cells(pa, pb, rc[:, 0], rc[:, 1])
    valid = band_valid_region(band, vals, cfg.valid_a)
    valid[0] = valid[-1] = True
    path = band_alignment(band, np.where(valid, vals, INF), cfg.slope_k)
    in_valid = path is not None
    if path is None:
        path = band_alignment(band, vals, cfg.slope_k)
    if path is None:
        raise ValueError(f"no slope-ruled time alignment between {seg_a} ({n} frames) and {seg_b} ({m} frames) "
                         f"with slope_k={cfg.slope_k}")
    flat = band.off[path[:, 0]] + path[:, 1] - band.lo[path[:, 0]]
    cells = path.astype(np.int64) + [seg_a.start, seg_b.start]
    return Alignment(cells, float(vals[flat].mean()), in_valid, band.n_cells)


# ----------------------------------------------------------------------------------------------
# curves
# ----------------------------------------------------------------------------------------------


def _group_mean(keys: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique sorted ``keys`` and the mean of ``values`` over each."""
    uk, inv = np.unique(keys, return_inverse=True)
    return uk, np.bincount(inv, weights=values) / np.bincount(inv)


def monotone_knots(cells: np.ndarray) -> np.ndarray:
    """Strictly increasing knots (q, 2) through a time alignment (KG04 §4.1), endpoints kept.

    A slope-ruled path repeats a row on horizontal runs and a column on vertical runs; each run
    is replaced by its midpoint (mean column per row, then mean row per column), which leaves
    both coordinates strictly increasing, and the first and last knots are reset to the path's
    corners (still strictly increasing: a run's midpoint never lies before its first cell).
    """
    c = np.asarray(cells, dtype=np.float64)
    if len(c) < 2 or c[-1, 0] <= c[0, 0] or c[-1, 1] <= c[0, 1]:
        raise ValueError(f"an alignment needs two frames on each side, got cells {c[[0, -1]].tolist()}")
    x, y = _group_mean(c[:, 0], c[:, 1])
    y, x = _group_mean(y, x)
    knots = np.stack([x, y], axis=1)
    knots[0], knots[-1] = c[0], c[-1]
    return knots


# ----------------------------------------------------------------------------------------------
# the registration
# ----------------------------------------------------------------------------------------------


@dataclass
class EdgeAlignment:
    """A shortest-path-tree edge, oriented from ``parent`` to ``child`` (graph node indices),
    with its recomputed alignment and curve (KG04 §4.1): ``self(frames)`` maps frames of the
    parent's segment to frames of the child's, strictly increasing (monotone PCHIP through
    ``knots``, which are strictly increasing) and endpoint-interpolating."""

    parent: int
    child: int
    edge: int
    alignment: Alignment
    knots: np.ndarray
    _curve: PchipInterpolator = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._curve = PchipInterpolator(self.knots[:, 0], self.knots[:, 1], extrapolate=False)

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        x0, x1 = self.knots[0, 0], self.knots[-1, 0]
        f = np.asarray(frames, dtype=np.float64)
        if np.any(f < x0) or np.any(f > x1):
            raise ValueError(f"edge {self.edge}: frames outside the parent segment {x0:g}..{x1:g}")
        return np.clip(self._curve(f), self.knots[0, 1], self.knots[-1, 1])


@dataclass
class Registration:
    """Every node of a match graph registered to the query (KG04 §4.1).

    Column ``c`` stands for graph node ``nodes[c]`` (Dijkstra order: the query first, every node
    after its parent ``parents[c]``, a column, −1 for the query), its segment ``segments[c]`` and
    shortest-path cost ``distances[c]``. ``frames`` (U, N): for each query frame
    ``u = query.start .. query.end`` (at ``rate``) the corresponding frame of every node's clip,
    as floats; every column strictly increasing, from the segment's start to its end.
    ``edges[c − 1]`` is the tree edge into column ``c``.
    """

    rate: float
    nodes: list[int]
    segments: list[Segment]
    parents: list[int]
    distances: np.ndarray
    frames: np.ndarray
    edges: list[EdgeAlignment]
    _curve: PchipInterpolator = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._curve = PchipInterpolator(self.u, self.frames, axis=0, extrapolate=False)

    @property
    def u(self) -> np.ndarray:
        """The query frames the samples are taken at."""
        q = self.segments[0]
        return np.arange(q.start, q.end + 1, dtype=np.float64)

    def warp(self, u: np.ndarray) -> np.ndarray:
        """s(u): (len(u), N) frames of every node at query frames ``u`` (floats in the query's
        segment), the N-dimensional strictly increasing time-warp curve of KG04 §4.1 (monotone
        PCHIP through ``frames`` in every coordinate)."""
        q = self.segments[0]
        uu = np.asarray(u, dtype=np.float64).reshape(-1)
        if np.any(uu < q.start) or np.any(uu > q.end):
            raise ValueError(f"u must lie in the query's frames {q.start}..{q.end}")
        starts = np.array([s.start for s in self.segments], np.float64)
        ends = np.array([s.end for s in self.segments], np.float64)
        return np.clip(self._curve(uu), starts, ends)

    def resample(self, length: int | None = None) -> np.ndarray:
        """(length, N) frames of every node at ``length`` evenly spaced points of s(u) from the
        query's first to its last frame (default: the query's own length): the examples at a
        common length, strictly increasing per column, first row the segment starts and last row
        the segment ends."""
        q = self.segments[0]
        n = q.n_frames if length is None else int(length)
        if n < 2:
            raise ValueError(f"a common length needs at least 2 frames, got {n}")
        return self.warp(np.linspace(q.start, q.end, n))


def shortest_path_tree(graph: MatchGraph) -> tuple[list[int], np.ndarray, np.ndarray]:
    """Dijkstra from the query (node 0) over the edge costs (KG04 §4.1): (settle order, parent
    edge of every node (−1 for the query and unreached nodes), distance (inf if unreached)).
    Parallel edges resolve to the cheapest; O(E log V)."""
    n = len(graph.nodes)
    dist = np.full(n, np.inf)
    via = np.full(n, -1, np.int64)
    dist[0] = 0.0
    adj = graph.adjacency()
    heap = [(0.0, 0)]
    done = np.zeros(n, bool)
    order: list[int] = []
    while heap:
        d, a = heapq.heappop(heap)
        if done[a]:
            continue
        done[a] = True
        order.append(a)
        for e in adj[a]:
            edge = graph.edges[e]
            b = edge.v if edge.u == a else edge.u
            if not done[b] and d + edge.cost < dist[b]:
                dist[b] = d + edge.cost
                via[b] = e
                heapq.heappush(heap, (dist[b], b))
    return order, via, dist


def _check(graph: MatchGraph, features: Mapping[str, np.ndarray]) -> None:
    if not graph.nodes:
        raise ValueError("the match graph has no nodes (node 0 must be the query)")
    for k, node in enumerate(graph.nodes):
        s = node.segment
        if s.clip not in features:
            raise ValueError(f"no features for clip {s.clip!r} (node {k})")
        f = features[s.clip]
        if s.start < 0 or s.end >= len(f):
            raise ValueError(f"node {k}: frames {s.start}..{s.end} of clip {s.clip!r} outside its {len(f)} "
                             f"feature frames at {graph.rate:g} Hz")
        if s.n_frames < 2:
            raise ValueError(f"node {k}: segment of clip {s.clip!r} has {s.n_frames} frame; registration needs 2")
    for e, edge in enumerate(graph.edges):
        if not (0 <= edge.u < len(graph.nodes) and 0 <= edge.v < len(graph.nodes)):
            raise ValueError(f"edge {e} joins unknown nodes {edge.u} and {edge.v}")
        if not (np.isfinite(edge.cost) and edge.cost >= 0):
            raise ValueError(f"edge {e} ({edge.u}-{edge.v}) has cost {edge.cost}; Dijkstra needs finite costs >= 0")
        if len(edge.cells) > 1 and np.any(np.diff(edge.cells, axis=0) < 0):
            raise ValueError(f"edge {e} ({edge.u}-{edge.v}): cells are not a monotone path")


def register(graph: MatchGraph, features: Mapping[str, np.ndarray], weights: np.ndarray, cfg: MatchWebParams,
             band_s: float | None = 0.25) -> Registration:
    """Register every node of ``graph`` to the query, node 0 (KG04 §4.1; design §6).

    ``features[clip]``: (F, P, 3) clouds of each node's clip at ``graph.rate``
    (``tasks.features.clip_features``) with point ``weights`` (P,); ``cfg``: ``valid_a`` and
    ``slope_k`` of the time alignments. Each tree edge's alignment is searched in a band of
    ``ceil(band_s · rate)`` frames (at least 2) around its web path, or densely over the segment
    rectangle when ``band_s`` is None (see :func:`align_segments`).

    Raises ValueError naming the node, clip or edge for: an empty graph, missing features, a
    segment outside its features or shorter than 2 frames, a bad edge, a node not connected to
    the query, an edge with no slope-ruled alignment. Cost: O(E log V) + O(Σ B·(P + k)) over the
    tree edges' search regions + O(U·N); memory O(max B·k + U·N).
    """
    _check(graph, features)
    order, via, dist = shortest_path_tree(graph)
    if len(order) < len(graph.nodes):
        k = next(i for i in range(len(graph.nodes)) if not np.isfinite(dist[i]))
        s = graph.nodes[k].segment
        raise ValueError(f"node {k} (clip {s.clip!r}, frames {s.start}..{s.end}) is not connected to the query "
                         f"(node 0); {len(graph.nodes) - len(order)} node(s) unreachable")
    segs = [graph.nodes[k].segment for k in order]
    clouds = [features[s.clip][s.start:s.end + 1] for s in segs]
    y0 = vertical_shift(*clouds, weights=weights)
    prepared = [prepare_features(c, weights, y0, np.float64) for c in clouds]
    radius = None if band_s is None else max(2, math.ceil(band_s * graph.rate - 1e-9))
    col = {k: c for c, k in enumerate(order)}
    frames = np.empty((segs[0].n_frames, len(order)))
    frames[:, 0] = np.arange(segs[0].start, segs[0].end + 1)
    parents, edges = [-1], []
    for c in range(1, len(order)):
        child = order[c]
        e = int(via[child])
        edge = graph.edges[e]
        parent = edge.u if edge.v == child else edge.v
        cells = edge.cells if edge.u == parent else edge.cells[:, ::-1]
        p = col[parent]
        try:
            al = align_segments(prepared[p], prepared[c], segs[p], segs[c], cells, cfg, radius)
        except ValueError as exc:
            raise ValueError(f"edge {e} (node {parent} -> node {child}): {exc}") from None
        ea = EdgeAlignment(parent, child, e, al, monotone_knots(al.cells))
        frames[:, c] = ea(frames[:, p])
        frames[[0, -1], c] = segs[c].start, segs[c].end  # exact despite round-off at the last knot
        parents.append(p)
        edges.append(ea)
    return Registration(float(graph.rate), order, segs, parents, dist[order], frames, edges)
