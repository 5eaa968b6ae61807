"""Trial ranking (tasks/ranking.py, KG04 §3.3 tiers per query window): synthetic ground truth where
the query's nearest match is a near copy, so the default ε admits that copy alone; and CMU subject
16's jumps among walks and runs (real data, skipped without it)."""

from __future__ import annotations

import pytest
from motionweb.tasks.ranking import nearest_costs, rank_trials
from motionweb.tasks.search import MatchSearch, SearchParams
from planted import CorpusWebs, PlantedCorpus, near_copy_chain


@pytest.fixture(scope="module")
def near_copy() -> tuple[PlantedCorpus, CorpusWebs]:
    pc = near_copy_chain(seed=0)
    return pc, CorpusWebs(pc.clips)


def test_a_near_copy_does_not_stop_the_tiers(near_copy) -> None:
    """The copy is ≥ 10× closer than V1, so ε = 2 × the nearest admits the copy alone; ``side`` is
    directly about as close as V2 and nearer than V3..V5. The tiers still chain V1 → V2 → … and rank
    the whole chain ahead of ``side`` (with nodes only within ε, ``side`` stayed ahead of V2); the
    found set stays the copy (every chain to a variant has an edge beyond ε)."""
    pc, webs = near_copy
    ms = MatchSearch(webs, SearchParams())
    near = nearest_costs(ms, pc.query)
    variants = [c for c in pc.expected if c != "kick/copy"]
    assert 10 * near["kick/copy"] <= near[variants[0]]
    assert near["kick/side"] < min(near[c] for c in variants[2:])
    one = rank_trials(ms, pc.query, tiers=1)
    assert one.ranking.index("kick/side") < one.ranking.index(variants[1])
    r = rank_trials(ms, pc.query)
    assert ms.cfg.window_tiers == 3
    assert r.ranking[:len(pc.expected)] == list(pc.expected)  # copy, then V1..V5 in chain order
    assert r.ranking[len(pc.expected)] == "kick/side"
    assert r.found == ["kick/copy"] and r.found == r.ranking[:len(r.found)]
    assert all(r.score[c] <= one.score[c] + 1e-12 for c in r.score)  # more tiers only shorten distances


JUMPS = ("01", "02", "03", "04", "05", "06", "07", "09", "10")  # jump, high jump, forward jump
OTHERS = ("11", "17", "33", "34", "08", "57")  # walks; runs (16_08 and 16_57 end in a sudden stop)


@pytest.fixture(scope="module")
def cmu_jumps(cmu_dir) -> CorpusWebs:
    """Subject 16's nine jumps with four walks and two runs (CMU, manifest categories)."""
    from motionweb.store.formats import read_motion

    return CorpusWebs({n: read_motion(cmu_dir / "asf_amc" / "16" / f"16_{n}.amc") for n in JUMPS + OTHERS})


def test_tiers_find_the_other_jumps_and_only_them(cmu_jumps) -> None:
    """KG04 §3.3's purpose on real data: a forward jump's query finds the plain and high jumps
    through tiers. 16_10[32..62] (1 s at 30 Hz) finds one jump directly and all eight with tiers,
    no walk or run; for 16_06[60..90], whose near copy 16_05 sets ε alone, one tier ranks walks
    between the jumps and three tiers rank the eight jumps first."""
    from motionweb.tasks.matchgraph import Segment

    ms = MatchSearch(cmu_jumps, SearchParams())
    q = Segment("10", 32, 62)
    one, tiered = rank_trials(ms, q, tiers=1), rank_trials(ms, q)
    others = set(JUMPS) - {"10"}
    assert len(one.found) < 3 and set(tiered.found) == others
    q = Segment("06", 60, 90)
    one, tiered = rank_trials(ms, q, tiers=1), rank_trials(ms, q)
    others = set(JUMPS) - {"06"}
    assert set(one.ranking[:len(others)]) != others
    assert set(tiered.ranking[:len(others)]) == others


def test_window_scores_weigh_windows_by_how_few_clips_match_them() -> None:
    """Closed form: window 0 has 2 of 4 clips within 2 × its nearest (weight log 2), window 1 one
    (weight log 4 = 2 log 2); a clip missing from a window counts as its worst; a window every
    clip matches within the ratio weighs nothing; if every window is such, the plain mean."""
    import numpy as np
    from motionweb.tasks.ranking import window_scores

    inf = np.inf
    direct = np.array([[1.0, 1.5, 4.0, inf], [1.0, 8.0, 8.0, 8.0]])
    tiered = np.array([[1.0, 1.5, 2.0, inf], [1.0, 8.0, 2.0, 8.0]])
    row0 = np.log([1.0, 1.5, 2.0, 2.0])
    row1 = np.log([1.0, 8.0, 2.0, 8.0])
    assert window_scores(direct, tiered, 2.0) == pytest.approx((row0 + 2 * row1) / 3)
    flat = np.array([[3.0, 4.0, 5.0, 6.0]])  # all within 2 × 3
    with_flat = window_scores(np.vstack([direct, flat]), np.vstack([tiered, flat]), 2.0)
    assert with_flat == pytest.approx(window_scores(direct, tiered, 2.0))
    both_flat = np.vstack([flat, 2 * flat])
    assert window_scores(both_flat, both_flat, 2.0) == pytest.approx(np.log(flat[0] / 3))


def test_one_epsilon_rule_for_every_front_door(near_copy) -> None:
    """``choose_epsilon`` (used by the query flow and the service's worker): a threshold passes
    through; a quantile is that quantile of the searched webs (or the caller's cached value); else
    ``eps_nearest_ratio`` × the nearest match; ``search_query`` searches at that ε."""
    import numpy as np
    from motionweb.tasks.ranking import choose_epsilon, search_query
    from motionweb.tasks.search import epsilon_from_quantile

    pc, webs = near_copy
    ms = MatchSearch(webs, SearchParams())
    assert choose_epsilon(ms, pc.query, 0.25, None) == 0.25
    q = epsilon_from_quantile(webs.all_webs(), 0.3)
    assert choose_epsilon(ms, pc.query, None, 0.3) == q
    assert choose_epsilon(ms, pc.query, None, 0.3, quantile_value=lambda v: 7.0 * v) == 2.1
    near = nearest_costs(ms, pc.query)
    eps = choose_epsilon(ms, pc.query, None, None)
    assert eps == ms.cfg.eps_nearest_ratio * min(near.values())
    graph, got = search_query(ms, pc.query, None, None)
    ref = ms.search(pc.query, eps)
    assert got == eps and len(graph.nodes) == len(ref.nodes) > 1
    assert np.array_equal([n.distance for n in graph.nodes], [n.distance for n in ref.nodes])
