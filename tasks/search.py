"""Search over match webs: match sequences, redundancy removal, tiers, the match graph (KG04 §3.3;
design §5).

A query is a segment ``M1[a, b]`` (frames at the web rate, inclusive) and a threshold ε. For each
web (M1, M2) the search intersects the web with rows a..b (KG04 Fig. 9): from every path with a
cell in row a (its earliest such cell) it walks along the path, branching onto bridges, until a
cell in row b; the columns of the first and last cells give the match ``M2[c, d]``, kept when the
average cell value of the walk is at most ε.

The walk (choice made here). Rather than enumerating every match sequence, which is exponential
in the number of bridges crossed, the webs of a clip are packed into one DAG whose states are the
cells of paths and bridge interiors (:class:`WalkGraph`; a bridge's first and last cells are the
path cells it joins). Cells advance by one row or column per step, so ``row + col`` orders the
states topologically. Per start cell a dynamic program over the states reachable within rows
a..b finds, for every terminal cell (the last cell of a row-b run), the walk of least average
value exactly, by Dinkelbach's parametric method: a walk with average ≤ λ exists iff the least
total of ``value − λ`` is ≤ 0, a plain shortest-path DP. λ = ε decides which terminals match;
each match is then refined with λ ← average of its current walk until the average stops
decreasing (a few passes). Cost of one query on one clip: per start (the earliest row-a cell of
a path, read from a table built when packing), O(R) for the R states reachable in the band of
rows a..b, and O(R) per refinement pass of a kept match — linear in the size of the webs searched,
as KG04 §3.4 reports. The trivial identity match of a self web cannot occur: self webs mask the
band |i − j| ≤ ``self_band_s`` (``tasks.matchweb.minima.mask_self_band``), and a match overlapping the
query anyway is absorbed by the query node (dedup below).

Matches shorter than the minimum chain length or with an overall slope outside [1/k, k] are not
kept (they could not be queries of the next tier; see :meth:`MatchSearch.matches`).

Redundancy removal (KG04 §3.3): matches sorted by average value, the best kept, every other
overlapping it by more than ``SearchParams.overlap_redundant`` dropped, repeat.

Tiers and the match graph (KG04 §3.3, Fig. 10): every new node becomes a query in turn, up to
``max_tiers`` tiers, until nothing new appears. A match M' of query node M is compared with every
node; m = its largest overlap (``Segment.overlap``). m < ``new_node_below``: new node and edge
M–M'; m > ``merge_above``: the node's interval is averaged with M' (the query node's interval is
never changed) and an edge M–node added; otherwise M' is discarded. One edge per node pair (the
cheaper kept). Edge cost = average cell value; node distance = shortest-path cost to the query
(Dijkstra); nodes 1.. are returned sorted by that distance. A full search costs one query per
node.

Nearest matches and trial ranking (design §5): :func:`nearest_matches` finds, per web, the match
of least average in one pass over the states of the query's rows for all starts at once (per-web
Dinkelbach), which the default ε rule and the trial ranking use (``tasks.ranking``).

Webs come from a mapping ``clip -> [(other clip, web with clip as rows), ...]`` (:data:`WebSource`),
so the core needs no store; :class:`motionweb.store.webs.StoreWebs` builds that mapping from a
store generation.
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from motionweb.store.cache import LRU, array_bytes
from motionweb.store.filecache import FileCache
from motionweb.store.web import MatchWeb
from motionweb.store.webs import WebSource
from motionweb.tasks.matchgraph import MatchEdge, MatchGraph, MatchNode, Segment
from motionweb.tasks.matchweb.params import MatchWebParams, min_chain_extent
from motionweb.tasks.params.search import SearchParams
from motionweb.store.numba_cache import njit
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

INF = np.inf


# ----------------------------------------------------------------------------------------------
# the webs of one clip as one DAG of cells
# ----------------------------------------------------------------------------------------------


@dataclass
class WalkGraph:
    """The webs of one clip (its frames are the rows) packed into one DAG of cells (KG04 §3.3).

    State s is a cell ``(rows[s], cols[s])`` with value ``values[s]``: the cells of the paths and
    the bridge interiors of every web (a bridge's first and last cells are the path cells it
    joins), numbered by (web, row, col) — per web a topological order, as every step advances the
    row or the column — so the states of web w in rows a..b are ``web_rows[w, a]..web_rows[w, b + 1] − 1``
    (``web_rows`` is (W, F + 1)). ``nxt[s]`` is the next cell along the same path or bridge (the
    last interior cell of a bridge continues onto the cell it joins; −1 at a path's end);
    ``branch_to[branch_off[s]:branch_off[s + 1]]`` are the bridges leaving path cell s (their first
    interior cell, or the joined cell for a two-cell bridge). The walks of rows a.. start at the
    earliest row-a cell of each path crossing row a: for web w these are
    ``starts[start_off[w·F + a]:start_off[w·F + a + 1]]``, in path order. ``others[w]`` is the
    columns clip of web w. The work buffers of :func:`_walk` are not the graph's: one set per thread,
    grown to the largest band walked (:func:`work_buffers`), so a cache of graphs holds their
    states only.
    """

    rate: float
    n_frames: int
    others: tuple[str, ...]
    rows: np.ndarray
    cols: np.ndarray
    values: np.ndarray
    nxt: np.ndarray
    branch_off: np.ndarray
    branch_to: np.ndarray
    web_rows: np.ndarray
    start_off: np.ndarray
    starts: np.ndarray
    #: steps of malformed webs that did not advance (dropped by :func:`walk_graph`; 0 for sound webs)
    dropped_steps: int = 0
    clip_names: list[str] = field(init=False, repr=False)
    clip_rank: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.clip_names = sorted(set(self.others))
        self.clip_rank = np.searchsorted(self.clip_names, self.others).astype(np.int64)

    @property
    def n_states(self) -> int:
        return len(self.rows)

    @property
    def nbytes(self) -> int:
        """Bytes its arrays span (what the service's memory cache counts for a packed graph; the
        work buffers are the thread's)."""
        return array_bytes(self.rows, self.cols, self.values, self.nxt, self.branch_off, self.branch_to,
                           self.web_rows, self.start_off, self.starts, self.clip_rank)

    #: the arrays of :meth:`to_arrays` (what is packed; ``clip_rank`` follows from ``others``)
    STORED = ("rows", "cols", "values", "nxt", "branch_off", "branch_to", "web_rows", "start_off", "starts")
    #: bump when packing changes what a graph holds: it enters every graph's content key
    LAYOUT = 1

    def to_arrays(self) -> tuple[dict[str, np.ndarray], dict]:
        """(flat arrays, JSON metadata) of the packed graph, without the clip names (the
        reader's web records give them, in the same order): :meth:`from_arrays` inverts it."""
        meta = {"layout": self.LAYOUT, "rate": self.rate, "n_frames": self.n_frames,
                "n_webs": len(self.others), "dropped_steps": self.dropped_steps}
        return {k: getattr(self, k) for k in self.STORED}, meta

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], meta: dict, others: Sequence[str]) -> WalkGraph:
        """A graph of :meth:`to_arrays` (e.g. read back from a file) for the webs with ``others``,
        checked (:meth:`check`: ValueError) before any compiled walk can index with it."""
        if meta.get("layout") != cls.LAYOUT or meta.get("n_webs") != len(others):
            raise ValueError(f"a packed graph of layout {meta.get('layout')} for {meta.get('n_webs')} webs, "
                             f"not layout {cls.LAYOUT} for {len(others)}")
        got = {k: np.require(arrays[k], requirements=["C", "A", "W"]) for k in cls.STORED}
        g = cls(rate=float(meta["rate"]), n_frames=int(meta["n_frames"]), others=tuple(others),
                dropped_steps=int(meta["dropped_steps"]), **got)
        g.check()
        return g

    def check(self) -> None:
        """The invariants the compiled walks index by (ValueError naming the first that fails):
        lengths and dtypes agree, every state number and offset lies in range, offsets never
        fall, and every step (``nxt``, ``branch_to``) advances the row or the column and never
        lowers either. :func:`walk_graph` makes them so; a graph read from outside is checked.
        O(states + branches)."""
        n, f, w = self.n_states, self.n_frames, len(self.others)
        ints = (self.rows, self.cols, self.nxt, self.branch_off, self.branch_to, self.web_rows, self.start_off,
                self.starts)

        def need(ok: bool, what: str) -> None:
            if not ok:
                raise ValueError(f"packed walk graph: {what}")

        need(all(a.dtype.kind == "i" for a in ints) and self.values.dtype.kind == "f", "arrays of the wrong kind")
        need(len(self.cols) == n and len(self.values) == n and len(self.nxt) == n, "state arrays differ in length")
        need(self.branch_off.shape == (n + 1,) and self.web_rows.shape == (w, f + 1)
             and self.start_off.shape == (w * f + 1,), "offset tables of the wrong shape")

        def offsets(a: np.ndarray, last: int) -> bool:
            return bool(a.size == 0 or (a.flat[0] == 0 and a.flat[-1] == last and np.all(np.diff(a.ravel()) >= 0)))

        need(offsets(self.branch_off, len(self.branch_to)) and offsets(self.start_off, len(self.starts)),
             "branch or start offsets out of order")
        need(bool(np.all((self.web_rows >= 0) & (self.web_rows <= n))) and bool(np.all(np.diff(self.web_rows, axis=1) >= 0)),
             "web row table out of range")
        need(self.starts.size == 0 or (self.starts.min() >= 0 and self.starts.max() < n), "a start state out of range")
        bad = _steps_ok(self.rows, self.cols, self.nxt, self.branch_off, self.branch_to, f)
        need(bad == 0, ("", "a cell out of range", "a next state out of range", "a branch state out of range",
                        "a step that does not advance")[min(bad, 4)])

    def band(self, a: int, b: int) -> int:
        """The most states one web has in rows a..b (``web_rows[w, b + 1] − web_rows[w, a]``): the
        work buffers a walk of those rows needs (:func:`work_buffers`). Requires 0 ≤ a ≤ b < F."""
        return int((self.web_rows[:, b + 1] - self.web_rows[:, a]).max(initial=0))


