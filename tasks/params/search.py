"""The parameters of the tiered search and match graph (design §5, KG04 §3.3): the stage's model, its defaults in one
place. Imports only pydantic, so the run config (``flows/config.py``) loads without the stage's
compiled kernels and libraries; the stage imports its model from here."""

from __future__ import annotations

from motionweb.store.params import Params


class SearchParams(Params):
    """Search and match graph (design §5)."""

    overlap_redundant: float = 0.5
    new_node_below: float = 0.2
    merge_above: float = 0.8
    max_tiers: int = 10
    all_categories: bool = False
    #: default ε = this × the query's nearest match in another clip (``tasks.ranking.default_epsilon``)
    eps_nearest_ratio: float = 2.0
    #: trial ranking (``tasks.ranking.rank_trials``): window length, tiers, nodes per tier per window
    window_s: float = 0.5
    window_tiers: int = 3
    window_nodes: int = 5
    #: a clip whose webs hold more states than this is packed per query window (the rows a..b a
    #: walk uses, ``tasks.search.walk_graph``), not whole: a long take's whole graph is hundreds of
    #: MB (11-29 M states on the million-frame store), a window of it a few MB; 0: never whole
    window_graph_states: int = 4_000_000
