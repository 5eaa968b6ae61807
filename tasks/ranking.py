"""The default ε rule and trials ranked for a user (retrieval; KG04 §3.3 tiers; design §5).

:func:`nearest_costs` gives a query's nearest match per clip (one pass per web,
:func:`motionweb.tasks.search.nearest_matches`), :func:`default_epsilon` the threshold a user
need not choose, and :func:`rank_trials` ranks clips by a small match graph per query window.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from motionweb.tasks.matchgraph import MatchGraph, Segment
from motionweb.tasks.matchweb.params import min_chain_extent
from motionweb.tasks.search import INF, MatchSearch, nearest_by_clip, nearest_matches


def nearest_costs(ms: MatchSearch, query: Segment) -> dict[str, float]:
    """Per clip other than the query's, the least average value of a match of the query in its
    web (:func:`nearest_matches` with the length and slope rules of :meth:`MatchSearch.matches`).
    Clips with no such match are absent."""
    g = ms.graph(query.clip, (query.start, query.end))
    cost, _, _ = nearest_matches(g, query.start, min(query.end, g.n_frames - 1),
                                 min_chain_extent(ms.web_cfg, g.rate), ms.web_cfg.slope_k)
    best: dict[str, float] = {}
    for w, clip in enumerate(g.others):
        if clip != query.clip and cost[w] < best.get(clip, INF):
            best[clip] = float(cost[w])
    return best


#: what a query with no nearest match is told (its result holds the query alone)
NO_MATCH = ("the query matches no other clip at any threshold: no path of a match web crosses its frames "
            "(a window that ends on a clip's last frames often has none: try one that ends earlier, or "
            "--all-categories)")


def default_epsilon(nearest: dict[str, float], ratio: float) -> float | None:
    """The default threshold: ``ratio`` times the query's nearest match in another clip (design §5).

    KG04 §3.3 leaves ε to the user; an absolute ε means little (web values scale with the
    skeleton and the motion's speed) and a quantile of the webs' values depends on what else the
    library holds. The nearest match measures how close the closest logically similar motion is
    for *this* query, so ``ratio`` × it admits the matches about as good as that one. None when
    the query has no nearest match: nothing matches it at any threshold, and its search result is
    the query alone (:meth:`~motionweb.tasks.search.MatchSearch.query_only`, with :data:`NO_MATCH`).
    """
    if not nearest:
        return None
    return float(ratio) * min(nearest.values())


def choose_epsilon(ms: MatchSearch, query: Segment, threshold: float | None, quantile: float | None,
                   quantile_value: Callable[[float], float] | None = None) -> float | None:
    """ε of one search (KG04 §3.3; design §5), the one rule every front door uses: ``threshold``
    when given; else the ``quantile`` of the searched webs' path values (``quantile_value(q)``
    when the caller keeps them computed, else :meth:`MatchSearch.quantile` over ``ms.webs``);
    else :func:`default_epsilon` with ``ms.cfg.eps_nearest_ratio``. None: no nearest match, the
    query matches nothing at any threshold (:data:`NO_MATCH`)."""
    if threshold is not None:
        return float(threshold)
    if quantile is not None:
        return float(quantile_value(quantile) if quantile_value is not None else ms.quantile(quantile))
    return default_epsilon(nearest_costs(ms, query), ms.cfg.eps_nearest_ratio)


def search_query(ms: MatchSearch, query: Segment, threshold: float | None, quantile: float | None,
                 quantile_value: Callable[[float], float] | None = None) -> tuple[MatchGraph, float | None]:
    """The tiered search of ``query`` at :func:`choose_epsilon`'s ε: (match graph, ε). With no
    ε (no nearest match) the graph holds the query alone and ε is None (:data:`NO_MATCH`)."""
    eps = choose_epsilon(ms, query, threshold, quantile, quantile_value)
    if eps is None:
        return ms.query_only(query), None
    return ms.search(query, eps), eps


def query_windows(query: Segment, frames: int) -> list[Segment]:
    """Half-overlapping windows of ``frames`` frames covering ``query`` (the query itself when
    it is no longer than one window)."""
    if query.end - query.start + 1 <= frames:
        return [query]
    starts = list(range(query.start, query.end - frames + 2, max(1, frames // 2)))
    if starts[-1] != query.end - frames + 1:
        starts.append(query.end - frames + 1)
    return [Segment(query.clip, a, a + frames - 1) for a in starts]


def window_scores(direct: np.ndarray, tiered: np.ndarray, ratio: float) -> np.ndarray:
    """Per clip, the weighted mean over the query's windows of log(distance / the window's nearest).

    ``direct`` (W, C): each window's nearest match per clip (tier 1; ∞ where none, at least one
    finite per window); ``tiered`` (W, C): the distances through the match graph (≤ ``direct``).
    A clip with no distance in a window counts as that window's worst. Window w weighs
    log(C / m_w), m_w the clips directly within ``ratio`` × its nearest: a window that most of the
    library matches about as well as its nearest one (standing still, the cluster of walks) says
    little about which clip matches, one that few clips match says much (its information, as in
    inverse document frequency). Equal weights when every window is matched by every clip.
    Returns (C,)."""
    lo = direct.min(axis=1, keepdims=True)
    worst = np.where(np.isfinite(tiered), tiered, -np.inf).max(axis=1, keepdims=True)
    d = np.where(np.isfinite(tiered), tiered, worst)
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.where(lo > 0, np.log(d / np.where(lo > 0, lo, 1.0)), np.where(d <= 0, 0.0, np.inf))
    weight = np.log(direct.shape[1] / (direct <= ratio * lo).sum(axis=1))
    if weight.sum() <= 0:
        weight = np.ones(len(weight))
    return weight @ logs / weight.sum()


@dataclass
class TrialRanking:
    """Trials ranked for a query (best first): ``ranking`` every clip with a web to the query's
    clip but the query's own, ``score`` per clip (:func:`window_scores`: the weighted mean over the
    query's windows of log(graph distance / the window's nearest match)), ``found`` the clips
    scoring ≤ log(ratio) (their matches are on average within ``ratio`` × the nearest),
    ``windows`` the query's windows."""

    ranking: list[str]
    found: list[str]
    score: dict[str, float]
    windows: list[Segment]