_POOL = threading.local()


def work_buffers(n: int) -> tuple[np.ndarray, ...]:
    """The work buffers of :func:`_walk` for bands of up to ``n`` states (:meth:`WalkGraph.band`;
    7 arrays ``(n,)``: ``local`` all 0, which every walk restores, then reach, stack, cost, total,
    length, pred): views of one set per thread, grown (by at least a quarter) when a larger band
    is walked. The walks of a thread run one at a time, so every graph of a thread shares them:
    56 bytes per state of the largest band walked (one web's states in the rows of a query), not
    of a whole graph, nor of every graph kept."""
    have = getattr(_POOL, "work", None)
    if have is None or len(have[0]) < n:
        m = max(n, len(have[0]) * 5 // 4) if have is not None else n
        _POOL.work = have = (np.zeros(m, np.int64), np.empty(m, np.int64), np.empty(m, np.int64),
                             np.empty(m, np.float64), np.empty(m, np.float64), np.empty(m, np.int64),
                             np.empty(m, np.int64))
    return tuple(x[:n] for x in have)


def _check_web(web: MatchWeb) -> None:
    """The structure :func:`walk_graph` relies on, checked before packing (ValueError): cells inside
    the web's shape, junction indices inside their paths. A web read from a damaged or foreign
    store fails here, not in the compiled walk."""
    fa, fb = web.shape
    for what, cells in (("path", web.paths_cells), ("bridge", web.bridges_cells)):
        if len(cells) and (cells.min(initial=0) < 0 or cells[:, 0].max() >= fa or cells[:, 1].max() >= fb):
            raise ValueError(f"a {what} cell of the web lies outside its {fa}x{fb} grid")
    if len(web.bridges):
        lens = np.diff(web.paths_offsets)
        p, q = web.bridges[:, 0], web.bridges[:, 2]
        if (p.min() < 0 or q.min() < 0 or p.max() >= web.n_paths or q.max() >= web.n_paths
                or np.any(web.bridges[:, 1] < 0) or np.any(web.bridges[:, 3] < 0)
                or np.any(web.bridges[:, 1] >= lens[np.clip(p, 0, len(lens) - 1)])
                or np.any(web.bridges[:, 3] >= lens[np.clip(q, 0, len(lens) - 1)])):
            raise ValueError("a bridge of the web joins a path cell that does not exist")


def _gathered(webs: Sequence[MatchWeb]) -> dict:
    """The arrays of all ``webs`` end to end, what :func:`_packed_states` and :func:`_window_states`
    number states from: ``offs`` (P + 1,) every path's first cell as a global cell number (then
    the cell count), ``cells`` (Nc, 2) and ``pvals`` (Nc,) the path cells and values,
    ``path_web`` (P,) each path's web, ``bridges`` (B, 4) with global path numbers,
    ``web_of_bridge`` (B,), ``bcells`` (Nb, 2), ``bvals`` (Nb,) and ``boffs`` (B + 1,) the bridge
    cells. O(cells + bridges) copies, no Python per cell."""
    n_webs = len(webs)
    p_cells = np.array([len(w.paths_cells) for w in webs], np.int64)
    n_paths = np.array([w.n_paths for w in webs], np.int64)
    n_br = np.array([len(w.bridges) for w in webs], np.int64)
    cell_base = np.concatenate([[0], np.cumsum(p_cells)])
    path_base = np.concatenate([[0], np.cumsum(n_paths)])
    n_cells = int(cell_base[-1])
    offs = np.concatenate([w.paths_offsets[:-1].astype(np.int64) + cell_base[i] for i, w in enumerate(webs)]
                          + [np.array([n_cells], np.int64)])
    web_of_br = np.repeat(np.arange(n_webs), n_br)
    br = np.concatenate([w.bridges.reshape(-1, 4) for w in webs]).astype(np.int64)
    br[:, 0] += path_base[web_of_br]
    br[:, 2] += path_base[web_of_br]
    blens = np.concatenate([np.diff(w.bridges_offsets) for w in webs]).astype(np.int64)
    return {
        "n_webs": n_webs, "offs": offs, "path_web": np.repeat(np.arange(n_webs), n_paths),
        "cells": np.concatenate([w.paths_cells for w in webs]).reshape(-1, 2),
        "pvals": np.concatenate([w.paths_values for w in webs]),
        "bridges": br, "web_of_bridge": web_of_br,
        "bcells": np.concatenate([w.bridges_cells for w in webs]).reshape(-1, 2),
        "bvals": np.concatenate([w.bridges_values for w in webs]),
        "boffs": np.concatenate([[0], np.cumsum(blens)]),
    }


def _packed_states(webs: Sequence[MatchWeb]) -> dict[str, np.ndarray]:
    """States, successors and branches of all ``webs`` at once (vectorised over every cell of
    every web: no Python per web beyond gathering its arrays). Numbering: every web's path cells
    in web and path order, then every web's bridge interiors in web and bridge order; within a
    web that is its path cells then its bridge interiors, so the (web, row, col) sort of
    :func:`walk_graph` breaks ties in the same order as per-web packing (``tests/naive.py``
    ``ref_walk_graph``).

    A bridge of fewer than two cells (two paths that share a cell: the junction's cells coincide)
    is a switch of path at that cell, not a step: its branches go from the shared cell of the
    leaving path straight to the successors of the joined path's cell (the next cell of that path
    and its bridges of two or more cells), so the shared cell is counted once and no step stays in
    place (KG04 §3.3 walks advance a row or a column per step; :func:`walk_graph` relies on it).
    O(cells + bridges · log bridges)."""
    g = _gathered(webs)
    n_webs, offs, cells, br, web_of_br, bcells, boffs = (g[k] for k in ("n_webs", "offs", "cells", "bridges",
                                                                         "web_of_bridge", "bcells", "boffs"))
    n_cells = int(offs[-1])
    nxt = np.arange(1, n_cells + 1, dtype=np.int64)
    plen = np.diff(offs)
    nxt[offs[1:][plen > 0] - 1] = -1
    blens = np.diff(boffs)
    from_state = offs[br[:, 0]] + br[:, 1]
    to_state = offs[br[:, 2]] + br[:, 3]
    inner = np.maximum(blens - 2, 0)
    inner_start = n_cells + np.cumsum(inner) - inner
    keep = np.ones(len(bcells), bool)
    keep[boffs[:-1][blens > 0]] = False
    keep[boffs[1:][blens > 0] - 1] = False
    # the interiors web by web: a web's bridges are consecutive, so this is web then bridge order
    inner_cells = bcells[keep]
    n_inner = int(inner.sum())
    inner_nxt = np.arange(n_cells + 1, n_cells + n_inner + 1, dtype=np.int64)
    last_inner = (inner_start + inner - 1)[inner > 0] - n_cells
    inner_nxt[last_inner] = to_state[inner > 0]
    switch = (blens < 2) | (cells[from_state] == cells[to_state]).all(axis=1)
    proper = ~switch
    b_from, b_to = from_state[proper], np.where(inner > 0, inner_start, to_state)[proper]
    if switch.any():
        b_from, b_to = _with_switches(b_from, b_to, from_state[switch], to_state[switch], nxt[to_state[switch]])
    i_count = np.bincount(web_of_br, weights=inner, minlength=n_webs).astype(np.int64)
    return {
        "cells": np.concatenate([cells, inner_cells]).astype(np.int32),
        "values": np.concatenate([g["pvals"], g["bvals"][keep]]).astype(np.float32),
        "nxt": np.concatenate([nxt, inner_nxt]),
        "web_of": np.concatenate([np.repeat(g["path_web"], plen), np.repeat(np.arange(n_webs), i_count)]),
        "branch_from": b_from.astype(np.int64),
        "branch_to": b_to.astype(np.int64),
        "path_first": offs[:-1],
        "path_last": offs[1:] - 1,
    }


def _with_switches(b_from: np.ndarray, b_to: np.ndarray, sw_from: np.ndarray, sw_to: np.ndarray,
                   after: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The branches ``b_from → b_to`` (proper bridges) and, for each switch ``sw_from → sw_to``
    (a bridge of < 2 cells), branches from ``sw_from`` to what follows the joined cell: its path's
    next cell ``after`` (when ≥ 0) and the proper bridges leaving ``sw_to``, in that order."""
    order = np.argsort(b_from, kind="stable")
    lo = np.searchsorted(b_from[order], sw_to, "left")
    hi = np.searchsorted(b_from[order], sw_to, "right")
    return (np.concatenate([b_from, sw_from[after >= 0], np.repeat(sw_from, hi - lo)]),
            np.concatenate([b_to, after[after >= 0], b_to[order[np.repeat(lo, hi - lo) + _ranges(hi - lo)]]]))


def _check_webs(webs: Sequence[tuple[str, MatchWeb]]) -> None:
    """:func:`_check_web` for every web, vectorised (the per-web check runs only to name the first
    web that fails). O(cells + bridges)."""
    fb = np.array([w.shape[1] for _, w in webs], np.int64)
    fa = np.array([w.shape[0] for _, w in webs], np.int64)
    ok = True
    for attr, off in (("paths_cells", None), ("bridges_cells", None)):
        counts = np.array([len(getattr(w, attr)) for _, w in webs], np.int64)
        c = np.concatenate([getattr(w, attr) for _, w in webs]).reshape(-1, 2)
        if len(c):
            ok &= bool(c.min() >= 0) and bool(np.all(c[:, 0] < np.repeat(fa, counts))) \
                and bool(np.all(c[:, 1] < np.repeat(fb, counts)))
    nb = np.array([len(w.bridges) for _, w in webs], np.int64)
    if ok and nb.sum():
        npaths = np.array([w.n_paths for _, w in webs], np.int64)
        base = np.concatenate([[0], np.cumsum(npaths)])
        lens = np.concatenate([np.diff(w.paths_offsets) for _, w in webs]).astype(np.int64)
        br = np.concatenate([w.bridges.reshape(-1, 4) for _, w in webs]).astype(np.int64)
        web = np.repeat(np.arange(len(webs)), nb)
        p, q, limit = br[:, 0], br[:, 2], npaths[web]
        ok = bool(np.all((p >= 0) & (q >= 0) & (p < limit) & (q < limit) & (br[:, 1] >= 0) & (br[:, 3] >= 0)))
        if ok:
            ok = bool(np.all((br[:, 1] < lens[base[web] + p]) & (br[:, 3] < lens[base[web] + q])))
    if not ok:
        for other, w in webs:
            try:
                _check_web(w)
            except ValueError as exc:
                raise ValueError(f"match web with {other!r}: {exc}; run motionweb index to recompute it") from None
        raise AssertionError("the vectorised web check and _check_web disagree")  # pragma: no cover


def _packed_window(webs: Sequence[MatchWeb], a: int, b: int) -> dict[str, np.ndarray]:
    """The states of :func:`_packed_states` that a walk of rows a'..b' ⊆ a..b may use, array for
    array as ``tests/naive.py`` ``ref_cut_rows`` cuts them from all the states, without numbering
    those outside the window: the webs gathered (:func:`_gathered`, copies), then one compiled
    pass (:func:`_window_states`). O(cells + bridges) to gather and mark, O(window states +
    bridges · log bridges) after.

    Kept: the states of rows a..b, plus each path's last cell before row a when its next cell
    lies in rows ≥ a (the row-start table of :func:`_renumbered` reads a path cell's predecessor's
    row); a step to a state left out ends (``nxt`` −1) or is dropped (branches). A walk of rows
    a'..b' never takes a step to a row past b' (:func:`_collect`) nor reaches a row before a', so
    it finds the same matches in the window's states as in all of them (KG04 §3.3 walks;
    ``tests/tasks/test_search_props.py`` checks it)."""
    g = _gathered(webs)
    out = _window_states(g["offs"], g["cells"], g["pvals"], g["path_web"], g["bridges"], g["web_of_bridge"],
                         g["bcells"], g["bvals"], g["boffs"], a, b)
    return dict(zip(("cells", "values", "nxt", "web_of", "branch_from", "branch_to", "path_first", "path_last"),
                    out))


@njit(cache=True)
def _window_states(offs, cells, pvals, path_web, br, br_web, bcells, bvals, boffs, a, b):
    """The states of rows a..b of the gathered webs (:func:`_gathered`), numbered, stepped and
    branched as :func:`_packed_states` numbers them and :func:`_packed_window` cuts them (KG04 §3.3
    walks): a path cell of rows a..b, or the last of its path before row a when the next is in a
    row ≥ a; a bridge interior cell of rows a..b. Returns (cells (K, 2) int32, values (K,)
    float32, nxt, web_of, branch_from, branch_to, path_first, path_last) in the new numbering.
    Branches come in :func:`_packed_states`'s order (proper bridges, then each switch's step onto
    its joined path, then each switch's bridges of the joined cell) filtered to those with both
    ends kept. O(cells + bridges · log bridges); ``new`` is one int64 per state.

    Bounds: path numbers of ``br`` lie in 0..P−1 and cell indices in their paths, bridge cells
    in their ``boffs`` ranges (:func:`_check_webs` before packing); every state index written is
    < the counts computed in the first passes."""
    n_paths = len(offs) - 1
    n_cells = offs[n_paths]
    n_br = len(br)
    from_s = np.empty(n_br, np.int64)
    to_s = np.empty(n_br, np.int64)
    inner = np.empty(n_br, np.int64)
    inner_start = np.empty(n_br, np.int64)
    n_inner = 0
    for k in range(n_br):
        from_s[k] = offs[br[k, 0]] + br[k, 1]
        to_s[k] = offs[br[k, 2]] + br[k, 3]
        inner[k] = max(boffs[k + 1] - boffs[k] - 2, 0)
        inner_start[k] = n_cells + n_inner
        n_inner += inner[k]
    new = np.empty(n_cells + n_inner, np.int64)
    path_first = np.empty(n_paths, np.int64)
    path_last = np.empty(n_paths, np.int64)
    cnt = 0
    for p in range(n_paths):
        path_first[p] = cnt
        e = offs[p + 1]
        for s in range(offs[p], e):
            r = cells[s, 0]
            if (a <= r <= b) or (r < a and s + 1 < e and cells[s + 1, 0] >= a):
                new[s] = cnt
                cnt += 1
            else:
                new[s] = -1
        path_last[p] = cnt - 1
    for k in range(n_br):
        for j in range(inner[k]):
            r = bcells[boffs[k] + 1 + j, 0]
            if a <= r <= b:
                new[inner_start[k] + j] = cnt
                cnt += 1
            else:
                new[inner_start[k] + j] = -1
    out_cells = np.empty((cnt, 2), np.int32)
    out_vals = np.empty(cnt, np.float32)
    out_nxt = np.empty(cnt, np.int64)
    out_web = np.empty(cnt, np.int64)
    for p in range(n_paths):
        e = offs[p + 1]
        for s in range(offs[p], e):
            i = new[s]
            if i >= 0:
                out_cells[i, 0] = cells[s, 0]
                out_cells[i, 1] = cells[s, 1]
                out_vals[i] = pvals[s]
                out_web[i] = path_web[p]
                out_nxt[i] = new[s + 1] if s + 1 < e else -1
    for k in range(n_br):
        for j in range(inner[k]):
            i = new[inner_start[k] + j]
            if i >= 0:
                c = boffs[k] + 1 + j
                out_cells[i, 0] = bcells[c, 0]
                out_cells[i, 1] = bcells[c, 1]
                out_vals[i] = bvals[c]
                out_web[i] = br_web[k]
                out_nxt[i] = new[inner_start[k] + j + 1] if j + 1 < inner[k] else new[to_s[k]]
    # branches: proper bridges, then the switches' steps onto their joined paths, then the
    # switches' bridges of the joined cells (each list in bridge order), both ends kept
    switch = np.empty(n_br, np.bool_)
    n_proper = 0
    for k in range(n_br):
        switch[k] = (boffs[k + 1] - boffs[k] < 2 or (cells[from_s[k], 0] == cells[to_s[k], 0]
                                                    and cells[from_s[k], 1] == cells[to_s[k], 1]))
        if not switch[k]:
            n_proper += 1
    p_from = np.empty(n_proper, np.int64)
    p_to = np.empty(n_proper, np.int64)
    q = 0
    for k in range(n_br):
        if not switch[k]:
            p_from[q] = from_s[k]
            p_to[q] = inner_start[k] if inner[k] > 0 else to_s[k]
            q += 1
    by_from = np.argsort(p_from, kind="mergesort")
    sorted_from = p_from[by_from]
    bf = []
    bt = []
    for q in range(n_proper):
        if new[p_from[q]] >= 0 and new[p_to[q]] >= 0:
            bf.append(new[p_from[q]])
            bt.append(new[p_to[q]])
    # the step after a switch's joined cell: the next cell of its path (``_packed_states``'s nxt)
    for k in range(n_br):
        if switch[k]:
            t = to_s[k]
            after = t + 1 if t + 1 < offs[br[k, 2] + 1] else -1
            if after >= 0 and new[from_s[k]] >= 0 and new[after] >= 0:
                bf.append(new[from_s[k]])
                bt.append(new[after])
    for k in range(n_br):
        if switch[k]:
            lo = np.searchsorted(sorted_from, to_s[k], "left")
            hi = np.searchsorted(sorted_from, to_s[k], "right")
            for m in range(lo, hi):
                v = p_to[by_from[m]]
                if new[from_s[k]] >= 0 and new[v] >= 0:
                    bf.append(new[from_s[k]])
                    bt.append(new[v])
    n_b = len(bf)
    out_from = np.empty(n_b, np.int64)
    out_to = np.empty(n_b, np.int64)
    for m in range(n_b):
        out_from[m] = bf[m]
        out_to[m] = bt[m]
    return out_cells, out_vals, out_nxt, out_web, out_from, out_to, path_first, path_last


def walk_graph(webs: Sequence[tuple[str, MatchWeb]], rows: tuple[int, int] | None = None) -> WalkGraph:
    """Pack the webs of one clip (each with that clip as rows) into a :class:`WalkGraph` (KG04
    §3.3). O(cells + bridges + webs · frames + columns): the states gathered for all webs at once
    (:func:`_packed_states`), put in (web, row, col) order and renumbered by two compiled passes
    (:func:`_pack_order`, :func:`_renumbered`; 1.9 s for an 11 M-state graph of 118 webs of the
    million-frame store, 4.1 s with numpy sorts). ``tests/naive.py`` ``ref_walk_graph`` packs
    the webs one at a time and renumbers with numpy (``ref_graph_of``).

    ``rows`` (a, b): a window graph, the states a walk of rows within a..b uses (:func:`_packed_window`):
    the same matches for such walks, at the cost of gathering the states plus O(window states +
    webs · frames) for the kernels, and a graph of the window's size, not the clip's."""
    if not webs:
        raise ValueError("no match webs to search")
    rates = {float(w.rate) for _, w in webs}
    frames = {int(w.shape[0]) for _, w in webs}
    if len(rates) != 1 or len(frames) != 1:
        raise ValueError(f"the webs of one clip disagree on rate {sorted(rates)} or rows {sorted(frames)}")
    n_frames = frames.pop()
    _check_webs(webs)
    if rows is None:
        cat = _packed_states([w for _, w in webs])
    else:
        cat = _packed_window([w for _, w in webs], max(int(rows[0]), 0), min(int(rows[1]), n_frames - 1))
    rows, cols = np.ascontiguousarray(cat["cells"][:, 0]), np.ascontiguousarray(cat["cells"][:, 1])
    # renumber the states by (web, row, col); ties keep the packing order
    order = _pack_order(cat["web_of"], rows, cols, len(webs), n_frames, int(cols.max(initial=0)) + 1)
    nxt, branch_off, branch_to, dropped, web_rows, start_off, starts = _renumbered(
        rows, cols, cat["nxt"], cat["web_of"], cat["branch_from"], cat["branch_to"], cat["path_first"],
        cat["path_last"], order, len(webs), n_frames)
    return WalkGraph(
        rate=rates.pop(), n_frames=n_frames, others=tuple(o for o, _ in webs), rows=rows[order], cols=cols[order],
        values=cat["values"][order], nxt=_narrow(nxt), branch_off=_narrow(branch_off), branch_to=_narrow(branch_to),
        dropped_steps=int(dropped), web_rows=_narrow(web_rows), start_off=_narrow(start_off), starts=_narrow(starts))


@njit(cache=True)
def _pack_order(web_of, rows, cols, n_webs, n_frames, width):
    """The states (N,) in (web, row, col) order, ties in packing order: the stable argsort of
    ``(web · F + row) · width + col``, as two stable counting sorts (by column, then by web and
    row). O(N + W · F + width). Bounds: the caller's cells lie in rows 0..F−1 and columns
    0..width−1 (:func:`_check_webs`), webs 0..W−1."""
    n = len(rows)
    count = np.zeros(width + 1, np.int64)
    for s in range(n):
        count[cols[s] + 1] += 1
    for c in range(width):
        count[c + 1] += count[c]
    by_col = np.empty(n, np.int64)
    for s in range(n):
        by_col[count[cols[s]]] = s
        count[cols[s]] += 1
    count = np.zeros(n_webs * n_frames + 1, np.int64)
    for s in range(n):
        count[web_of[s] * n_frames + rows[s] + 1] += 1
    for k in range(n_webs * n_frames):
        count[k + 1] += count[k]
    order = np.empty(n, np.int64)
    for i in range(n):
        s = by_col[i]
        k = web_of[s] * n_frames + rows[s]
        order[count[k]] = s
        count[k] += 1
    return order


@njit(cache=True)
def _renumbered(rows, cols, nxt, web_of, branch_from, branch_to, path_first, path_last, order, n_webs, n_frames):
    """The tables of :class:`WalkGraph` for states renumbered by ``order`` (:func:`_pack_order`):
    (nxt, branch_off, branch_to, dropped steps, web_rows, start_off, starts), all int64 (KG04
    §3.3 walks; ``tests/naive.py`` ``ref_graph_of`` computes them with numpy sorts).

    * successors and branches renumbered; a step that does not advance (row and column never
      fall, their sum grows: the walk's topological order, :func:`_collect`) is dropped and
      counted, so the compiled walks only ever see a DAG within their bands;
    * branches grouped by their new from-state, packing order kept (a counting sort);
    * the row-start table: a path cell whose predecessor on its path lies in a lower row (or that
      starts its path) starts the walks of the rows above that predecessor's up to its own; per
      (web, row) in packing order (= path order);
    * ``web_rows[w, r]``: the first state of web w in row ≥ r.

    O(N + B + W · F). Bounds: state numbers from :func:`_packed_states` lie in 0..N−1, paths
    ``path_first..path_last`` in it, rows in 0..F−1 and webs in 0..W−1."""
    n = len(order)
    new = np.empty(n, np.int64)
    for i in range(n):
        new[order[i]] = i
    dropped = 0
    out_nxt = np.empty(n, np.int64)
    for i in range(n):
        u = order[i]
        t = nxt[u]
        if t >= 0:
            if (rows[t] >= rows[u] and cols[t] >= cols[u]
                    and np.int64(rows[t]) + cols[t] > np.int64(rows[u]) + cols[u]):
                out_nxt[i] = new[t]
            else:
                out_nxt[i] = -1
                dropped += 1
        else:
            out_nxt[i] = -1
    n_b = len(branch_from)
    good = np.zeros(n_b, np.bool_)
    branch_off = np.zeros(n + 1, np.int64)
    for k in range(n_b):
        u, v = branch_from[k], branch_to[k]
        if rows[v] >= rows[u] and cols[v] >= cols[u] and np.int64(rows[v]) + cols[v] > np.int64(rows[u]) + cols[u]:
            good[k] = True
            branch_off[new[u] + 1] += 1
        else:
            dropped += 1
    for i in range(n):
        branch_off[i + 1] += branch_off[i]
    fill = branch_off[:-1].copy()
    out_to = np.empty(branch_off[n], np.int64)
    for k in range(n_b):
        if good[k]:
            f = new[branch_from[k]]
            out_to[fill[f]] = new[branch_to[k]]
            fill[f] += 1
    # row starts: count per (web, row), then place in packing order (entries come in rising state)
    n_keys = n_webs * n_frames
    start_off = np.zeros(n_keys + 1, np.int64)
    for p in range(len(path_first)):
        for s in range(path_first[p], path_last[p] + 1):
            prev = rows[s] - 1 if s == path_first[p] else rows[s - 1]
            for r in range(prev + 1, rows[s] + 1):
                start_off[web_of[s] * n_frames + r + 1] += 1
    for k in range(n_keys):
        start_off[k + 1] += start_off[k]
    at = start_off[:-1].copy()
    starts = np.empty(start_off[n_keys], np.int64)
    for p in range(len(path_first)):  # paths in packing order, their cells rising: states rise
        for s in range(path_first[p], path_last[p] + 1):
            prev = rows[s] - 1 if s == path_first[p] else rows[s - 1]
            for r in range(prev + 1, rows[s] + 1):
                k = web_of[s] * n_frames + r
                starts[at[k]] = new[s]
                at[k] += 1
    web_rows = np.empty((n_webs, n_frames + 1), np.int64)
    i = 0
    for w in range(n_webs):
        for r in range(n_frames + 1):
            while i < n and (web_of[order[i]] < w or (web_of[order[i]] == w and rows[order[i]] < r)):
                i += 1
            web_rows[w, r] = i
    return out_nxt, branch_off, out_to, dropped, web_rows, start_off, starts


@njit(cache=True)
def _steps_ok(rows, cols, nxt, boff, bto, n_frames) -> int:
    """What :meth:`WalkGraph.check` asks of the states, in one pass: 0 when every cell lies in rows
    0..n_frames−1 and columns ≥ 0 and every step (``nxt``, the branches ``bto[boff[s]:boff[s+1]]``)
    goes to a state in range and advances (row and column never fall, their sum grows); else 1 (a
    cell), 2 (a next state), 3 (a branch state) or 4 (a step that does not advance). Bounds: the
    caller checks ``len(cols) == len(nxt) == len(rows)``, ``len(boff) == len(rows) + 1`` and that
    ``boff`` rises from 0 to ``len(bto)``; every other index is checked here before it is read.
    O(states + branches)."""
    n = len(rows)
    for s in range(n):
        if rows[s] < 0 or rows[s] >= n_frames or cols[s] < 0:
            return 1
    for s in range(n):
        r, c = np.int64(rows[s]), np.int64(cols[s])
        t = nxt[s]
        if t < -1 or t >= n:
            return 2
        if t >= 0 and (rows[t] < r or cols[t] < c or np.int64(rows[t]) + cols[t] <= r + c):
            return 4
        for k in range(boff[s], boff[s + 1]):
            t = bto[k]
            if t < 0 or t >= n:
                return 3
            if rows[t] < r or cols[t] < c or np.int64(rows[t]) + cols[t] <= r + c:
                return 4
    return 0


def _narrow(a: np.ndarray) -> np.ndarray:
    """State numbers and offsets as int32 when they fit (half the bytes a cached graph holds;
    the same values), else int64."""
    fits = a.size == 0 or (int(a.max()) < 2**31 and int(a.min()) >= -(2**31))
    return np.ascontiguousarray(a, np.int32 if fits else np.int64)


def _ranges(n: np.ndarray) -> np.ndarray:
    """0..n[0]−1, 0..n[1]−1, … concatenated."""
    n = np.asarray(n, np.int64)
    return np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)


# ----------------------------------------------------------------------------------------------
# the walk (compiled)
# ----------------------------------------------------------------------------------------------


@njit(cache=True)
def _collect(s0, lo, hi, rows, cols, nxt, boff, bto, b, local, reach, stack) -> int:
    """States reachable from s0 within rows ≤ b and states lo..hi−1 (the band of s0's web in
    rows a..b), sorted by row + col (a topological order); ``local[s − lo]`` is set to each
    state's position in ``reach`` plus one (0: not reached; every walk puts the 0s back).
    Returns their count.

    A step to a state past the band is not followed: it leaves rows a..b (its row is > b, a
    state with no step a walk of rows a..b may take, never its end), so what a walk finds is the
    same; a state before the band cannot be a step's target in a checked graph and is skipped
    too. Hence the buffers need only the band's size (:func:`work_buffers`): a query of rows
    a..b touches the states of those rows, not the whole graph.

    Bounds: ``local`` is indexed by ``s − lo`` for states lo ≤ s < hi only, and marks each once,
    so ``reach`` and ``stack`` (``hi − lo`` long at least) hold at most ``hi − lo`` entries; the
    counting sort's ranks lie in [rank(s0), max rank] because every step raises row + col
    (:func:`walk_graph` drops any step of a malformed web that does not).

    The successors of state s (here, in :func:`_dp` and :func:`_nearest`, written out in each:
    numba calls in these loops cost several times the loop): below row b the next cell of its
    path or bridge (``nxt[s]``, when there is one) then every bridge leaving s; in row b only the
    next cell, when it is still in row b (a walk ends at the last cell of its row-b run); of
    these, the states of the band."""
    n = 1
    reach[0] = s0
    local[s0 - lo] = 1
    sp = 1
    stack[0] = s0
    while sp > 0:
        sp -= 1
        s = stack[sp]
        t = nxt[s]
        k0 = k1 = 0
        if rows[s] < b:
            k0, k1 = boff[s], boff[s + 1]
        elif t >= 0 and rows[t] != b:
            t = -1
        if lo <= t < hi and local[t - lo] == 0:
            local[t - lo] = n + 1
            reach[n] = t
            n += 1
            stack[sp] = t
            sp += 1
        for k in range(k0, k1):
            t = bto[k]
            if lo <= t < hi and local[t - lo] == 0:
                local[t - lo] = n + 1
                reach[n] = t
                n += 1
                stack[sp] = t
                sp += 1
    r0 = rows[s0] + cols[s0]  # the start has the least rank; counting sort by rank into ``stack``
    r1 = r0
    for q in range(n):
        r1 = max(r1, rows[reach[q]] + cols[reach[q]])
    count = np.zeros(r1 - r0 + 2, np.int64)
    for q in range(n):
        count[rows[reach[q]] + cols[reach[q]] - r0 + 1] += 1
    for r in range(r1 - r0 + 1):
        count[r + 1] += count[r]
    for q in range(n):
        r = rows[reach[q]] + cols[reach[q]] - r0
        stack[count[r]] = reach[q]
        count[r] += 1
    for q in range(n):
        reach[q] = stack[q]
        local[stack[q] - lo] = q + 1
    return n


@njit(cache=True)
def _dp(n, lo, hi, reach, rows, values, nxt, boff, bto, b, local, lam, cost, total, length, pred) -> None:
    """Least total of (value − lam) from reach[0] to every reachable state (KG04 §3.3 walks).
    Bounds: writes positions < n of ``cost``/``total``/``length``/``pred``, reads ``local`` of the
    n states :func:`_collect` placed (every successor it follows is one of them: the same steps,
    in the band lo..hi−1)."""
    for q in range(n):
        cost[q] = INF
    s0 = reach[0]
    cost[0] = values[s0] - lam
    total[0] = values[s0]
    length[0] = 1
    pred[0] = -1
    for q in range(n):
        s = reach[q]
        cq = cost[q]
        t = nxt[s]
        k0 = k1 = 0
        if rows[s] < b:
            k0, k1 = boff[s], boff[s + 1]
        elif t >= 0 and rows[t] != b:
            t = -1
        if lo <= t < hi:
            r = local[t - lo] - 1
            c = cq + values[t] - lam
            if c < cost[r]:
                cost[r] = c
                total[r] = total[q] + values[t]
                length[r] = length[q] + 1
                pred[r] = q
        for k in range(k0, k1):
            t = bto[k]
            if lo <= t < hi:
                r = local[t - lo] - 1
                c = cq + values[t] - lam
                if c < cost[r]:
                    cost[r] = c
                    total[r] = total[q] + values[t]
                    length[r] = length[q] + 1
                    pred[r] = q


@njit(cache=True)
def _walk(rows, cols, values, nxt, boff, bto, web_rows, start_off, starts, a, b, eps,
          local, reach, stack, cost, total, length, pred):
    """Every match of rows a..b with average ≤ eps, per (start path, terminal cell), each with its
    least-average walk, start paths in path order. Returns (webs, c, d, averages, cells (K, 2),
    offsets).

    Web w's walks stay in its states of rows a..b, ``web_rows[w, a]..web_rows[w, b + 1] − 1``
    (:func:`_collect`). Bounds: the work buffers (at least that band's size for every web,
    :meth:`WalkGraph.band`) are indexed by state − band start or by position in ``reach``; a start
    outside its band (a damaged graph) is skipped; a walk's cells are its predecessor chain, of
    exactly ``length[q]`` states because the states are processed in a topological order (each
    ``pred``/``length`` pair is final before it is read); the outputs are typed lists, grown as
    needed. Requires 0 ≤ a ≤ b < n_frames (checked by :func:`_walk_arrays`)."""
    n_webs, n_frames = web_rows.shape[0], web_rows.shape[1] - 1
    o_web = []
    o_c = []
    o_d = []
    o_avg = []
    o_cells = []
    for w in range(n_webs):
        lo, hi = web_rows[w, a], web_rows[w, b + 1]
        for e in range(start_off[w * n_frames + a], start_off[w * n_frames + a + 1]):
            s0 = starts[e]
            if s0 < lo or s0 >= hi:
                continue
            n = _collect(s0, lo, hi, rows, cols, nxt, boff, bto, b, local, reach, stack)
            _dp(n, lo, hi, reach, rows, values, nxt, boff, bto, b, local, eps, cost, total, length, pred)
            terms = []
            first = []
            for q in range(n):
                s = reach[q]
                # average ≤ eps ⟺ total − eps·length ≤ 0 (relative round-off allowed for ties)
                if (rows[s] == b and (nxt[s] < 0 or rows[nxt[s]] != b)  # the last cell of a row-b run
                        and cost[q] <= 1e-12 * (total[q] + eps * length[q])):
                    terms.append(q)
                    first.append(total[q] / length[q])
            for u in range(len(terms)):
                q = terms[u]
                lam = first[u]
                while True:  # Dinkelbach: the walk of least average ending at q
                    _dp(n, lo, hi, reach, rows, values, nxt, boff, bto, b, local, lam, cost, total, length, pred)
                    avg = total[q] / length[q]
                    if avg < lam - 1e-12 * max(abs(lam), 1e-30):
                        lam = avg
                    else:
                        break
                m = length[q]
                cells = np.empty((m, 2), np.int32)
                r = q
                for i in range(m - 1, -1, -1):
                    if r < 0:  # cannot happen in a DAG walked in topological order (see above)
                        raise IndexError("match walk shorter than its length")
                    cells[i, 0] = rows[reach[r]]
                    cells[i, 1] = cols[reach[r]]
                    r = pred[r]
                o_web.append(w)
                o_c.append(cols[s0])
                o_d.append(cols[reach[q]])
                o_avg.append(avg)
                o_cells.append(cells)
            for q in range(n):
                local[reach[q] - lo] = 0
    k = len(o_web)
    off = np.zeros(k + 1, np.int64)
    for u in range(k):
        off[u + 1] = off[u] + o_cells[u].shape[0]
    flat = np.empty((off[k], 2), np.int32)
    for u in range(k):  # element by element: no slice assignment's message formatting compiled
        cu = o_cells[u]
        for i in range(cu.shape[0]):
            flat[off[u] + i, 0] = cu[i, 0]
            flat[off[u] + i, 1] = cu[i, 1]
    webs = np.empty(k, np.int64)
    cs = np.empty(k, np.int64)
    ds = np.empty(k, np.int64)
    avgs = np.empty(k, np.float64)
    for u in range(k):
        webs[u] = o_web[u]
        cs[u] = o_c[u]
        ds[u] = o_d[u]
        avgs[u] = o_avg[u]
    return webs, cs, ds, avgs, flat, off


@njit(cache=True)
def _nearest(rows, cols, values, nxt, boff, bto, web_rows, start_off, starts, a, b, min_span, slope_k, slots, n_slots):
    """Per web, the least average value of a walk across rows a..b (KG04 §3.3 walks, from the
    earliest row-a cell of any path to the last cell of a row-b run), with the first and last
    columns of that walk, reduced over the webs of each slot: per slot s the least over the webs
    w with ``slots[w] == s`` (the first such web on ties; webs with a negative slot are not
    searched): (averages (n_slots,), c, d); ∞ and −1 for a slot with no walk.

    All starts of a web at once, by Dinkelbach's method: λ ← the least average found so far
    (λ = 0 at first), one shortest-path pass of (value − λ) over the web's states of rows a..b in
    (row, col) order — the contiguous states ``web_rows[w, a]..web_rows[w, b + 1] − 1`` — until the
    average stops falling. Cost O(S · passes) for the S states of all webs in rows a..b (two to
    four passes), independent of how many paths cross row a.

    Bounds: the per-web buffers have the largest band ``web_rows[w, b + 1] − web_rows[w, a]`` and
    are indexed by ``state − web_rows[w, a]`` for states of that band: a step never goes to a lower
    row (:func:`walk_graph`) and targets past the band are skipped; ``best``/``bc``/``bd`` by slots
    < ``n_slots`` (checked by :func:`nearest_by_clip`). Requires 0 ≤ a ≤ b < n_frames."""
    n_webs, n_frames = web_rows.shape[0], web_rows.shape[1] - 1
    best = np.empty(n_slots)  # (np.full with a dtype costs a Python call per use in numba)
    bc = np.empty(n_slots, np.int64)
    bd = np.empty(n_slots, np.int64)
    best[:] = INF
    bc[:] = -1
    bd[:] = -1
    band = 0
    for w in range(n_webs):
        if slots[w] >= 0:
            band = max(band, web_rows[w, b + 1] - web_rows[w, a])
    cost = np.empty(band, np.float64)  # per web, indexed by state − web_rows[w, a]
    total = np.empty(band, np.float64)
    length = np.empty(band, np.int64)
    src = np.empty(band, np.int64)
    rows_ab = b - a + 1
    for w in range(n_webs):
        e0 = start_off[w * n_frames + a]
        e1 = start_off[w * n_frames + a + 1]
        if e0 == e1 or slots[w] < 0:
            continue
        lo = web_rows[w, a]
        hi = web_rows[w, b + 1]
        lam = 0.0
        first = True
        bw, bcw, bdw = INF, -1, -1
        while True:
            cost[:hi - lo] = INF
            for e in range(e0, e1):
                s0 = starts[e]
                cost[s0 - lo] = values[s0] - lam
                total[s0 - lo] = values[s0]
                length[s0 - lo] = 1
                src[s0 - lo] = cols[s0]
            for s in range(lo, hi):  # successors: see _collect
                u = s - lo
                cu = cost[u]
                if cu == INF:
                    continue
                t = nxt[s]
                k0 = k1 = 0
                if rows[s] < b:
                    k0, k1 = boff[s], boff[s + 1]
                elif t < 0 or rows[t] != b:  # a terminal: the last cell of a row-b run
                    span = cols[s] - src[u]
                    if (rows[s] == b and total[u] / length[u] < bw and span >= min_span
                            and rows_ab <= slope_k * (span + 1) and span + 1 <= slope_k * rows_ab):
                        bw = total[u] / length[u]
                        bcw = src[u]
                        bdw = cols[s]
                    continue
                if 0 <= t < hi:  # states past row b are never part of a walk of rows a..b
                    v = t - lo
                    c = cu + values[t] - lam
                    if c < cost[v]:
                        cost[v] = c
                        total[v] = total[u] + values[t]
                        length[v] = length[u] + 1
                        src[v] = src[u]
                for k in range(k0, k1):
                    t = bto[k]
                    if t < hi:
                        v = t - lo
                        c = cu + values[t] - lam
                        if c < cost[v]:
                            cost[v] = c
                            total[v] = total[u] + values[t]
                            length[v] = length[u] + 1
                            src[v] = src[u]
            if bw == INF or not (first or bw < lam - 1e-12 * max(abs(lam), 1e-30)):
                break
            first = False
            lam = bw
        if bw < best[slots[w]]:
            best[slots[w]], bc[slots[w]], bd[slots[w]] = bw, bcw, bdw
    return best, bc, bd


# ----------------------------------------------------------------------------------------------
# one tier
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class WebMatch:
    """A match ``clip[start..end]`` of a query, ``cost`` the average cell value of its walk, whose
    ``cells`` (k, 2) are (query frame, match frame) at the web rate (KG04 §3.3)."""

    clip: str
    start: int
    end: int
    cost: float
    cells: np.ndarray

    @property
    def segment(self) -> Segment:
        return Segment(self.clip, self.start, self.end)


def _walk_arrays(graph: WalkGraph, a: int, b: int, eps: float):
    """:func:`_walk` on ``graph``, one entry per (clip, c, d) kept: the least average, the first
    such walk found on ties (KG04 §3.3). Returns (clip ranks, c, d, averages, cells, offsets,
    entries) with ``entries`` indexing the walk outputs in the order each key first appears."""
    _check_rows(graph, a, b)
    work = work_buffers(graph.band(a, b))
    try:
        webs, cs, ds, avgs, flat, off = _walk(
            graph.rows, graph.cols, graph.values, graph.nxt, graph.branch_off, graph.branch_to, graph.web_rows,
            graph.start_off, graph.starts, int(a), int(b), float(eps), *work)
    except BaseException:
        work[0].fill(0)  # a walk cut short leaves its cells marked: the next walk finds them clean
        raise
    rank = graph.clip_rank[webs]
    order = np.lexsort((np.arange(len(webs)), avgs, ds, cs, rank))
    new = np.ones(len(order), bool)
    new[1:] = (np.diff(rank[order]) != 0) | (np.diff(cs[order]) != 0) | (np.diff(ds[order]) != 0)
    group = np.cumsum(new) - 1
    chosen = order[new]  # first least average per key
    first = np.full(len(chosen), len(webs), np.int64)
    np.minimum.at(first, group, order)  # where each key first appears
    chosen = chosen[np.argsort(first, kind="stable")]
    return rank, cs, ds, avgs, flat, off, chosen


def _check_rows(graph: WalkGraph, a: int, b: int) -> None:
    """Rows a..b must lie inside the clip (the compiled walks index per-row tables by them)."""
    if not 0 <= a <= b < graph.n_frames:
        raise ValueError(f"query rows {a}..{b} are outside the clip's frames 0..{graph.n_frames - 1}")


def _as_matches(graph: WalkGraph, arrays, entries: np.ndarray) -> list[WebMatch]:
    rank, cs, ds, avgs, flat, off, _ = arrays
    names = graph.clip_names
    return [WebMatch(names[rank[u]], int(cs[u]), int(ds[u]), float(avgs[u]), flat[off[u]:off[u + 1]].copy())
            for u in entries]


def find_matches(graph: WalkGraph, a: int, b: int, eps: float) -> list[WebMatch]:
    """All matches of rows a..b in the webs of ``graph`` with average ≤ ``eps`` (KG04 §3.3), one
    per (clip, c, d) with its least-average walk. Cost: see the module docstring."""
    arrays = _walk_arrays(graph, a, b, eps)
    return _as_matches(graph, arrays, arrays[-1])


def walk_web(web: MatchWeb, a: int, b: int, eps: float, other: str = "") -> list[WebMatch]:
    """:func:`find_matches` on a single web (rows = the query clip)."""
    return find_matches(walk_graph([(other, web)]), a, b, eps)


@njit(cache=True)
def _greedy_disjoint(clip, start, end, overlap) -> np.ndarray:
    """KG04 §3.3 redundancy removal on matches already sorted best first: keep a match unless it
    overlaps (``Segment.overlap``: shared frames over the shorter length) a kept match of the same
    clip by more than ``overlap``. Returns the kept positions. O(m · kept). Bounds: at most one
    kept entry per match, in a buffer of m."""
    kept = np.empty(len(clip), np.int64)
    n = 0
    for u in range(len(clip)):
        ok = True
        for v in range(n):
            w = kept[v]
            if clip[w] != clip[u]:
                continue
            shared = min(end[u], end[w]) - max(start[u], start[w]) + 1
            if max(shared, 0) / min(end[u] - start[u] + 1, end[w] - start[w] + 1) > overlap:
                ok = False
                break
        if ok:
            kept[n] = u
            n += 1
    return kept[:n]


def _redundant_order(rank: np.ndarray, start: np.ndarray, end: np.ndarray, cost: np.ndarray,
                     overlap: float) -> np.ndarray:
    """Positions kept by redundancy removal, best first: by (cost, clip, start, end)."""
    order = np.lexsort((end, start, rank, cost))
    return order[_greedy_disjoint(rank[order], start[order], end[order], float(overlap))]


def remove_redundant(matches: Iterable[WebMatch], overlap: float) -> list[WebMatch]:
    """KG04 §3.3: by increasing average value, keep a match and drop every other overlapping it by
    more than ``overlap`` (``Segment.overlap``), repeat. O(m · kept) for m matches."""
    ms = list(matches)
    if not ms:
        return []
    names = sorted({m.clip for m in ms})
    rank = np.searchsorted(names, [m.clip for m in ms])
    keep = _redundant_order(rank, np.array([m.start for m in ms], np.int64), np.array([m.end for m in ms], np.int64),
                            np.array([m.cost for m in ms], np.float64), overlap)
    return [ms[u] for u in keep]


def sorted_path_values(webs: Iterable[MatchWeb]) -> np.ndarray:
    """The finite path values of ``webs``, sorted ``(N,)`` (their dtype, float32 as stored): any
    quantile of them is then a lookup (:func:`quantile_of_sorted`; design §5). O(N log N)."""
    return sorted_values([finite_path_values(w) for w in webs])


def finite_path_values(web: MatchWeb) -> np.ndarray:
    """The finite path values of one web ``(n,)``, a copy (its dtype, float32 as stored)."""
    v = web.paths_values
    return v[np.isfinite(v)]


def sorted_values(parts: list[np.ndarray]) -> np.ndarray:
    """The values of ``parts`` (finite, each ``(n_i,)``) in one sorted array ``(Σ n_i,)``: the same
    bytes whatever the order of the parts. O(N log N)."""
    return np.sort(np.concatenate(parts)) if parts else np.zeros(0)


def check_quantile(q: float) -> None:
    """Refuse a quantile outside [0, 1] (ValueError naming it): asked before any pass over webs."""
    if not 0.0 <= q <= 1.0:
        raise ValueError(f"quantile must be within [0, 1], got {q}")


def quantile_of_sorted(values: np.ndarray, q: float) -> float:
    """ε as the ``q`` quantile (0..1) of ``values`` sorted ``(N,)`` (:func:`sorted_path_values`):
    numpy's linear rule, which reads the two order statistics around ``q·(N − 1)``, so it is taken
    of those two alone (``np.quantile`` of the pair at the same fraction: the same float as of all
    ``values``, tests/tasks/test_search_props.py), O(1) instead of numpy's O(N) partition."""
    check_quantile(q)
    n = len(values)
    if not n:
        raise ValueError("no match web values to take a quantile of (empty index or chunk)")
    at = (n - 1) * float(q)
    lo = min(int(np.floor(at)), n - 1)
    return float(np.quantile(np.asarray(values[lo:lo + 2]), at - lo))


#: values checked per step of :func:`_sorted_values` (4 bytes each: a 64 MB temporary)
_CHECK_BLOCK = 1 << 24


def _sorted_values(arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> np.ndarray:
    """The opener of a scope's kept sorted values (:meth:`MatchSearch.path_values`): the array
    ``(N,)`` after checking it is one flat array of ``meta["n"]`` finite values in increasing
    order (ValueError otherwise: the file is computed again and replaced). O(N), in blocks."""
    v = arrays.get("values")
    if set(arrays) != {"values"} or v is None or v.ndim != 1 or len(v) != meta.get("n"):
        raise ValueError("not a scope's sorted path values")
    for lo in range(0, len(v), _CHECK_BLOCK):
        block = v[lo:lo + _CHECK_BLOCK + 1]
        if not np.isfinite(block).all() or np.any(block[1:] < block[:-1]):
            raise ValueError("a scope's path values out of order or not finite")
    return v


def epsilon_from_quantile(webs: Iterable[MatchWeb], q: float) -> float:
    """ε as the ``q`` quantile (0..1) of the path values of ``webs`` (design §5: absolute distances
    mean little to a user, a quantile of the chunk's web values does)."""
    check_quantile(q)
    return quantile_of_sorted(sorted_path_values(webs), q)


# ----------------------------------------------------------------------------------------------
# tiers and the match graph
# ----------------------------------------------------------------------------------------------


class MatchSearch:
    """Searches over a :data:`WebSource`, one :class:`WalkGraph` packed per clip when a search
    first reaches it (KG04 §3.3) and kept mapped from the file cache ``files`` when there is one
    (see :meth:`graph`), else in ``graphs`` (an :class:`~motionweb.store.cache.LRU`, unbounded by
    default; the service shares one bounded by bytes between its scopes, each with its own
    ``key``). Packing a clip's graph costs O(cells of its webs). Not thread-safe (graphs share
    work buffers)."""

    def __init__(self, webs: WebSource, cfg: SearchParams | None = None, web_cfg: MatchWebParams | None = None,
                 graphs: LRU | None = None, key: tuple = (), files: FileCache | None = None):
        self.webs = webs
        self.cfg = cfg or SearchParams()
        self.web_cfg = web_cfg or MatchWebParams()
        self._graphs = graphs if graphs is not None else LRU()
        self._key = ("graph", *key)
        # packed graphs kept in files between processes, for a source that names its webs'
        # content (``StoreWebs.content_key``); others are packed every time
        self.files = files if hasattr(webs, "content_key") else None
        self._named: dict[str, tuple[str, list[str]]] = {}  # clip -> (file key, other clips) of its graph
        self._long: set[str] = set()  # clips packed per window (``cfg.window_graph_states``)

    def graph(self, clip: str, rows: tuple[int, int] | None = None) -> WalkGraph:
        """The packed webs of ``clip`` (ValueError naming an unknown clip); with ``rows`` (a, b),
        a graph a walk of rows within a..b may use: the whole clip's, or for a clip whose webs
        hold more than ``cfg.window_graph_states`` states, the window's alone (:func:`walk_graph`
        ``rows``; the same matches, see :func:`_packed_window`).

        With a file cache (a source naming its content): the graph mapped from its file
        (:meth:`FileCache.open_mapped`: kept open by the cache, checked once per process, ~0.5 s
        for a 29 M-state, 600 MB graph of a long take), else read, packed (8 s for an 11.5 M-state
        graph of 118 webs: 3 s reading them, 5 s packing) and put there, then mapped — the packed
        copy is dropped. Without one, or when the file cannot be kept: the packed graph, kept in
        the memory cache. A window graph is kept the same way under its clip and rows, so a query
        asked again reads neither webs nor packs; a new window of a long clip packs the window from
        its webs (O(the clip's cells) to gather, O(window states + webs · frames) after), kept in
        the memory cache while it holds them (a clip's webs up to half its bound), else read.

        Each call first releases the pages of the mapped graphs walked since the last
        (``FileCache.release``): the page cache maps a file in folios of up to 2 MB, so a walk of
        a few rows in each web of a graph maps most of it, and a tier-3 search that walks dozens
        of graphs of long takes would otherwise hold them all until the request ends (10.8 GB of
        file pages in one search worker on the million-frame store). So the graphs in use are
        resident, not all those walked; a graph walked again takes minor faults from the page
        cache."""
        if self.files is not None:
            self.files.release()
        g = self._graphs.get((*self._key, clip))
        if g is not None:
            return g
        if rows is not None:
            rows = (int(rows[0]), int(rows[1]))
        window = rows is not None and clip in self._long
        if window:
            if (g := self._graphs.get((*self._key, clip, rows))) is not None:
                return g
        unknown = ValueError(f"unknown clip {clip!r}: it is not in the index searched")
        fkey = None
        if self.files is not None:
            if (named := self._named.get(clip)) is None:
                try:
                    named = self._named[clip] = (self.webs.content_key(clip, f"walk graph layout {WalkGraph.LAYOUT}"),
                                                 self.webs.others_of(clip))
                except KeyError:
                    raise unknown from None
            fkey, others = named

            def opener(arrays: dict[str, np.ndarray], meta: dict) -> WalkGraph:
                return WalkGraph.from_arrays(arrays, meta, others)

            if not window and (g := self.files.open_mapped(fkey, opener)) is not None:
                return g
            # a window's file is looked for even before this process knows the clip is long
            if rows is not None and (g := self.files.open_mapped(self._window_key(fkey, rows), opener)) is not None:
                self._long.add(clip)
                return g
        webs = self._graphs.get((*self._key, "webs", clip)) if window else None
        if webs is None:
            try:
                webs = self.webs[clip]
            except KeyError:
                raise unknown from None
            if not webs:
                raise ValueError(f"clip {clip!r} has no match webs in the index searched")
            if rows is not None and not window and sum(len(w.paths_cells) + len(w.bridges_cells) for _, w in webs) \
                    > self.cfg.window_graph_states:
                self._long.add(clip)
                window = True
            if window:  # its next windows pack from these while the memory cache holds them
                size = sum(w.nbytes for _, w in webs)
                bound = self._graphs.max_bytes
                if bound is None or size <= bound // 2:
                    self._graphs.put((*self._key, "webs", clip), webs, size)
        g = walk_graph(webs, rows if window else None)
        if fkey is not None:
            if window:
                fkey = self._window_key(fkey, rows)
            if self.files.put(fkey, *g.to_arrays(), raw=True) and (
                    mapped := self.files.open_mapped(fkey, opener, count=False)) is not None:
                return mapped
        self._graphs.put((*self._key, clip, rows) if window else (*self._key, clip), g, g.nbytes)
        return g

    @staticmethod
    def _window_key(fkey: str, rows: tuple[int, int]) -> str:
        """The file key of the window graph of rows a..b of the graph keyed ``fkey``."""
        return hashlib.sha256(f"{fkey} rows {rows[0]} {rows[1]}".encode()).hexdigest()

    def quantile(self, q: float, stream: bool = False) -> float:
        """ε as the ``q`` quantile of the searched webs' path values (:func:`epsilon_from_quantile`).
        The scope's sorted values (:meth:`path_values`) are kept in the file cache when the source
        names its content, so any quantile of a scope costs one pass over its webs, once for every
        process (about 3 s for a 16,290-web category of the 381k-frame demo store), then a lookup
        in the mapped file; each quantile's value is kept too (a few bytes). ``stream``: see :meth:`path_values`."""
        check_quantile(q)
        key = self._scope_file(f"path value quantile {float(q)!r}")
        if key is not None:
            kept = self.files.get(key)
            if kept is not None and isinstance(kept[1].get("value"), float):
                return kept[1]["value"]
        value = quantile_of_sorted(self.path_values(stream), q)
        if key is not None:
            self.files.put(key, {}, {"value": value})
        return value

    def path_values(self, stream: bool = False) -> np.ndarray:
        """The scope's finite path values sorted ``(N,)`` float32 (:func:`sorted_path_values`),
        from the file cache (kept raw and mapped, :meth:`FileCache.open_mapped`: checked once per
        process, then a quantile reads two of its values), else one pass over every web of the
        scope (then kept there).
        ``stream`` (a source with ``map_webs``, the store's): the webs read and not kept, their
        shards shared among one thread per core, else kept in the source's cache. O(N log N) + O(bytes of the webs) / threads the first time, O(N) read back."""
        key = self._scope_file("path values sorted")
        if key is not None and (values := self.files.open_mapped(key, _sorted_values)) is not None:
            return values
        if stream and hasattr(self.webs, "map_webs"):  # the shards read by as many threads as cores
            values = sorted_values(self.webs.map_webs(finite_path_values))
        else:
            values = sorted_path_values(self.webs.all_webs())
        if key is not None and len(values) and self.files.put(key, {"values": values}, {"n": len(values)}, raw=True):
            mapped = self.files.open_mapped(key, _sorted_values, count=False)
            if mapped is not None:  # the file's pages, not a second copy in this process
                return mapped
        return values

    def _scope_file(self, salt: str) -> str | None:
        """The file cache's key of a value of this scope (None: no file cache, or a source that
        does not name its webs' content)."""
        if self.files is None or not hasattr(self.webs, "scope_key"):
            return None
        return self.webs.scope_key(salt)

    def check(self, query: Segment) -> WalkGraph:
        """Validate a user query: known clip, range inside it, at least the minimum chain length."""
        g = self.graph(query.clip, (query.start, query.end))
        if query.start < 0 or query.end >= g.n_frames:
            raise ValueError(f"query range {query.start}..{query.end} is outside clip {query.clip!r} "
                             f"(frames 0..{g.n_frames - 1} at {g.rate:g} Hz)")
        need = min_chain_extent(self.web_cfg, g.rate)
        if query.end - query.start < need:
            raise ValueError(f"query range {query.start}..{query.end} of {query.clip!r} spans "
                             f"{query.end - query.start} frames, shorter than the minimum chain length "
                             f"{need} frames ({self.web_cfg.min_chain_s:g} s at {g.rate:g} Hz)")
        return g

    def matches(self, query: Segment, eps: float) -> list[WebMatch]:
        """One tier: matches of ``query`` with average ≤ ``eps``, redundant ones removed.

        Matches must also be usable as queries of the next tier: spanning at least the minimum
        chain length, and with an overall slope within [1/k, k] (the slope rule of KG04 §3.1 for
        the whole match: a walk joining paths through bridges restarts the rule at each junction
        and could otherwise shrink a match, and tier after tier a query, to a few frames)."""
        g, arrays, kept = self._kept(query, eps)
        return _as_matches(g, arrays, kept)

    def _kept(self, query: Segment, eps: float) -> tuple[WalkGraph, tuple, np.ndarray]:
        """:meth:`matches` as arrays: (the query clip's graph, the :func:`_walk_arrays` output,
        the positions of the kept matches in it, best first)."""
        g = self.graph(query.clip, (query.start, query.end))
        b = min(query.end, g.n_frames - 1)
        rows, k = b - query.start + 1, self.web_cfg.slope_k
        need = min_chain_extent(self.web_cfg, g.rate)
        arrays = _walk_arrays(g, query.start, b, eps)
        rank, cs, ds, avgs = (x[arrays[-1]] for x in arrays[:4])
        span = ds - cs
        ok = (span >= need) & (rows <= k * (span + 1)) & (span + 1 <= k * rows)
        entries = arrays[-1][ok]
        keep = _redundant_order(rank[ok], cs[ok], ds[ok], avgs[ok], self.cfg.overlap_redundant)
        return g, arrays, entries[keep]

    def query_only(self, query: Segment) -> MatchGraph:
        """The match graph of a query that matches nothing (checked as :meth:`search` checks it):
        the query node alone."""
        g = self.check(query)
        return _finish(g.rate, [MatchNode(query, tier=0, cost=0.0, distance=0.0)], [])

    def search(self, query: Segment, eps: float) -> MatchGraph:
        """The tiered search from ``query`` (KG04 §3.3): a match graph, nodes sorted by distance.

        Each query node's matches are placed in one compiled pass (:func:`place_matches`); cost: one
        :meth:`matches` per node plus O(matches × nodes) for placing."""
        if not (np.isfinite(eps) and eps >= 0):
            raise ValueError(f"threshold ε must be finite and ≥ 0, got {eps}")
        g = self.check(query)
        ids = {query.clip: 0}  # clip -> a number, for the compiled placement
        nodes = [MatchNode(query, tier=0, cost=0.0, distance=0.0)]
        where = np.zeros((3, 64), np.int64)  # per node: clip number, start, end (grown as needed)
        where[:, 0] = 0, query.start, query.end
        edges: dict[tuple[int, int], tuple[int, int, float, np.ndarray]] = {}  # (u, v, cost, cells)
        frontier = [0]
        for tier in range(1, self.cfg.max_tiers + 1):
            added = []
            for qi in frontier:
                gq, (rank, cs, ds, avgs, flat, off, _), kept = self._kept(nodes[qi].segment, eps)
                names = gq.clip_names
                number = np.array([ids.setdefault(c, len(ids)) for c in names], np.int64)
                n = len(nodes)
                if where.shape[1] < n + len(kept):
                    where = np.concatenate([where, np.zeros((3, n + len(kept)), np.int64)], axis=1)
                node, new, moved = place_matches(number[rank[kept]], cs[kept], ds[kept], where, n,
                                          self.cfg.new_node_below, self.cfg.merge_above)
                for u in np.nonzero(new)[0].tolist():
                    m = kept[u]
                    nodes.append(MatchNode(Segment(names[rank[m]], int(cs[m]), int(ds[m])), tier=tier,
                                           cost=float(avgs[m])))
                    added.append(int(node[u]))
                # one edge per node pair, the cheaper kept (the earlier on ties): matches come best
                # first, so a node's first match in the list is its cheapest
                ok = np.nonzero((node >= 0) & (node != qi))[0]
                _, first = np.unique(node[ok], return_index=True)
                firsts = ok[np.sort(first)]
                for v, m in zip(node[firsts].tolist(), kept[firsts].tolist()):
                    key = (min(qi, v), max(qi, v))
                    cost = float(avgs[m])
                    if key not in edges or cost < edges[key][2]:
                        edges[key] = (qi, v, cost, flat[off[m]:off[m + 1]].copy())
                for v in np.unique(moved[moved >= 0]).tolist():
                    old = nodes[v].segment
                    nodes[v].segment = Segment(old.clip, int(where[1, v]), int(where[2, v]))
            if not added:
                break
            frontier = added
        return _finish(g.rate, nodes, [MatchEdge(*e) for e in edges.values()])


@njit(cache=True)
def place_matches(clip, start, end, where, n, new_below, merge_above):
    """Dedup matches of one query node against the graph, in order (KG04 §3.3): per match the
    largest ``Segment.overlap`` m with a node of its clip (the first node on ties); m <
    ``new_below`` (or no node of the clip): a new node; m > ``merge_above``: that node, whose
    interval is averaged with the match's (rounded half to even; the query node 0 is never
    changed); otherwise discarded. ``where`` (3, ≥ n + matches) holds per node (clip, start,
    end), ``n`` nodes so far; new nodes are appended. Returns per match (its node or −1, whether
    it is new, the node it moved or −1). O(matches × nodes). Bounds: at most one node per match is
    appended, so ``where`` needs n + matches columns (checked, ValueError otherwise)."""
    m = clip.shape[0]
    if where.shape[1] < n + m:
        raise ValueError("place_matches: where has fewer columns than nodes + matches")
    node = np.full(m, -1, np.int64)
    new = np.zeros(m, np.bool_)
    moved = np.full(m, -1, np.int64)
    for u in range(m):
        best = -1
        top = -1.0
        for v in range(n):
            if where[0, v] != clip[u]:
                continue
            shared = min(end[u], where[2, v]) - max(start[u], where[1, v]) + 1
            ov = max(shared, 0) / min(end[u] - start[u] + 1, where[2, v] - where[1, v] + 1)
            if ov > top:
                top = ov
                best = v
        if best < 0 or top < new_below:
            where[0, n], where[1, n], where[2, n] = clip[u], start[u], end[u]
            node[u] = n
            new[u] = True
            n += 1
        elif top > merge_above:
            node[u] = best
            if best != 0:
                for r, x in ((1, start[u]), (2, end[u])):
                    t = where[r, best] + x  # Python's round(t / 2): half to even
                    h = t // 2
                    if t % 2 == 1 and h % 2 == 1:
                        h += 1
                    where[r, best] = h
                moved[u] = best
    return node, new, moved


def _finish(rate: float, nodes: list[MatchNode], edges: list[MatchEdge]) -> MatchGraph:
    """Shortest-path distances to the query (Dijkstra) and nodes 1.. sorted by them."""
    n = len(nodes)
    if edges:
        u = np.array([e.u for e in edges])
        v = np.array([e.v for e in edges])
        w = np.array([e.cost for e in edges], np.float64)
        dist = dijkstra(csr_matrix((w, (u, v)), shape=(n, n)), directed=False, indices=0)
    else:
        dist = np.zeros(n)
    for i, node in enumerate(nodes):
        node.distance = float(dist[i])
    order = [0, *sorted(range(1, n), key=lambda i: (dist[i], nodes[i].tier, nodes[i].cost))]
    new = {old: k for k, old in enumerate(order)}
    return MatchGraph(rate=rate, nodes=[nodes[i] for i in order],
                      edges=[MatchEdge(new[e.u], new[e.v], e.cost, e.cells) for e in edges])


def search(query: Segment, eps: float, webs: WebSource, cfg: SearchParams | None = None,
           web_cfg: MatchWebParams | None = None) -> MatchGraph:
    """Tiered search of ``query`` (frames at the web rate) with threshold ``eps`` over ``webs``
    (KG04 §3.3; design §5). Raises ValueError for an unknown clip, a range outside the clip or
    shorter than the minimum chain length, a bad ε."""
    return MatchSearch(webs, cfg, web_cfg).search(query, eps)


# ----------------------------------------------------------------------------------------------
# nearest matches (one pass per web)
# ----------------------------------------------------------------------------------------------


def nearest_matches(graph: WalkGraph, a: int, b: int, min_span: int = 0, slope_k: int = 1 << 30
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per web of ``graph`` (order of ``graph.others``), the match ``[c, d]`` of rows a..b of least
    average value (KG04 §3.3 at ε = ∞): (averages (W,), c (W,), d (W,)), ∞ / −1 where none.

    With ``min_span`` / ``slope_k`` only walks with d − c ≥ min_span and an overall slope in
    [1/k, k] end a match (the rules of :meth:`MatchSearch.matches`); the search then returns the
    best valid walk its passes meet: exact without the rules (the defaults), with them an upper
    bound (a valid walk is missed only when an invalid one beats it at its terminal in every
    pass). Cost: see :func:`_nearest`."""
    n = len(graph.others)
    return nearest_by_clip(graph, a, b, np.arange(n), n, min_span, slope_k)


def nearest_by_clip(graph: WalkGraph, a: int, b: int, slots: np.ndarray, n_slots: int, min_span: int = 0,
                    slope_k: int = 1 << 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`nearest_matches` reduced to ``n_slots`` slots (e.g. clips): per slot s, the least
    average over the webs w with ``slots[w] == s`` (the first such web on ties), with its c and
    d; ∞ / −1 where none. Webs with ``slots[w] < 0`` (e.g. the query's own clip) are not searched."""
    _check_rows(graph, a, b)
    slots = np.asarray(slots, np.int64)
    if len(slots) != len(graph.others) or (len(slots) and slots.max(initial=-1) >= n_slots):
        raise ValueError(f"slots must give one slot < {n_slots} per web ({len(graph.others)}), got {len(slots)}")
    return _nearest(graph.rows, graph.cols, graph.values, graph.nxt, graph.branch_off, graph.branch_to,
                    graph.web_rows, graph.start_off, graph.starts, int(a), int(b), int(min_span), int(slope_k),
                    np.asarray(slots, np.int64), int(n_slots))
