"""Candidate clip pairs by approximate nearest neighbours over pose windows (issue 25, part 4).

KG04 §3 builds a match web for every pair of motions: O(clips²) webs, which a library without
categories (``index.chunk_by: none``) pays in full. Most pairs hold nothing the search returns
(a kick and a sit share no half second of motion). This stage shortlists the pairs worth a web;
the index then builds exact webs (``tasks.matchweb``) for those pairs only.

Descriptor. The features at the lowest rate (KG04 §3.2's coarsest level, 10 Hz by default) are
already windows: frame ``f``'s cloud holds the joints of the ``features.window`` frames centred on
it (``tasks.features.clip_features``, 0.5 s at 10 Hz). A window's descriptor is that cloud with
its horizontal coordinates centred on their weighted mean and every point scaled by the square
root of its weight, flattened: ``(3·P,)`` for ``P = window·J`` points. For two descriptors
``u, v`` and a rotation ``R`` about the vertical axis, ``|u − R v|²`` is the KG04 frame distance
(``tasks.distance``) for that rotation with the best horizontal translation (the centroids
aligned), so ``min_R |u − R v|²`` is the frame distance itself, the value of a cell of the
coarsest distance grid. Windows are taken every ``stride`` frames.

Rotation. The k-NN metric is plain Euclidean, so each query window is searched at ``headings``
headings ``2πh/headings`` (the database holds each window once, as recorded); a neighbour's
distance is the least over the headings, within a factor ``cos(π/headings)`` of the aligned
distance's cross term. No canonical heading is guessed from the pose (a principal axis of the
cloud flips or spins when the cloud is nearly round, e.g. standing still).

Neighbours → pairs. Each window keeps its ``k`` nearest other clips (each at its nearest window
over the headings; its own clip is excluded from the search) and, hubs (below), every other clip
within ``hub_ratio`` × the nearest one's distance; ``hits(a, b)`` counts the windows of ``a`` with
a neighbour in ``b`` plus the windows of ``b`` with a neighbour in ``a``. A pair is shortlisted
when ``hits ≥ min_hits``; every self pair is kept, as the exact index keeps them (KG04 §3.3 finds
repeats within a clip).

Hubs (issue 25, part 4). The search's default ε is ``eps_nearest_ratio`` (2) × the query's
nearest match in another clip (``tasks.ranking.default_epsilon``), so it returns every clip about
as close as the nearest one, however many: a standing pose, or a window whose nearest clip is far
while hundreds of clips are about as far (distances concentrate), matches hundreds of clips, more
than ``k``. The descriptor distance is the coarsest level's frame distance, the web's cell value
at that level, so the rule in the search's own form is: a window keeps every other clip within
``hub_ratio`` × the distance to its nearest other clip. ``hub_ratio`` (32) is measured, not
derived: ``eps_nearest_ratio``² = 4 would follow if a query's nearest average were about twice its
windows' least nearest, but a match's cost is a path average at the finest rate under the chain
rules, often 10-100 × its windows' descriptor distances (bench corpus: a sitting query's windows
are at 0.06 ε on average, some at 0: exact copies of a still pose), so 4 leaves the bench's sitting
hubs at recall 0 and 8 recovers them. A query whose nearest match is far (nothing in the library
moves like it, though each of its windows has near copies) gets an ε hundreds of times its windows'
nearest distances (one bench query: 300 ×), and its tiers 2-3 return thousands of matches along most pairs of the library
(one bench query: 5,589 matches along 80% of the cross pairs). Those few queries decide recall
pooled over queries: on the bench corpus (``bench/shortlist.py``, 100 queries, 3 tiers) 8 keeps 23%
of the pairs at recall 0.22 pooled (0.95 per query on average), 12 to 24 keep 35% to 56% at
0.70, 32 keeps 67% at 0.957 (0.994 per query). The default is 32, the least measured ratio that
meets recall ≥ 0.95 pooled; a library that can give up those queries' far matches saves more
pairs with 8-12. The radius r = ``hub_ratio`` × d₁ is taken from the window's own nearest, so it scales with the
skeleton, the motion's speed and the library, and a window with a near copy (d₁ ≈ 0) keeps the
copy only, as ε does. It costs a second pass only where the ``k`` nearest do not settle it: the
windows whose ``k``-th nearest clip is still within r (the hub windows; elsewhere every clip within
r is among the ``k``) get an exhaustive pass over every window at every heading
(:func:`_within_radius`), which also recomputes d₁ exactly.

Library: faiss (``faiss-cpu``, ``IndexHNSWFlat``). Chosen over hnswlib and pynndescent because on
Python 3.11+ with numpy 2 it installs as a binary wheel that needs numpy alone (hnswlib 0.8.0,
last released 2023-12, ships only a source archive that compiles C++ at install time; pynndescent
0.7 pulls in scikit-learn and joblib), it is maintained (releases through 2026), and it is
deterministic the way this project needs: HNSW levels come from a fixed seed inside faiss, the
graph is built with one OpenMP thread (faiss inserts in parallel otherwise, and the graph then
depends on thread timing), and a search's answer for one query does not depend on the threads.
It also restricts a search to other clips directly (``IDSelectorNot(IDSelectorRange)``), so a
long clip of near-identical windows (standing still) cannot fill a window's k neighbours with
itself.

Cost: descriptors O(W·P) for W windows; the HNSW build O(W·log W·M·P); the search
O(W·headings·ef_search·log W·P) — grows about as W log W, against O(W²) web grid cells of the
exact all-pairs index at the same rate; the hub pass O(Wₕ·W·headings·P) for Wₕ hub windows
(matrix products in blocks of ``_BLOCK_CELLS`` cells): it grows as W² times the fraction of hub
windows, a fraction the library sets (on the bench corpus see ``bench/shortlist.py``). Memory
O(W·P) for the database plus O(M·W) links plus one block. Pairs: the k-NN part keeps ≤ W·k
(window, clip) hits; the hub part as many as the windows within r, which is what the search at
the default ε needs.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from motionweb.tasks.params.shortlist import ShortlistParams

__all__ = ["Shortlist", "ShortlistParams", "rotate_about_vertical", "shortlist_pairs", "window_descriptors"]


def window_descriptors(features: np.ndarray, weights: np.ndarray, stride: int = 1) -> np.ndarray:
    """(W, 3·P) float32 descriptors of every ``stride``-th frame of ``features`` (F, P, 3) with point
    weights (P,) summing to 1: each cloud centred horizontally on its weighted mean, each point
    scaled by sqrt(weight), flattened point-major (x, y, z per point). See the module notes."""
    f = np.asarray(features, dtype=np.float64)[::max(1, int(stride))]
    w = np.asarray(weights, dtype=np.float64)
    if f.ndim != 3 or f.shape[2] != 3 or f.shape[1] != w.shape[0]:
        raise ValueError(f"features must be (F, P, 3) with P = {w.shape[0]} points, got {f.shape}")
    centred = f.copy()
    for axis in (0, 2):  # horizontal: x and z (column 1 is vertical)
        centred[:, :, axis] -= (f[:, :, axis] @ w)[:, None]
    centred *= np.sqrt(w)[None, :, None]
    return np.ascontiguousarray(centred.reshape(len(f), -1), dtype=np.float32)


def rotate_about_vertical(desc: np.ndarray, angle: float) -> np.ndarray:
    """Descriptors (W, 3·P) turned by ``angle`` radians about the vertical (y) axis."""
    d = desc.reshape(len(desc), -1, 3)
    c, s = np.cos(angle), np.sin(angle)
    out = np.empty_like(d)
    out[:, :, 0] = c * d[:, :, 0] + s * d[:, :, 2]
    out[:, :, 1] = d[:, :, 1]
    out[:, :, 2] = -s * d[:, :, 0] + c * d[:, :, 2]
    return out.reshape(desc.shape)


@dataclass
class Shortlist:
    """The shortlisted pairs of a set of clips.

    ``pairs``: sorted unordered pairs ``(a, b)`` with ``a <= b`` of clip keys, every self pair
    included; ``hits[(a, b)]``: the neighbour hits of each cross pair kept (see the module notes);
    ``windows``: windows indexed; ``candidates``: the pairs of the clips (self pairs included);
    ``hub_windows``: the windows given the radius pass (see the module notes)."""

    pairs: list[tuple[str, str]]
    hits: dict[tuple[str, str], int] = field(default_factory=dict)
    windows: int = 0
    candidates: int = 0
    hub_windows: int = 0

    def keeps(self, a: str, b: str) -> bool:
        return (min(a, b), max(a, b)) in self._set

    def __post_init__(self) -> None:
        self._set = set(self.pairs)


def _faiss():
    import faiss

    return faiss


def _knn(db: np.ndarray, owner_ranges: list[tuple[int, int]], queries: list[np.ndarray], k: int,
         params: ShortlistParams) -> tuple[np.ndarray, np.ndarray]:
    """For each clip c (``queries[c]``: its windows at every heading, (headings, Wc, D)), the ``k``
    nearest database windows outside ``owner_ranges[c]`` at each heading: (distances, ids), each
    (W, headings·k) with rows in database order (-1 ids where fewer exist)."""
    faiss = _faiss()
    threads = faiss.omp_get_max_threads()
    index = faiss.IndexHNSWFlat(db.shape[1], params.hnsw_m)
    index.hnsw.efConstruction = params.ef_construction
    faiss.omp_set_num_threads(1)  # a deterministic graph: faiss inserts in parallel otherwise
    try:
        index.add(db)
    finally:
        faiss.omp_set_num_threads(threads)
    n_head = queries[0].shape[0] if queries else 0
    dist = np.full((len(db), n_head * k), np.inf, np.float32)
    ids = np.full((len(db), n_head * k), -1, np.int64)
    for (lo, hi), q in zip(owner_ranges, queries, strict=True):
        if hi <= lo:
            continue
        outside = faiss.IDSelectorNot(faiss.IDSelectorRange(lo, hi))
        sp = faiss.SearchParametersHNSW(sel=outside, efSearch=max(params.ef_search, k))
        d, i = index.search(q.reshape(-1, db.shape[1]), k, params=sp)
        # (headings·Wc, k) → (Wc, headings·k)
        dist[lo:hi] = d.reshape(n_head, hi - lo, k).transpose(1, 0, 2).reshape(hi - lo, -1)
        ids[lo:hi] = i.reshape(n_head, hi - lo, k).transpose(1, 0, 2).reshape(hi - lo, -1)
    return dist, ids


def _nearest_clips(dist: np.ndarray, ids: np.ndarray, owner: np.ndarray, k: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row (window), the ``k`` other clips whose nearest window over the headings is nearest:
    (rows, clips, distances) flat, by row then distance, ties broken by window id (deterministic)."""
    rows = np.repeat(np.arange(len(ids)), ids.shape[1])
    d, i = dist.ravel(), ids.ravel()
    ok = i >= 0
    rows, d, i = rows[ok], d[ok], i[ok]
    order = np.lexsort((i, d, rows))  # by row, then distance, then window id
    rows, c, d = rows[order], owner[i[order]], d[order]
    _, first = np.unique(rows * np.int64(owner.max() + 1) + c, return_index=True)
    first.sort()  # each (row, clip) once, at its nearest window, in distance order
    rows, c, d = rows[first], c[first], d[first]
    rank = np.arange(len(rows)) - np.searchsorted(rows, rows, side="left")
    keep = rank < k
    return rows[keep], c[keep], d[keep]


