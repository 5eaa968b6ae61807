"""The candidate-pair shortlist (tasks/shortlist.py, issue 25): its descriptor is the KG04 frame
distance, its pairs hold every planted match, faiss's HNSW gives the brute-force answer on a small
corpus, and the same input gives the same pairs."""

from __future__ import annotations

import numpy as np
import pytest
from motionweb.tasks.distance import distance_grid
from motionweb.tasks.features import FeatureParams, clip_features, point_weights
from motionweb.tasks.shortlist import (
    ShortlistParams,
    rotate_about_vertical,
    shortlist_pairs,
    window_descriptors,
)
from naive import ref_shortlist
from planted import planted_corpus

FC = FeatureParams()
LOW = min(FC.rates)


def lowest(pc) -> dict:
    w = point_weights(next(iter(pc.clips.values())).skeleton, FC)
    return {k: (clip_features(m, LOW, FC), w) for k, m in pc.clips.items()}


@pytest.fixture(scope="module")
def planted():
    pc = planted_corpus(seed=0, n_copies=8)
    return pc, lowest(pc)


def test_descriptor_distance_is_the_frame_distance(planted):
    """min over headings of |u − R v|² is the coarsest grid's cell value (KG04 §3.1's metric)."""
    _, clips = planted
    (fa, w), (fb, _) = clips["kick/query"], clips["walk/walk_00"]
    grid = distance_grid(fa[::4], fb[::4], w)
    u, v = window_descriptors(fa, w, stride=4), window_descriptors(fb, w, stride=4)
    best = np.full(grid.shape, np.inf)
    for a in np.linspace(0, 2 * np.pi, 720, endpoint=False):
        rv = rotate_about_vertical(v, a).astype(np.float64)
        d = (u.astype(np.float64) ** 2).sum(1)[:, None] + (rv ** 2).sum(1)[None] - 2 * u.astype(np.float64) @ rv.T
        best = np.minimum(best, d)
    np.testing.assert_allclose(best, grid, rtol=2e-3, atol=1e-5)


def test_every_planted_pair_is_shortlisted(planted):
    """The query clip and every clip holding a planted copy of its kick are paired, with fewer
    neighbours than the default too; and the nearest neighbours alone leave some pairs out (on these
    17 clips of noise every clip is within the default hub radius of a window's nearest)."""
    pc, clips = planted
    want = {tuple(sorted((pc.query.clip, k))) for k in pc.expected}
    for k in (4, ShortlistParams().k):
        sl = shortlist_pairs(clips, ShortlistParams(k=k, k_windows=4 * k))
        assert want <= set(sl.pairs), (k, want - set(sl.pairs))
        assert {(c, c) for c in clips} <= set(sl.pairs)
        assert sl.candidates == len(clips) * (len(clips) + 1) // 2
    assert len(shortlist_pairs(clips, ShortlistParams(k=4, k_windows=16, hub_ratio=0)).pairs) < sl.candidates


def test_same_input_same_pairs(planted):
    """Fixed seeds and a one-thread build: the same pairs and hits whatever the order of the clips
    and the threads faiss searches with."""
    import faiss

    _, clips = planted
    p = ShortlistParams(k=4, k_windows=12, min_hits=2)
    a = shortlist_pairs(clips, p)
    b = shortlist_pairs(dict(reversed(list(clips.items()))), p)
    threads = faiss.omp_get_max_threads()
    faiss.omp_set_num_threads(1)
    try:
        c = shortlist_pairs(clips, p)
    finally:
        faiss.omp_set_num_threads(threads)
    assert a.pairs == b.pairs == c.pairs and a.hits == b.hits == c.hits and a.windows == c.windows


def test_hnsw_gives_the_brute_force_pairs():
    """On a small corpus faiss's approximate search finds the exact neighbours (tests/naive.py),
    with the hub rule (on 7 clips with k = 2 nearly every window is a hub window) and without it."""
    pc = planted_corpus(seed=0, n_copies=3, distractors=("walk", "sit", "punch"))
    clips = lowest(pc)
    for ratio in (ShortlistParams().hub_ratio, 0.0):
        got = shortlist_pairs(clips, ShortlistParams(k=2, k_windows=6, min_hits=2, headings=8, stride=2,
                                                     hub_ratio=ratio))
        ref = ref_shortlist(clips, k=2, k_windows=6, min_hits=2, headings=8, stride=2, hub_ratio=ratio)
        assert got.pairs == ref, ratio
    assert len(ref) < got.candidates  # without the hub rule something was left out


