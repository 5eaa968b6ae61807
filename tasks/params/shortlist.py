"""The parameters of the candidate-pair shortlist (issue 25; an addition to KG04 §3, which builds
a web for every pair of motions): the stage's model, its defaults in one place. Imports only
pydantic, so the run config (``flows/config.py``, section ``index.shortlist``) loads without the
stage's nearest-neighbour library; the stage (``tasks/shortlist.py``) imports its model from here."""

from __future__ import annotations

from motionweb.store.params import Params
from pydantic import Field


class ShortlistParams(Params):
    """Shortlist candidate clip pairs by approximate k-NN over pose windows (``tasks/shortlist.py``).

    Off by default: the index then builds every pair of a chunk (KG04 §3). On, it builds the webs
    of the pairs shortlisted in each chunk only (meant for ``index.chunk_by: none``)."""

    enabled: bool = False
    #: neighbour clips per window: the other clips of a window's ``k`` nearest windows (the nearest
    #: window of each clip), its own clip excluded
    k: int = Field(24, ge=1)
    #: windows asked of the k-NN index per window and heading, at least ``k``: deeper than ``k`` so that
    #: a clip of many near-identical windows (standing still) takes one of the ``k`` places, not all
    k_windows: int = Field(64, ge=1)
    #: windows: every ``stride``-th frame of the lowest feature rate (each frame's cloud is a
    #: window of ``features.window`` frames, 0.5 s at 10 Hz)
    stride: int = Field(1, ge=1)
    #: hubs (issue 25, part 4): a window also keeps every other clip within this × the distance to its
    #: nearest other clip, the default ε rule's form (ε = ``search.eps_nearest_ratio`` × the query's
    #: nearest match). Measured (tasks/shortlist.py notes, bench/shortlist.py): 32 recalls ≥ 0.95 of
    #: the exact index's matches pooled over 100 queries with 67% of the pairs; 8 (the default before)
    #: 23% of the pairs, recall 0.95 per query on average but 0.22 pooled; 4 (that ratio squared) misses
    #: the bench corpus's sitting hubs. Looked for past the ``k`` nearest only when the ``k``-th is still
    #: within it. 0: off (the rule before issue 25 part 4)
    hub_ratio: float = Field(32.0, ge=0)
    #: a pair is kept when at least this many windows of either clip have a neighbour in the other
    min_hits: int = Field(1, ge=1)
    #: headings the query windows are turned to (the frame distance minimises over a rotation about
    #: the vertical axis; the k-NN metric is Euclidean, so each window is searched at this many
    #: headings, 360°/headings apart: the least of them is within cos(180°/headings) of the aligned distance)
    headings: int = Field(16, ge=1)
    #: HNSW graph degree (faiss ``IndexHNSWFlat`` M)
    hnsw_m: int = Field(32, ge=4)
    #: HNSW build beam width (faiss ``efConstruction``)
    ef_construction: int = Field(200, ge=1)
    #: HNSW search beam width (faiss ``efSearch``; raised to ``k`` when smaller)
    ef_search: int = Field(128, ge=1)