def _full_rows(rows: np.ndarray, dist: np.ndarray, k: int, ratio: float) -> np.ndarray:
    """Hub candidates (issue 25, part 4): the rows (windows) whose ``k`` nearest other clips
    (``rows``, ``dist`` as :func:`_nearest_clips` returns them, by row then distance) are all
    within ``ratio`` × the nearest one, so more clips may be within it: sorted row numbers."""
    starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
    counts = np.diff(np.r_[starts, len(rows)])
    full = counts >= k
    last = starts + counts - 1
    full &= dist[last] <= ratio * dist[starts]
    return rows[starts[full]]


#: windows × database windows of one block of the radius pass (float32: 4 bytes each, ~64 MB)
_BLOCK_CELLS = 1 << 24


def _within_radius(db: np.ndarray, bounds: np.ndarray, owner: np.ndarray, rows: np.ndarray, angles: np.ndarray,
                   ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """The radius pass for hub windows (issue 25, part 4): for each database window ``rows[i]``
    (``db`` (W, D), clip ``c`` owning rows ``bounds[c]:bounds[c + 1]``, ``owner`` (W,)), every
    other clip whose nearest window over the headings ``angles`` (H,) is within ``ratio`` × the
    nearest other clip's: (rows, clips) flat, by row then clip.

    Exhaustive, not approximate: the distances of the rows to every window at every heading
    (``|R u|² + |v|² − 2 R u·v``, float32 matrix products), least per clip
    (``np.minimum.reduceat``). Cost O(len(rows)·W·D·H) time, O(W) memory per row in blocks of
    ``_BLOCK_CELLS`` cells. Why not HNSW: a hub's clips lie among thousands of near-identical
    windows (each clip standing still holds tens of them), which a beam of ``ef_search`` does not
    reach past; faiss's HNSW range search keeps a bounded beam too."""
    norms = np.einsum("ij,ij->i", db, db)
    block = max(1, _BLOCK_CELLS // max(1, len(db)))
    out_rows, out_clips = [], []
    for lo in range(0, len(rows), block):
        r = rows[lo:lo + block]
        best = np.full((len(r), len(db)), np.inf, np.float32)
        for a in angles:
            q = rotate_about_vertical(db[r], float(a))
            np.minimum(best, np.einsum("ij,ij->i", q, q)[:, None] + norms[None] - 2 * (q @ db.T), out=best)
        per = np.minimum.reduceat(best, bounds[:-1], axis=1)  # (rows, clips): least over each clip's windows
        per[np.arange(len(r)), owner[r]] = np.inf
        np.maximum(per, 0, out=per)  # rounding of the expansion
        near = per <= ratio * per.min(axis=1, keepdims=True)
        i, c = np.nonzero(near)
        out_rows.append(r[i])
        out_clips.append(c)
    if not out_rows:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(out_rows).astype(np.int64), np.concatenate(out_clips).astype(np.int64)


def shortlist_pairs(clips: Mapping[str, tuple[np.ndarray, np.ndarray]],
                    params: ShortlistParams | None = None) -> Shortlist:
    """The shortlist of ``clips``: key -> (features at the lowest rate (F, P, 3), point weights
    (P,)), every clip with the same points (one skeleton). Same input, same output: clips are
    taken in key order whatever the mapping's order. See the module notes for the descriptor,
    the neighbours and the cost."""
    params = params or ShortlistParams()
    keys = sorted(clips)
    self_pairs = [(c, c) for c in keys]
    n_cand = len(keys) * (len(keys) + 1) // 2
    if len(keys) < 2:
        return Shortlist(self_pairs, {}, 0, n_cand)
    descs = [window_descriptors(*clips[c], params.stride) for c in keys]
    dims = {d.shape[1] for d in descs}
    if len(dims) != 1:
        raise ValueError(f"clips of a shortlist must have the same points, got descriptor sizes {sorted(dims)}")
    sizes = np.array([len(d) for d in descs])
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    owner = np.repeat(np.arange(len(keys)), sizes)
    db = np.ascontiguousarray(np.concatenate(descs))
    angles = 2 * np.pi * np.arange(params.headings) / params.headings
    queries = [np.stack([rotate_about_vertical(d, a) for a in angles]) for d in descs]
    kw = min(max(params.k, params.k_windows), len(db) - int(sizes.min()))
    dist, ids = _knn(db, [(int(bounds[c]), int(bounds[c + 1])) for c in range(len(keys))], queries, kw, params)
    rows, b, near = _nearest_clips(dist, ids, owner, params.k)
    full = np.zeros(0, np.int64)
    if params.hub_ratio > 0:  # hubs: every clip within hub_ratio × the nearest, past the k nearest
        full = _full_rows(rows, near, params.k, params.hub_ratio)
        hr, hb = _within_radius(db, bounds, owner, full, angles, params.hub_ratio)
        rows, b = np.concatenate([rows, hr]), np.concatenate([b, hb])
    # one hit per (window, other clip)
    _, first = np.unique(rows * np.int64(len(keys)) + b, return_index=True)
    rows, b = rows[first], b[first]
    qa = owner[rows]
    lo, hi = np.minimum(qa, b), np.maximum(qa, b)
    pair_ids, counts = np.unique(lo * len(keys) + hi, return_counts=True)
    hits = {(keys[int(p // len(keys))], keys[int(p % len(keys))]): int(n)
            for p, n in zip(pair_ids, counts, strict=True) if n >= params.min_hits}
    pairs = sorted(self_pairs + list(hits))
    return Shortlist(pairs, hits, len(db), n_cand, len(full))
