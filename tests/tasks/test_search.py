"""Search over match webs (KG04 §3.3, design §5): the compiled walk against brute-force enumeration
of match sequences, planted copies under known warps (recall, precision, endpoints), a chain of
variants found only through tiers, errors, quantile ε, self webs and the store adapter."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from motionweb.store.generations import Generation, commit
from motionweb.store.keys import web_key
from motionweb.store.web import MatchWeb, transpose
from motionweb.store.webs import StoreWebs
from motionweb.store.zarr_store import MotionStore, new_id, now_iso
from motionweb.tasks.matchgraph import Segment
from motionweb.tasks.matchweb.build import build_web_full
from motionweb.tasks.matchweb.params import MatchWebParams, self_band
from motionweb.tasks.ranking import default_epsilon, nearest_costs, rank_trials
from motionweb.tasks.search import (
    MatchSearch,
    SearchParams,
    epsilon_from_quantile,
    find_matches,
    nearest_by_clip,
    nearest_matches,
    place_matches,
    remove_redundant,
    search,
    walk_graph,
    walk_web,
)
from naive import ref_matches, ref_place, ref_remove_redundant, ref_row_starts, ref_walk_steps
from planted import CorpusWebs, PlantedCorpus, planted_corpus, variant_chain
from smaps import HAVE_SMAPS, mapping_rss_kb

TOL = 3  # frames at 30 Hz
EPS = 0.005  # planted copies cost ~3e-4, the nearest other motion 0.02 (see test output)


# ---------------------------------------------------------------------------- slow reference


@pytest.fixture(scope="module")
def tangled_web() -> MatchWeb:
    """A 50x50 web of five noisy diagonal valleys joined by many bridges."""
    rng = np.random.default_rng(9)
    i, j = np.mgrid[0:50, 0:50]
    g = np.full((50, 50), np.inf)
    for o in (-12, -6, 0, 5, 11):
        g = np.minimum(g, 0.1 + rng.uniform(0.01, 0.05) * np.abs(j - i - o) + 0.02 * rng.random((50, 50)))
    web = build_web_full(g.astype(np.float32), 30.0, MatchWebParams(min_chain_s=0.2, bridge_max_s=0.5, valid_a=0.5),
                         self_pair=False)
    assert web.n_bridges >= 15 and web.n_paths >= 5
    return web


def test_walk_graph_packs_every_step_and_start(tangled_web) -> None:
    """The packed graph (states renumbered by web, row, col) holds exactly the web's steps and, per
    row, the earliest row-a cell of every path, in path order."""
    web = tangled_web
    g = walk_graph([("other", web), ("self", web)])
    steps = sorted(ref_walk_steps(web))
    for w in range(2):
        lo, hi = g.web_rows[w, 0], g.web_rows[w, g.n_frames]
        keys = g.rows[lo:hi].astype(np.int64) * 1000 + g.cols[lo:hi]
        assert np.all(np.diff(keys) >= 0)
        got = []
        for s in range(lo, hi):
            succ = ([g.nxt[s]] if g.nxt[s] >= 0 else []) + list(g.branch_to[g.branch_off[s]:g.branch_off[s + 1]])
            assert all(lo <= t < hi for t in succ)
            got += [((int(g.rows[s]), int(g.cols[s])), (int(g.rows[t]), int(g.cols[t])), float(g.values[t])) for t in succ]
        assert sorted(got) == steps
        for a in range(g.n_frames):
            st = g.starts[g.start_off[w * g.n_frames + a]:g.start_off[w * g.n_frames + a + 1]]
            assert [(int(g.rows[s]), int(g.cols[s])) for s in st] == ref_row_starts(web, a)


def test_walk_is_the_brute_force_enumeration(tangled_web) -> None:
    web = tangled_web
    n_matches = n_differ = 0
    for a in range(0, 50, 3):
        for b in range(a, min(50, a + 24)):
            ref = ref_matches(web, a, b)
            got = {(m.start, m.end): m for m in walk_web(web, a, b, 1e9)}
            assert set(got) == set(ref), (a, b)
            for key, (least_avg, avg_of_least_total) in ref.items():
                m = got[key]
                assert m.cost == pytest.approx(least_avg, rel=1e-9, abs=1e-12)
                assert m.cells[0, 0] == a and m.cells[-1, 0] == b and m.cells[0, 1] == key[0]
                assert m.cells[-1, 1] == key[1] and np.all(np.diff(m.cells, axis=0) >= 0)
                n_differ += avg_of_least_total > least_avg + 1e-9
            n_matches += len(ref)
            if ref:  # the ε filter: exactly the sequences of average ≤ ε
                eps = float(np.median([v[0] for v in ref.values()]))
                kept = {(m.start, m.end) for m in walk_web(web, a, b, eps)}
                assert kept == {k for k, v in ref.items() if v[0] <= eps}
    # enough cases, and some where the least-total walk is not the least-average one
    assert n_matches > 500 and n_differ > 0


def test_transpose_swaps_rows_and_columns(tangled_web) -> None:
    t = transpose(tangled_web)
    assert t.shape == tangled_web.shape[::-1] and np.array_equal(t.paths_cells, tangled_web.paths_cells[:, ::-1])
    back = transpose(t)
    for k, v in tangled_web.to_arrays().items():
        assert np.array_equal(back.to_arrays()[k], v)
    # a match of rows a..b in the web is, transposed, a walk over its columns: same cells swapped
    m = walk_web(tangled_web, 10, 30, 1e9)[0]
    mt = {(x.start, x.end): x for x in walk_web(t, int(m.cells[0, 1]), int(m.cells[-1, 1]), 1e9)}
    assert (10, 30) in mt


def test_redundancy_removal_keeps_the_best_of_overlapping() -> None:
    from motionweb.tasks.search import WebMatch

    cells = np.zeros((0, 2), np.int32)
    ms = [WebMatch("x", 0, 30, 0.2, cells), WebMatch("x", 5, 33, 0.1, cells), WebMatch("x", 20, 50, 0.3, cells),
          WebMatch("y", 0, 30, 0.4, cells)]
    kept = remove_redundant(ms, 0.5)
    # (5,33) best; (0,30) overlaps it 26/29 > 0.5: dropped; (20,50) overlaps 14/29 ≤ 0.5: kept
    assert [(m.clip, m.start, m.end) for m in kept] == [("x", 5, 33), ("x", 20, 50), ("y", 0, 30)]


def test_redundancy_removal_is_the_plain_greedy() -> None:
    from motionweb.tasks.search import WebMatch

    rng = np.random.default_rng(3)
    cells = np.zeros((0, 2), np.int32)
    for trial in range(20):
        n = int(rng.integers(0, 80))
        starts = rng.integers(0, 100, n)
        ms = [WebMatch(f"c{rng.integers(0, 4)}", int(s), int(s + rng.integers(0, 40)),
                       float(rng.integers(0, 6)) / 5, cells) for s in starts]  # ties in cost on purpose
        for ov in (0.0, 0.5, 0.8):
            got = [(m.clip, m.start, m.end, m.cost) for m in remove_redundant(ms, ov)]
            assert got == [(m.clip, m.start, m.end, m.cost) for m in ref_remove_redundant(ms, ov)], (trial, ov)


# ---------------------------------------------------------------------------- planted copies


@pytest.fixture(scope="module")
def planted() -> tuple[PlantedCorpus, CorpusWebs]:
    pc = planted_corpus(seed=0, n_copies=20)
    return pc, CorpusWebs(pc.clips)


def test_planted_copies_found_with_their_endpoints(planted) -> None:
    pc, webs = planted
    graph = search(pc.query, EPS, webs, SearchParams(max_tiers=1))
    found = [n.segment for n in graph.nodes[1:]]
    hits = [s for s in found if s.clip in pc.expected
            and abs(s.start - pc.expected[s.clip].start) <= TOL and abs(s.end - pc.expected[s.clip].end) <= TOL]
    recall = len({s.clip for s in hits}) / len(pc.expected)
    precision = len(hits) / max(len(found), 1)
    assert recall >= 0.95 and precision >= 0.95, (recall, precision, found)
    # the match graph: query first, distances = edge costs at one tier, sorted, cells span the query
    assert graph.nodes[0].segment == pc.query and graph.rate == 30.0
    dist = [n.distance for n in graph.nodes]
    assert dist == sorted(dist) and all(n.tier == 1 for n in graph.nodes[1:])
    for e in graph.edges:
        assert e.u == 0 and graph.nodes[e.v].distance == pytest.approx(e.cost) and e.cost <= EPS
        assert e.cells[0, 0] == pc.query.start and e.cells[-1, 0] == pc.query.end
    # the known warp: each match's cells follow it (query frame ≈ warp(copy frame))
    for e in graph.edges:
        seg = graph.nodes[e.v].segment
        truth = pc.warps[seg.clip][e.cells[:, 1]]
        assert np.nanmax(np.abs(truth - e.cells[:, 0])) <= TOL


def test_quantile_threshold(planted) -> None:
    pc, webs = planted
    query_webs = [w for _, w in webs[pc.query.clip]]
    values = np.concatenate([w.paths_values for w in query_webs])
    assert epsilon_from_quantile(query_webs, 0.25) == pytest.approx(np.quantile(values, 0.25))
    assert epsilon_from_quantile(query_webs, 0.0) == pytest.approx(values.min())
    eps = epsilon_from_quantile(query_webs, 0.35)
    assert 0.001 < eps < 0.02  # between the copies (~3e-4) and the other motions (≥ 0.02)
    graph = search(pc.query, eps, webs, SearchParams(max_tiers=1))
    assert {n.segment.clip for n in graph.nodes[1:]} == set(pc.expected)
    for q in (-0.1, 1.5):
        with pytest.raises(ValueError, match="quantile"):
            epsilon_from_quantile(query_webs, q)
    with pytest.raises(ValueError, match="no match web values"):
        epsilon_from_quantile([], 0.5)


def test_bad_queries_are_clear_errors(planted) -> None:
    pc, webs = planted
    n = pc.clips[pc.query.clip].n_frames
    ms = MatchSearch(webs, SearchParams(max_tiers=1))
    with pytest.raises(ValueError, match="unknown clip 'kick/nope'"):
        ms.search(Segment("kick/nope", 0, 20), EPS)
    with pytest.raises(ValueError, match="outside clip 'kick/query'"):
        ms.search(Segment(pc.query.clip, n - 20, n), EPS)
    with pytest.raises(ValueError, match="outside clip"):
        ms.search(Segment(pc.query.clip, -1, 20), EPS)
    need = int(np.ceil(MatchWebParams().min_chain_s * 30))
    with pytest.raises(ValueError, match="shorter than the minimum chain length"):
        ms.search(Segment(pc.query.clip, 10, 10 + need - 1), EPS)
    ms.search(Segment(pc.query.clip, 10, 10 + need), EPS)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="threshold"):
            ms.search(pc.query, bad)


def test_self_web_never_returns_the_query_itself() -> None:
    from motionweb.store.demo.corpus import generate_clip

    walk, _ = generate_clip("walk", 0, 3, fps=30.0)
    webs = CorpusWebs({"walk/w": walk})
    (_, web), = webs["walk/w"]
    band = self_band(MatchWebParams(), 30.0)
    assert web.self_pair and np.all(np.abs(web.paths_cells[:, 0] - web.paths_cells[:, 1]) > band)
    q = Segment("walk/w", 30, 60)
    graph = search(q, 0.05, webs, SearchParams(max_tiers=1, new_node_below=0.2))
    assert len(graph.nodes) > 1  # other steps of the walk
    for node in graph.nodes[1:]:
        assert node.segment.overlap(q) < 0.2
    for e in graph.edges:
        assert np.all(np.abs(e.cells[:, 0] - e.cells[:, 1]) > band)


# ---------------------------------------------------------------------------- tiers


@pytest.fixture(scope="module")
def chain() -> tuple[PlantedCorpus, CorpusWebs]:
    pc = variant_chain(seed=0, n_variants=5)
    return pc, CorpusWebs(pc.clips)


def test_far_variants_found_only_through_tiers(chain) -> None:
    pc, webs = chain
    eps = 0.003  # between one chain step (~0.0015) and two (~0.0055)
    one = search(pc.query, eps, webs, SearchParams(max_tiers=1))
    assert [n.segment.clip for n in one.nodes[1:]] == ["kick/variant_1"]
    tiered = search(pc.query, eps, webs, SearchParams())
    order = [n.segment.clip for n in tiered.nodes[1:]]
    assert order == list(pc.expected)  # all five, ranked by graph distance in chain order
    assert [n.tier for n in tiered.nodes] == [0, 1, 2, 3, 4, 5]
    dist = [n.distance for n in tiered.nodes]
    assert all(d1 < d2 for d1, d2 in itertools.pairwise(dist))
    # each variant's distance is the sum of the chain's edge costs
    costs = {frozenset((e.u, e.v)): e.cost for e in tiered.edges}
    for k in range(1, 6):
        assert dist[k] == pytest.approx(dist[k - 1] + costs[frozenset((k - 1, k))])
    for node in tiered.nodes[1:]:
        exp = pc.expected[node.segment.clip]
        assert abs(node.segment.start - exp.start) <= 2 * TOL and abs(node.segment.end - exp.end) <= 2 * TOL
    # max_tiers bounds the tiers
    two = search(pc.query, eps, webs, SearchParams(max_tiers=2))
    assert [n.segment.clip for n in two.nodes[1:]] == ["kick/variant_1", "kick/variant_2"]


def _commit_chain(pc: PlantedCorpus, webs: CorpusWebs, folder) -> list[str]:
    """A store at ``folder`` whose committed generation holds every web of ``pc`` (its clips' keys)."""
    store = MotionStore(str(folder))
    keys = list(pc.clips)
    recs = []
    for i, a in enumerate(keys):
        for b in keys[i:]:
            key = web_key(f"{i:064x}", f"{keys.index(b):064x}", "test")
            store.write_web(key, webs.web(a, b).to_arrays())
            recs.append({"a": a, "b": b, "key": key, "chunk": "all"})
    clips = [{"path": k, "category": pc.categories[k]} for k in keys]
    commit(store, Generation(new_id(), now_iso(), clips=clips, webs=recs))
    return keys


def test_store_adapter_searches_the_committed_generation(chain, tmp_path) -> None:
    pc, webs = chain
    keys = _commit_chain(pc, webs, tmp_path / "store")
    ro = MotionStore(str(tmp_path / "store"), read_only=True)
    src = StoreWebs.for_query(ro, pc.query.clip)
    assert set(src) == {k for k in keys if pc.categories[k] == "kick"}
    assert len(StoreWebs.for_query(ro, pc.query.clip, all_categories=True)) == len(keys)
    # a web stored with the variant as rows is read transposed for the query
    v5 = dict(src["kick/variant_5"])["kick/query"]
    assert np.array_equal(v5.paths_cells, webs.web("kick/variant_5", "kick/query").paths_cells)
    got = search(pc.query, 0.003, src)
    want = search(pc.query, 0.003, webs)
    assert [n.segment for n in got.nodes] == [n.segment for n in want.nodes]
    assert [n.distance for n in got.nodes] == pytest.approx([n.distance for n in want.nodes])
    assert epsilon_from_quantile(src.all_webs(), 0.5) > 0
    with pytest.raises(ValueError, match="unknown clip 'kick/nope'"):
        StoreWebs.for_query(ro, "kick/nope")
    with pytest.raises(ValueError, match="never indexed"):
        StoreWebs(MotionStore(str(tmp_path / "empty")))


def test_graph_files_give_the_packed_graph_and_the_same_search(chain, tmp_path) -> None:
    """Issue 25 part 5: a search keeps each packed graph in a file cache; a fresh search (another
    process, another run) reads them back instead of its webs, checked, and finds the same graph;
    a damaged, foreign or stale file is packed again."""
    from motionweb.store.filecache import FileCache
    from motionweb.tasks.search import MatchSearch, WalkGraph

    pc, webs = chain
    _commit_chain(pc, webs, tmp_path / "store")
    files = FileCache(tmp_path / "graphs", 1 << 30)

    def fresh() -> tuple[StoreWebs, MatchSearch]:  # as in another process: its own cache of mappings
        src = StoreWebs.for_query(MotionStore(str(tmp_path / "store"), read_only=True), pc.query.clip)
        return src, MatchSearch(src, SearchParams(), files=FileCache(tmp_path / "graphs", 1 << 30))

    src1, ms1 = fresh()
    want = ms1.search(pc.query, 0.003)
    assert ms1.files.writes == len(want.nodes) and src1.reads > 0 and ms1.files.hits == 0
    src2, ms2 = fresh()
    got = ms2.search(pc.query, 0.003)
    assert src2.reads == 0 and ms2.files.hits == len(want.nodes)  # every graph from its file, no web read
    assert ms2.files.writes == 0 and ms2.files.stats()["mapped"]["entries"] == len(want.nodes)
    assert [(n.segment, n.distance, n.tier) for n in got.nodes] == [(n.segment, n.distance, n.tier) for n in want.nodes]
    packed = MatchSearch(StoreWebs.for_query(MotionStore(str(tmp_path / "store"), read_only=True), pc.query.clip))
    for clip in src1:
        a, b = packed.graph(clip), ms2.graph(clip)
        assert ms2.graph(clip) is b and ms1.graph(clip) is not b  # kept mapped, per process
        assert not b.rows.flags.owndata and b.rows.flags.writeable  # a view of the mapped file
        assert a.others == b.others and b.values.dtype == np.float32
        for name in (*WalkGraph.STORED, "clip_rank"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert ms2.files.hits == len(want.nodes)  # a graph asked again: no second open
    # a file from another layout (or of other webs under a colliding key) is packed again, and replaced
    fkey = src2.content_key(pc.query.clip, f"walk graph layout {WalkGraph.LAYOUT}")
    arrays, meta = files.get(fkey)
    files.put(fkey, arrays, {**meta, "layout": WalkGraph.LAYOUT + 1})
    src3, ms3 = fresh()
    assert ms3.graph(pc.query.clip).n_states == ms1.graph(pc.query.clip).n_states and src3.reads > 0
    assert files.get(fkey)[1]["layout"] == WalkGraph.LAYOUT
    # a pass over the scope's webs with the shards read in threads answers as the webs one by one
    from motionweb.tasks.search import finite_path_values

    srcm, _ = fresh()
    want_v = [finite_path_values(w) for w in srcm.all_webs()]  # in records() order, now all in the cache
    reads = srcm.reads
    fresh_src, _ = fresh()
    for src in (fresh_src, srcm):  # read from the store, then from srcm's cache
        got_v = src.map_webs(finite_path_values, threads=2)
        assert len(got_v) == len(want_v) and all(np.array_equal(a, b) for a, b in zip(got_v, want_v, strict=True))
        assert src.reads == reads > 0  # each web read once by the pass; none by srcm's (all cached)
    # a scope's quantile of web values is kept too: a later search of the scope reads no web for it
    all_webs = fresh()[0].all_webs()  # the reference: every web of the scope, read whole
    want_q = epsilon_from_quantile(all_webs, 0.3)
    src4, ms4 = fresh()
    assert ms4.quantile(0.3, stream=True) == want_q and src4.reads == len(all_webs) > 0  # each web read once
    src5, ms5 = fresh()
    assert ms5.quantile(0.3) == want_q and src5.reads == 0
    assert ms5.quantile(0.7) == epsilon_from_quantile(src5.all_webs(), 0.7)  # another quantile: its own key
    # any other quantile of the scope from its sorted values, kept by the first pass: no web read
    src6, ms6 = fresh()
    for q in (0.0, 0.05, 0.123, 0.5, 0.99, 1.0):
        assert ms6.quantile(q) == epsilon_from_quantile(all_webs, q)
    assert src6.reads == 0
    vkey = src6.scope_key("path values sorted")
    values = files.get(vkey)[0]["values"]
    assert values.dtype == np.float32 and np.all(np.diff(values) >= 0)
    kept = ms6.path_values()
    assert not kept.flags.owndata and ms6.path_values() is kept  # a view of the mapped file, opened once
    for raw in (False, True):  # not sorted (compressed, or raw and mapped): taken again, and replaced
        files.put(vkey, {"values": values[::-1].copy()}, {"n": len(values)}, raw=raw)
        src7, ms7 = fresh()
        assert np.array_equal(ms7.path_values(), values) and src7.reads > 0
        assert np.array_equal(files.get(vkey)[0]["values"], values)
    files.put(vkey, {"values": values}, {"n": len(values) + 1}, raw=True)  # another count: refused too
    src8, ms8 = fresh()
    assert np.array_equal(ms8.path_values(), values) and src8.reads > 0
    # a source that does not name its webs' content (a plain mapping) keeps no files
    assert MatchSearch(webs, files=files).files is None


def test_long_clips_are_searched_through_window_graphs(chain, tmp_path) -> None:
    """Issue 25 part 5: clips whose webs hold more states than ``window_graph_states`` are packed
    per query window: the tiered search and the trial ranking give what whole graphs give, the
    window graphs are kept under their rows (in memory, or in the file cache, where another
    process reads them back without a web read), and a window graph holds fewer states."""
    from motionweb.store.filecache import FileCache
    from motionweb.tasks.search import MatchSearch

    pc, webs = chain
    whole = MatchSearch(webs, SearchParams())
    part = MatchSearch(webs, SearchParams(window_graph_states=0))
    want = whole.search(pc.query, 0.003)
    assert [n.segment.clip for n in want.nodes[1:]] == list(pc.expected)
    got = part.search(pc.query, 0.003)
    assert [(n.segment, n.distance, n.tier) for n in got.nodes] == [(n.segment, n.distance, n.tier) for n in want.nodes]
    assert part._long == {n.segment.clip for n in want.nodes}
    keys = part._graphs.oldest_first()
    graphs = [k for k in keys if k[1] != "webs"]
    assert graphs and all(len(k) == 3 and isinstance(k[2], tuple) for k in graphs)
    assert {k[2] for k in keys if k[1] == "webs"} == part._long  # and each long clip's webs
    q = pc.query
    assert part.graph(q.clip, (q.start, q.end)).n_states < whole.graph(q.clip).n_states
    assert part.graph(q.clip, (q.start, q.end)) is part.graph(q.clip, (q.start, q.end))  # kept
    rw, rp = rank_trials(whole, q), rank_trials(part, q)
    assert rp.ranking == rw.ranking and rp.found == rw.found
    # in the file cache: another process reads the window graphs back, no web read
    _commit_chain(pc, webs, tmp_path / "store")

    def fresh() -> tuple[StoreWebs, MatchSearch]:
        src = StoreWebs.for_query(MotionStore(str(tmp_path / "store"), read_only=True), q.clip)
        src.keep_webs = False  # as the service's worker reads them: webs not kept by the source
        return src, MatchSearch(src, SearchParams(window_graph_states=0), files=FileCache(tmp_path / "graphs", 1 << 30))

    src1, ms1 = fresh()
    first = ms1.search(q, 0.003)
    assert ms1.files.writes == len(want.nodes) and src1.reads > 0
    src2, ms2 = fresh()
    again = ms2.search(q, 0.003)
    assert src2.reads == 0 and ms2.files.hits == len(want.nodes) and ms2.files.writes == 0
    assert [(n.segment, n.distance) for n in again.nodes] == [(n.segment, n.distance) for n in first.nodes] \
        == [(n.segment, n.distance) for n in want.nodes]
    # a new window of a long clip packs from its webs kept in the memory cache (up to half its bound)
    reads = src1.reads
    other = ms1.graph(q.clip, (q.start + 1, q.end))
    assert src1.reads == reads and other.n_states > 0
    from motionweb.store.cache import LRU

    src3 = StoreWebs.for_query(MotionStore(str(tmp_path / "store"), read_only=True), q.clip)
    src3.keep_webs = False  # as the service's worker reads them: webs not kept by the source
    small = MatchSearch(src3, SearchParams(window_graph_states=0), graphs=LRU(max_bytes=1000))
    small.graph(q.clip, (q.start, q.end))
    reads = src3.reads
    small.graph(q.clip, (q.start + 1, q.end))
    assert src3.reads == 2 * reads  # webs more than half the bound: not kept, read again


@pytest.mark.skipif(not HAVE_SMAPS, reason="needs Linux's /proc/self/smaps")
def test_asking_for_a_graph_releases_the_pages_of_the_graphs_walked_before(chain, tmp_path) -> None:
    """Issue 25 part 5: a walk maps most pages of a mapped graph (the page cache's folios), so
    MatchSearch.graph releases those of the graphs walked before: a search holds the graphs in
    use, not every graph it walked; the walks find the same matches after a release."""
    from motionweb.store.filecache import FileCache
    from motionweb.tasks.search import MatchSearch, WalkGraph

    pc, webs = chain
    _commit_chain(pc, webs, tmp_path / "store")
    src = StoreWebs.for_query(MotionStore(str(tmp_path / "store"), read_only=True), pc.query.clip)
    ms = MatchSearch(src, SearchParams(), files=FileCache(tmp_path / "graphs", 1 << 30))
    clips = sorted(src)
    for c in clips:
        ms.graph(c)  # packed, written, mapped
    key = {c: src.content_key(c, f"walk graph layout {WalkGraph.LAYOUT}") for c in clips}
    paths = {c: tmp_path / "graphs" / key[c][:2] / f"{key[c]}.mwc" for c in clips}
    assert len(clips) > 2 and all(p.is_file() for p in paths.values())
    first = {}
    for c in clips:
        g = ms.graph(c)
        first[c] = find_matches(g, 0, g.n_frames - 1, 0.01)  # every row: every page read
        assert mapping_rss_kb(paths[c]) > 0, c
        others = [o for o in clips if o != c]
        assert all(mapping_rss_kb(paths[o]) == 0 for o in others), c  # released when this one was asked
    for c in clips:  # walked again after the release: the same matches
        g = ms.graph(c)
        again = find_matches(g, 0, g.n_frames - 1, 0.01)
        assert [(m.clip, m.start, m.end, m.cost) for m in again] == [(m.clip, m.start, m.end, m.cost) for m in first[c]]


def test_a_packed_graph_from_outside_is_checked(chain) -> None:
    """WalkGraph.from_arrays refuses what the compiled walks could index out of bounds with."""
    from motionweb.tasks.search import WalkGraph

    pc, webs = chain
    g = walk_graph(webs[pc.query.clip])
    arrays, meta = g.to_arrays()
    ok = WalkGraph.from_arrays(arrays, meta, g.others)
    assert ok.n_states == g.n_states and np.array_equal(ok.clip_rank, g.clip_rank)

    def damaged(name: str, change) -> dict:
        out = {k: v.copy() for k, v in arrays.items()}
        change(out[name])
        return out

    n = g.n_states
    cases = {
        "a next state out of range": damaged("nxt", lambda a: a.__setitem__(0, n)),
        "a branch state out of range": damaged("branch_to", lambda a: a.__setitem__(0, -1)),
        "a start state out of range": damaged("starts", lambda a: a.__setitem__(0, n + 5)),
        "a cell out of range": damaged("rows", lambda a: a.__setitem__(0, g.n_frames)),
        "offsets out of order": damaged("branch_off", lambda a: a.__setitem__(slice(1, 3), [5, 2])),
        "web row table": damaged("web_rows", lambda a: a.__setitem__((0, 1), n + 1)),
        "does not advance": damaged("cols", lambda a: a.__setitem__(slice(None), 0)),
    }
    for what, bad in cases.items():
        with pytest.raises(ValueError, match=what):
            WalkGraph.from_arrays(bad, meta, g.others)
    with pytest.raises(ValueError, match="differ in length"):
        WalkGraph.from_arrays({**arrays, "values": arrays["values"][:-1]}, meta, g.others)
    with pytest.raises(ValueError, match="layout"):
        WalkGraph.from_arrays(arrays, meta, g.others[:-1])


# ---------------------------------------------------------------------------- graph dedup


def diagonal_web(shape: tuple[int, int], shifts: dict[int, float], last_row: int = 10**9) -> MatchWeb:
    """Paths j = i + shift (rows ≤ ``last_row`` where the column exists) of constant value, no bridges."""
    parts = [np.array([(i, i + s) for i in range(min(shape[0], last_row + 1)) if 0 <= i + s < shape[1]])
             for s in shifts]
    vals = [np.full(len(p), v) for p, v in zip(parts, shifts.values(), strict=True)]
    return MatchWeb(rate=30.0, shape=shape, paths_cells=np.concatenate(parts), paths_values=np.concatenate(vals),
                    paths_offsets=np.cumsum([0, *map(len, parts)]))


def test_dedup_new_node_merge_and_discard() -> None:
    """design §5 on constructed webs: A→B, A→C diagonals, B→C shifted by 4 (a near-duplicate of C:
    merged, intervals averaged), A→D at shifts 0, 15 (overlap 0.52: discarded) and 30 (overlap
    1/31: a new node), A→D paths ending at row 45 (so D[40, 70] finds only A's query back)."""
    n = 80
    ab, ac = diagonal_web((n, n), {0: 0.1}), diagonal_web((n, n), {0: 0.1})
    bc, ad = diagonal_web((n, n), {4: 0.1}), diagonal_web((n, n), {0: 0.1, 15: 0.2, 30: 0.3}, last_row=45)
    webs = {"A": [("B", ab), ("C", ac), ("D", ad)], "B": [("A", transpose(ab)), ("C", bc)],
            "C": [("A", transpose(ac)), ("B", transpose(bc))], "D": [("A", transpose(ad))]}
    cfg = SearchParams(overlap_redundant=0.9)
    graph = search(Segment("A", 10, 40), 1.0, webs, cfg)
    assert sorted((s.clip, s.start, s.end) for s in (n.segment for n in graph.nodes)) == [
        ("A", 10, 40),  # the query is never moved
        ("B", 9, 39),  # merged with B[8, 38] found from C[12, 42]
        ("C", 12, 42),  # merged with C[14, 44] found from B[10, 40]
        ("D", 10, 40), ("D", 40, 70)]  # D[25, 55] (overlap 16/31 with D[10, 40]) discarded
    dist = {(n.segment.clip, n.segment.start): n.distance for n in graph.nodes}
    assert dist == pytest.approx({("A", 10): 0.0, ("B", 9): 0.1, ("C", 12): 0.1, ("D", 10): 0.1, ("D", 40): 0.3})
    pairs = {frozenset((graph.nodes[e.u].segment.clip + str(graph.nodes[e.u].segment.start),
                        graph.nodes[e.v].segment.clip + str(graph.nodes[e.v].segment.start))) for e in graph.edges}
    assert pairs == {frozenset(p) for p in (("A10", "B9"), ("A10", "C12"), ("B9", "C12"), ("A10", "D10"),
                                            ("A10", "D40"))}
    assert len(graph.edges) == len(pairs)  # one edge per node pair
    for e in graph.edges:  # cells are (frame of u's clip, frame of v's clip)
        assert e.cells[0, 0] == 10 or graph.nodes[e.u].segment.clip != "A"


def test_placement_is_the_one_at_a_time_dedup() -> None:
    """The compiled placement of a batch of matches = placing them one at a time with
    ``Segment.overlap`` (random overlapping intervals on three clips, merges rounding half to even)."""
    rng = np.random.default_rng(5)
    for trial in range(30):
        new_below, merge_above = [(0.2, 0.8), (0.5, 0.5), (0.1, 0.6)][trial % 3]
        nodes = [Segment("c0", 40, 60)]
        where = np.zeros((3, 400), np.int64)
        where[:, 0] = 0, 40, 60
        n = 1
        for _ in range(4):  # batches, as one per query node
            clip = rng.integers(0, 3, 60)
            start = rng.integers(0, 90, 60)
            end = start + rng.integers(0, 25, 60)
            ref = ref_place(nodes, [Segment(f"c{c}", int(a), int(b)) for c, a, b in zip(clip, start, end)],
                            new_below, merge_above)
            node, new, _ = place_matches(clip, start, end, where, n, new_below, merge_above)
            assert [None if v < 0 else v for v in node.tolist()] == ref
            assert np.nonzero(new)[0].tolist() == [u for u, v in enumerate(ref) if v is not None and v >= n
                                                   and v not in ref[:u]]
            n += int(new.sum())
            assert n == len(nodes)
            assert [(f"c{c}", a, b) for c, a, b in where[:, :n].T.tolist()] == [(x.clip, x.start, x.end) for x in nodes]


def test_matches_too_short_or_too_steep_are_not_kept() -> None:
    """A walk can chain paths and bridges into a match far steeper than the slope rule allows (here
    a constructed vertical path): find_matches reports it, the tiered search does not keep it."""
    steep = np.array([(i, 5 + i // 4) for i in range(60)])  # 4 rows per column: slope 1/4 < 1/3
    web = MatchWeb(rate=30.0, shape=(60, 60), paths_cells=steep, paths_values=np.full(60, 0.1),
                   paths_offsets=[0, 60])
    assert [(m.start, m.end) for m in walk_web(web, 10, 40, 1.0)] == [(7, 15)]
    graph = search(Segment("A", 10, 40), 1.0, {"A": [("B", web)], "B": [("A", transpose(web))]})
    assert len(graph.nodes) == 1 and not graph.edges
    short = MatchWeb(rate=30.0, shape=(60, 60), paths_cells=[(i, i) for i in range(60)], paths_values=np.full(60, 0.1),
                     paths_offsets=[0, 60])
    ms = MatchSearch({"A": [("B", short)], "B": [("A", transpose(short))]})
    assert [m.segment for m in ms.matches(Segment("A", 10, 20), 1.0)] == [Segment("B", 10, 20)]
    assert ms.matches(Segment("A", 10, 16), 1.0) == []  # 6 frames < the minimum chain length (8)


# ---------------------------------------------------------------------------- default ε and trial ranking


def test_nearest_match_is_the_least_average_walk(tangled_web) -> None:
    """One pass for all starts (per-web Dinkelbach) = the least average over every enumerated
    match sequence; with the length and slope rules, a valid match no better than the enumeration's
    best valid one."""
    web = tangled_web
    g = walk_graph([("other", web), ("self", web)])  # two webs: each solved alone
    n = 0
    for a in range(0, 50, 2):
        for b in range(a, min(50, a + 24)):
            ref = ref_matches(web, a, b)
            cost, c, d = nearest_matches(g, a, b)
            if not ref:
                assert np.all(np.isinf(cost)) and np.all(c == -1)
                continue
            least = min(v[0] for v in ref.values())
            assert cost == pytest.approx([least, least], rel=1e-9, abs=1e-12)
            assert ref[(int(c[0]), int(d[0]))][0] == pytest.approx(least, rel=1e-9, abs=1e-12)
            rows, span = b - a + 1, 6
            ok = {key: v[0] for key, v in ref.items() if key[1] - key[0] >= span
                  and rows <= 3 * (key[1] - key[0] + 1) and key[1] - key[0] + 1 <= 3 * rows}
            fc, fcs, fds = nearest_matches(g, a, b, span, 3)
            if np.isfinite(fc[0]):
                key = (int(fcs[0]), int(fds[0]))
                assert key in ok and ok[key] == pytest.approx(fc[0], rel=1e-9) and fc[0] >= min(ok.values()) - 1e-12
                n += fc[0] == pytest.approx(min(ok.values()), rel=1e-9)
            else:
                assert not ok or min(ok.values()) > least
    assert n > 100  # the rules rarely cost the exact answer


def test_nearest_by_clip_is_the_least_over_each_clips_webs(tangled_web) -> None:
    """The per-clip reduction in the kernel = the least of :func:`nearest_matches` over each slot's
    webs (the first web on ties), skipped webs never counted."""
    web = tangled_web
    g = walk_graph([("a", web), ("b", transpose(web)), ("a", transpose(web)), ("c", web)])
    for slots in ([0, 1, 0, 2], [1, -1, 1, 0], [-1, -1, -1, -1]):
        for a, b in [(0, 20), (5, 30), (12, 40), (30, 49)]:
            per_web = nearest_matches(g, a, b, 6, 3)
            ref = np.full(3, np.inf), np.full(3, -1), np.full(3, -1)
            for w, s in enumerate(slots):
                if s >= 0 and per_web[0][w] < ref[0][s]:
                    for k in range(3):
                        ref[k][s] = per_web[k][w]
            got = nearest_by_clip(g, a, b, np.array(slots), 3, 6, 3)
            for x, y in zip(got, ref):
                assert np.array_equal(x, y)
    assert np.isfinite(nearest_by_clip(g, 5, 30, np.array([0, 1, 0, 2]), 3)[0]).all()


def test_default_epsilon_and_ranking_find_the_planted_copies(planted) -> None:
    """The default rule (2 × the nearest match) needs no threshold: the planted copies (~3e-4)
    are found with their endpoints, the other motions (≥ 0.02) are not; the trial ranking puts the
    copies first and finds them."""
    pc, webs = planted
    ms = MatchSearch(webs, SearchParams(max_tiers=1))
    near = nearest_costs(ms, pc.query)
    assert pc.query.clip not in near and set(pc.expected) <= set(near)
    eps = default_epsilon(near, 2.0)
    assert eps == pytest.approx(2.0 * min(near.values()))
    graph = ms.search(pc.query, eps)
    hits = [n.segment for n in graph.nodes[1:] if n.segment.clip in pc.expected
            and abs(n.segment.start - pc.expected[n.segment.clip].start) <= TOL
            and abs(n.segment.end - pc.expected[n.segment.clip].end) <= TOL]
    assert len({s.clip for s in hits}) / len(pc.expected) >= 0.95
    assert len(hits) / max(len(graph.nodes) - 1, 1) >= 0.95
    r = rank_trials(ms, pc.query, tiers=1)  # one tier: only the query clip's webs get built (tiers: below)
    assert set(r.found) <= set(pc.expected) and len(r.found) >= 0.95 * len(pc.expected)
    assert set(r.ranking[:len(pc.expected)]) == set(pc.expected) and pc.query.clip not in r.ranking
    assert [r.score[c] for c in r.ranking] == sorted(r.score.values())
    assert len(r.windows) >= 3 and r.windows[0].start == pc.query.start and r.windows[-1].end == pc.query.end
    assert default_epsilon({}, 2.0) is None  # no nearest match: the query alone (MatchSearch.query_only)
    alone = ms.query_only(pc.query)
    assert [n.segment for n in alone.nodes] == [pc.query] and not alone.edges
    with pytest.raises(ValueError, match="tiers"):
        rank_trials(ms, pc.query, tiers=0)


def test_rank_trials_finds_far_variants_through_tiers(chain) -> None:
    """Each variant is as close to the next as the first is to the query: one tier finds the
    first only; every further tier one more, in chain order."""
    pc, webs = chain
    ms = MatchSearch(webs, SearchParams())
    one = rank_trials(ms, pc.query, tiers=1)
    assert one.found == ["kick/variant_1"]
    two = rank_trials(ms, pc.query, tiers=2)
    assert two.found == list(pc.expected)[:2]
    many = rank_trials(ms, pc.query, tiers=len(pc.expected))
    assert many.found[:3] == list(pc.expected)[:3] and set(many.found) <= set(pc.expected)
    assert many.ranking[:len(pc.expected)] == list(pc.expected)  # chain order


def test_graphs_share_the_threads_work_buffers(chain) -> None:
    """The walk's work buffers are one set per thread (tasks/search.work_buffers), grown for a
    larger band and shared by every graph: a search after walks of graphs of other sizes gives
    what it gives in a fresh thread (fresh buffers), and a cached graph holds no buffers."""
    import threading

    from motionweb.tasks.search import _POOL, work_buffers

    pc, webs = chain
    ms = MatchSearch(webs)
    sizes = {c: ms.graph(c).band(0, ms.graph(c).n_frames - 1) for c in webs}
    first = search(pc.query, 0.003, webs, SearchParams())
    for c in sorted(sizes, key=sizes.get, reverse=True):  # walk the largest graphs first
        ms.matches(Segment(c, 0, ms.graph(c).n_frames - 1), 0.01)
    assert len(_POOL.work[0]) >= max(sizes.values())
    assert (_POOL.work[0] == 0).all()  # every walk restores the marks
    fresh = []
    t = threading.Thread(target=lambda: fresh.append(search(pc.query, 0.003, webs, SearchParams())))
    t.start()
    t.join()
    again = search(pc.query, 0.003, webs, SearchParams())
    for got in (fresh[0], again):
        assert [(n.segment, n.tier) for n in got.nodes] == [(n.segment, n.tier) for n in first.nodes]
        assert [n.distance for n in got.nodes] == [n.distance for n in first.nodes]
    g = ms.graph(pc.query.clip)
    assert g.nbytes == sum(a.nbytes for a in (g.rows, g.cols, g.values, g.nxt, g.branch_off, g.branch_to,
                                              g.web_rows, g.start_off, g.starts, g.clip_rank))
    assert all(len(b) == 5 for b in work_buffers(5))
    assert all(a.dtype == np.int32 for a in (g.nxt, g.branch_off, g.branch_to, g.web_rows, g.start_off, g.starts))