def rank_trials(ms: MatchSearch, query: Segment, tiers: int | None = None) -> TrialRanking:
    """Clips ranked for ``query`` by a match graph per query window (KG04 §3.3 tiers; design §5).

    The query is cut into half-overlapping windows of ``SearchParams.window_s``. For each window
    w: its nearest match in every clip (:func:`nearest_matches`, one per web, with the slope and
    length rules of :meth:`MatchSearch.matches`), n_w the least of them, ε_w =
    ``eps_nearest_ratio`` × n_w (the default ε rule). Tier 1: the ``window_nodes`` clips with
    the least distance become nodes (their nearest matches are the node segments); tier k + 1
    queries the nodes of tier k in turn, a clip's distance through a node being the bottleneck
    (the largest edge cost on the path to w), and the ``window_nodes`` clips whose distance tier
    k + 1 lowered become its nodes, least distance first, with the match that lowered it (a node
    of an earlier tier again when a chain reached it with a better match); up to ``tiers`` tiers
    (default ``window_tiers``). A clip's distance to w is the least bottleneck
    distance of its matches to w or to any node; a clip with no match counts as the window's
    worst. Score = the mean over windows of log(distance / n_w) (:func:`window_scores`):
    scale-free per window, each window weighted by how few clips match it directly within ε_w.
    ``found`` = the clips with score ≤ log(``eps_nearest_ratio``), whose distance is within ε_w
    on average (weighted geometric mean over the windows); a bottleneck
    within ε_w means every edge of the chain is, as for KG04's tiers at the default ε. ``found``
    is a prefix of ``ranking``.

    Why windows: a clip shorter than the query, or whose web holds no walk across all its rows,
    still ranks by the parts it matches. Why the bottleneck: a chain of matches each as good as
    the query's nearest one stays logically similar, while a sum would punish long chains. Why
    the nearest clips as nodes rather than those within ε_w: a node's distance is part of every
    bottleneck through it, so a node beyond ε_w adds no clip within ε_w, yet it ranks the clips
    it is close to ahead of those close to nothing; and when one clip is a near copy of the query
    (n_w tiny), ε_w admits that copy alone and the rest of the library would rank by direct
    distance only. Why the weights: a query that is half kick, half standing still is matched by
    every standing part of the library in its standing windows; the kick windows, which few clips
    match, decide which clips are found.
    Cost: one :func:`nearest_matches` per window and per node (≤ windows × (1 + (tiers − 1) ×
    ``window_nodes``)).
    """
    g = ms.check(query)
    cfg = ms.cfg
    tiers = cfg.window_tiers if tiers is None else int(tiers)
    if tiers < 1:
        raise ValueError(f"tiers must be ≥ 1, got {tiers}")
    clips = [c for c in g.clip_names if c != query.clip]
    index = {c: i for i, c in enumerate(clips)}
    need = min_chain_extent(ms.web_cfg, g.rate)
    k = ms.web_cfg.slope_k
    wins = query_windows(query, max(need + 1, round(cfg.window_s * g.rate) + 1))
    direct, tiered = [], []

    slots: dict[str, np.ndarray] = {}  # per clip searched: its webs' positions in ``clips``

    def reach(seg: Segment) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(cost, c, d) per clip of ``clips`` of the nearest match of ``seg``."""
        # the query's windows share the query's graph (a window graph of its rows serves them all)
        inside = seg.clip == query.clip and query.start <= seg.start and seg.end <= query.end
        gg = g if inside else ms.graph(seg.clip, (seg.start, seg.end))
        if seg.clip not in slots:
            slots[seg.clip] = np.array([-1 if o == seg.clip else index.get(o, -1) for o in gg.others], np.int64)
        return nearest_by_clip(gg, seg.start, min(seg.end, gg.n_frames - 1), slots[seg.clip], len(clips), need, k)

    for win in wins:
        dist, c, d = reach(win)
        if not np.isfinite(dist).any():
            continue
        direct.append(dist)
        frontier = []
        if tiers > 1:
            near = np.argsort(dist, kind="stable")
            near = near[np.isfinite(dist[near])]
            frontier = list(zip(near.tolist(), c[near].tolist(), d[near].tolist(), dist[near].tolist()))
        for _ in range(2, tiers + 1):
            nodes, noded = [], set()
            for i, ci, di, cost in frontier:  # least distance first: a clip's first entry is its best
                if i not in noded and len(nodes) < cfg.window_nodes:
                    noded.add(i)
                    nodes.append((i, ci, di, cost))
            frontier = []
            for i, ci, di, cost in nodes:
                hop, hc, hd = reach(Segment(clips[i], ci, di))
                hop = np.maximum(hop, cost)
                better = hop < dist
                dist = np.where(better, hop, dist)
                j = np.nonzero(better)[0]
                frontier += zip(j.tolist(), hc[j].tolist(), hd[j].tolist(), hop[j].tolist())
            frontier.sort(key=lambda x: x[3])
            if not frontier:
                break
        tiered.append(dist)
    if not direct:
        raise ValueError(f"query {query.clip}[{query.start}..{query.end}] matches no other clip: nothing to rank")
    score = window_scores(np.array(direct), np.array(tiered), cfg.eps_nearest_ratio)
    order = sorted(range(len(clips)), key=lambda i: (score[i], clips[i]))
    ranking = [clips[i] for i in order]
    cut = np.log(cfg.eps_nearest_ratio)
    return TrialRanking(ranking, [clips[i] for i in order if score[i] <= cut],
                        {clips[i]: float(score[i]) for i in order}, wins)
