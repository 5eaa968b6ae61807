"""The match graph that a search builds and registration consumes (KG04 §3.3, §4.1; design §5-6).

Frames are counted at the web rate ``MatchGraph.rate`` (the index's working rate), inclusive at
both ends. Clip keys are the corpus-relative paths the index uses (``Generation.clips[i]["path"]``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Segment:
    """Frames ``start..end`` (inclusive, at the graph's rate) of clip ``clip``."""

    clip: str
    start: int
    end: int

    def __post_init__(self) -> None:
        if self.end < self.start:
            raise ValueError(f"segment of {self.clip!r} ends ({self.end}) before it starts ({self.start})")

    @property
    def n_frames(self) -> int:
        return self.end - self.start + 1

    def overlap(self, other: Segment) -> float:
        """Frames shared with ``other`` over the shorter length; 0 for different clips."""
        if other.clip != self.clip:
            return 0.0
        shared = min(self.end, other.end) - max(self.start, other.start) + 1
        return max(shared, 0) / min(self.n_frames, other.n_frames)


@dataclass
class MatchNode:
    """A node: the query (tier 0, cost 0) or a match found at ``tier`` with average cell value
    ``cost``; ``distance`` is its shortest-path cost to the query through the graph."""

    segment: Segment
    tier: int = 0
    cost: float = 0.0
    distance: float = 0.0


@dataclass
class MatchEdge:
    """Edge ``u -> v`` of cost ``cost`` (average cell value of the match).

    ``cells`` (k, 2) int: the monotone path through the web that produced the match, as
    (frame of u's clip, frame of v's clip) at the graph's rate. When the node was merged with a
    later match its interval may extend slightly beyond these cells.
    """

    u: int
    v: int
    cost: float
    cells: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int32))

    def __post_init__(self) -> None:
        self.cells = np.asarray(self.cells, dtype=np.int32).reshape(-1, 2)


@dataclass
class MatchGraph:
    """Nodes (``nodes[0]`` is the query) and undirected edges at ``rate`` Hz."""

    rate: float
    nodes: list[MatchNode] = field(default_factory=list)
    edges: list[MatchEdge] = field(default_factory=list)

    def adjacency(self) -> dict[int, list[int]]:
        """Node -> indices into ``edges`` touching it."""
        adj: dict[int, list[int]] = {i: [] for i in range(len(self.nodes))}
        for e, edge in enumerate(self.edges):
            adj[edge.u].append(e)
            adj[edge.v].append(e)
        return adj