def test_one_clip_and_mixed_skeletons(planted):
    _, clips = planted
    one = {"kick/query": clips["kick/query"]}
    assert shortlist_pairs(one).pairs == [("kick/query", "kick/query")]
    f, _ = clips["walk/walk_00"]
    bad = {**one, "other": (f[:, :-5], np.full(f.shape[1] - 5, 1 / (f.shape[1] - 5)))}
    with pytest.raises(ValueError, match="same points"):
        shortlist_pairs(bad)


def hub_corpus(n_hub: int = 12, n_other: int = 4, frames: int = 6, points: int = 10, seed: int = 3) -> dict:
    """A planted hub (issue 25, part 4): ``n_hub`` clips each ending on one frame of the same pose
    (a random cloud plus noise of 1e-3, at one heading), and ``n_other`` clips without it. Their
    other ``frames`` frames come in twins (clips 2i and 2i + 1 share random clouds, noise 1e-2 each), so
    that a frame off the hub has one clear nearest clip: (features (frames, points, 3), weights
    (points,)) per clip key."""
    rng = np.random.default_rng(seed)
    pose = rng.standard_normal((points, 3))
    twins = rng.standard_normal(((n_hub + n_other + 1) // 2, frames, points, 3))
    w = np.full(points, 1 / points)
    clips = {}
    for i in range(n_hub + n_other):
        f = twins[i // 2] + 1e-2 * rng.standard_normal((frames, points, 3))
        if i < n_hub:  # one more frame, after the twin's
            f = np.concatenate([f, (pose + 1e-3 * rng.standard_normal((points, 3)))[None]])
        clips[f"{'hub' if i < n_hub else 'other'}_{i:02d}"] = (f, w)
    return clips


HUB = {"k": 2, "k_windows": 6, "min_hits": 1, "headings": 8}


def test_a_hub_keeps_every_clip_within_range():
    """All pairs of the planted hub's 12 clips are kept with the hub rule (12 · 11 / 2 = 66, far
    more than the 2 neighbours each hub window has room for), and the rule adds no other pair;
    without it (hub_ratio 0, the rule before) some hub pairs are lost."""
    clips = hub_corpus()
    hub = sorted(c for c in clips if c.startswith("hub"))
    clique = {(a, b) for a in hub for b in hub if a < b}
    new = shortlist_pairs(clips, ShortlistParams(**HUB))
    old = shortlist_pairs(clips, ShortlistParams(**HUB, hub_ratio=0))
    assert ShortlistParams().hub_ratio > 0
    assert clique <= set(new.pairs), sorted(clique - set(new.pairs))[:5]
    # the old rule: each hub window names 2 hub clips (24 hits for 66 pairs); the frames off the hub
    # name their twin and one more clip, which covers a few more hub pairs by chance
    assert len(clique - set(old.pairs)) >= 10, len(clique - set(old.pairs))
    assert set(new.pairs) - set(old.pairs) <= clique
    assert set(old.pairs) <= set(new.pairs)
    assert len(new.pairs) < new.candidates
    assert all(new.hits[p] >= 1 for p in clique)
    assert new.hub_windows == len(hub) and old.hub_windows == 0  # the hub frames only: twins settle the rest


def test_hnsw_gives_the_brute_force_pairs_with_a_hub():
    """The radius pass for hub windows gives the brute-force pairs (tests/naive.py), with the hub
    rule and without it; the two differ on this corpus."""
    clips = hub_corpus()
    for ratio in (ShortlistParams().hub_ratio, 0.0):
        got = shortlist_pairs(clips, ShortlistParams(**HUB, hub_ratio=ratio))
        ref = ref_shortlist(clips, **HUB, hub_ratio=ratio)
        assert got.pairs == ref, (ratio, sorted(set(got.pairs) ^ set(ref))[:5])
    assert ref != ref_shortlist(clips, **HUB, hub_ratio=ShortlistParams().hub_ratio)
