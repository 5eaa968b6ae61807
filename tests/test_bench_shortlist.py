"""bench/shortlist.py's pieces that need no index run (the benchmark itself is not run by the tests)."""

from __future__ import annotations

from bench.shortlist import pairs_used


def test_pairs_used_are_the_cross_clip_pairs_of_the_edges() -> None:
    """Node 0 is the query; an edge within one clip names no pair; each pair once, sorted."""
    rec = {"matches": [["b.bvh", 0, 9, 1], ["c.bvh", 3, 12, 2], ["b.bvh", 20, 29, 1], ["d.bvh", 0, 9, 3]],
           "edges": [[0, 1, 0.1], [1, 2, 0.2], [2, 1, 0.2], [1, 3, 0.0], [0, 3, 0.3]]}
    assert pairs_used("a.bvh", rec) == {("a.bvh", "b.bvh"), ("b.bvh", "c.bvh")}
    assert pairs_used("a.bvh", {"matches": [], "edges": []}) == set()
    assert pairs_used("a.bvh", {"matches": [["a.bvh", 5, 9, 1]]}) == set()
