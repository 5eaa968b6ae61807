"""Property-based tests of the compiled search walks (KG04 §3.3) against the slow enumeration.

Random match webs, small enough to enumerate, with what real webs hold and the first version of
the walk did not survive (issue 22): paths that share a cell joined by one-cell bridges
("switches"), bridges of two cells, webs of one row or one column, webs of very different lengths
packed into one graph, queries on a clip's first and last frame, ε = 0 and ε huge. Run with
``NUMBA_BOUNDSCHECK=1`` (CI's second pass) any write out of bounds is an IndexError here.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from motionweb.store.web import MatchWeb, transpose
from motionweb.tasks.matchgraph import Segment
from motionweb.tasks.matchweb.params import MatchWebParams
from motionweb.tasks.search import MatchSearch, SearchParams, nearest_matches, walk_graph, walk_web
from naive import TooManySequences, ref_cut_rows, ref_matches, ref_walk_graph, ref_walk_steps

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _staircase(draw, start: tuple[int, int], end: tuple[int, int]) -> list[tuple[int, int]]:
    """A monotone path of cells from ``start`` to ``end`` (up, right or diagonal steps)."""
    (i, j), (i1, j1) = start, end
    cells = [(i, j)]
    while (i, j) != (i1, j1):
        moves = [(di, dj) for di, dj in ((1, 0), (0, 1), (1, 1)) if i + di <= i1 and j + dj <= j1]
        di, dj = moves[draw(st.integers(0, len(moves) - 1))]
        i, j = i + di, j + dj
        cells.append((i, j))
    return cells


@st.composite
def webs(draw, rows: int | None = None) -> MatchWeb:
    """A random web: monotone paths (some through a cell of an earlier path), proper bridges
    between path cells and switches where two paths share a cell."""
    fa = rows if rows is not None else draw(st.integers(1, 14))
    fb = draw(st.integers(1, 14))
    paths: list[list[tuple[int, int]]] = []
    for _ in range(draw(st.integers(0, 4))):
        if paths and draw(st.booleans()):  # through a cell of an earlier path: a shared cell
            p = paths[draw(st.integers(0, len(paths) - 1))]
            mid = p[draw(st.integers(0, len(p) - 1))]
            a = (draw(st.integers(0, mid[0])), draw(st.integers(0, mid[1])))
            b = (draw(st.integers(mid[0], fa - 1)), draw(st.integers(mid[1], fb - 1)))
            cells = _staircase(draw, a, mid)[:-1] + _staircase(draw, mid, b)
        else:
            a = (draw(st.integers(0, fa - 1)), draw(st.integers(0, fb - 1)))
            b = (draw(st.integers(a[0], fa - 1)), draw(st.integers(a[1], fb - 1)))
            cells = _staircase(draw, a, b)
        paths.append(cells)
    bridges, bcells = [], []
    where: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for p, cells in enumerate(paths):
        for i, c in enumerate(cells):
            where.setdefault(c, []).append((p, i))
    for c, at in where.items():  # switches: every ordered pair of paths sharing a cell, sometimes
        for p, i in at:
            for q, j in at:
                if p != q and draw(st.booleans()):
                    bridges.append((p, i, q, j))
                    bcells.append([c])
    if len(paths) >= 2:
        for _ in range(draw(st.integers(0, 4))):
            p, q = draw(st.integers(0, len(paths) - 1)), draw(st.integers(0, len(paths) - 1))
            if p == q:
                continue
            i, j = draw(st.integers(0, len(paths[p]) - 1)), draw(st.integers(0, len(paths[q]) - 1))
            x, y = paths[p][i], paths[q][j]
            if y[0] >= x[0] and y[1] >= x[1] and y != x:
                bridges.append((p, i, q, j))
                bcells.append(_staircase(draw, x, y))
    values = st.floats(0.0, 1.0, allow_nan=False, width=32)
    pc = [c for cells in paths for c in cells]
    bc = [c for cells in bcells for c in cells]
    return MatchWeb(
        rate=30.0, shape=(fa, fb),
        paths_cells=np.array(pc, np.int32).reshape(-1, 2),
        paths_values=np.array([draw(values) for _ in pc], np.float32),
        paths_offsets=np.cumsum([0, *map(len, paths)]),
        bridges=np.array(bridges, np.int64).reshape(-1, 4),
        bridges_cells=np.array(bc, np.int32).reshape(-1, 2),
        bridges_values=np.array([draw(values) for _ in bc], np.float32),
        bridges_offsets=np.cumsum([0, *map(len, bcells)]),
    )


def _query(draw, fa: int, web: MatchWeb | None = None) -> tuple[int, int]:
    """Rows a..b: the first and last rows among the choices, and where ``web`` has a switch below
    its last row mostly a range across it (the case the enumeration tells apart)."""
    if web is not None and web.n_bridges and draw(st.integers(0, 3)) > 0:
        rows = [int(web.bridges_cells[web.bridges_offsets[k], 0]) for k in range(web.n_bridges)
                if web.bridges_offsets[k + 1] - web.bridges_offsets[k] == 1]
        rows = [r for r in rows if r < fa - 1]
        if rows:
            x = draw(st.sampled_from(rows))
            return draw(st.integers(0, x)), draw(st.integers(x + 1, fa - 1))
    a = draw(st.sampled_from(sorted({0, fa - 1, draw(st.integers(0, fa - 1))})))
    b = draw(st.sampled_from(sorted({a, fa - 1, draw(st.integers(a, fa - 1))})))
    return a, b


@SETTINGS
@given(st.data())
def test_walk_equals_the_enumeration(data) -> None:
    """Every match of rows a..b (per (c, d): the least average) is the enumeration's, for ε huge
    and ε = 0 and ε at a match's own average, on webs with switches and two-cell bridges."""
    web = data.draw(webs())
    a, b = _query(data.draw, web.shape[0], web)
    try:
        ref = ref_matches(web, a, b, max_sequences=20000)
    except TooManySequences:
        return
    got = {(m.start, m.end): m for m in walk_web(web, a, b, 1e30)}
    assert set(got) == set(ref)
    for key, (least, _) in ref.items():
        m = got[key]
        assert m.cost == pytest.approx(least, rel=1e-9, abs=1e-12)
        assert m.cells[0, 0] == a and m.cells[-1, 0] == b and tuple(m.cells[[0, -1], 1]) == key
        assert np.all(np.diff(m.cells.astype(np.int64), axis=0) >= 0)
    assert {(m.start, m.end) for m in walk_web(web, a, b, 0.0)} == {k for k, v in ref.items() if v[0] <= 0.0}
    if ref:
        eps = data.draw(st.sampled_from(sorted(v[0] for v in ref.values())))
        assert {(m.start, m.end) for m in walk_web(web, a, b, eps)} == {k for k, v in ref.items() if v[0] <= eps}
    # the one-pass nearest match is the least of them all
    cost, c, d = nearest_matches(walk_graph([("x", web)]), a, b)
    if ref:
        assert cost[0] == pytest.approx(min(v[0] for v in ref.values()), rel=1e-9, abs=1e-12)
        assert (int(c[0]), int(d[0])) in ref
    else:
        assert cost[0] == np.inf and c[0] == -1 and d[0] == -1


@SETTINGS
@given(st.data())
def test_packed_steps_advance_and_equal_the_reference(data) -> None:
    """The packed graph holds exactly the reference's steps, and every step goes up or right."""
    web = data.draw(webs())
    g = walk_graph([("x", web)])
    assert g.dropped_steps == 0
    got = []
    for s in range(g.n_states):
        succ = ([g.nxt[s]] if g.nxt[s] >= 0 else []) + list(g.branch_to[g.branch_off[s]:g.branch_off[s + 1]])
        for t in succ:
            assert g.rows[t] >= g.rows[s] and g.cols[t] >= g.cols[s] and g.rows[t] + g.cols[t] > g.rows[s] + g.cols[s]
        got += [((int(g.rows[s]), int(g.cols[s])), (int(g.rows[t]), int(g.cols[t])), float(g.values[t])) for t in succ]
    assert sorted(got) == sorted(ref_walk_steps(web))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_tiered_search_over_webs_of_very_different_lengths(data) -> None:
    """Several clips, each clip's webs of very different column counts packed into one graph, a
    tiered search from every kind of query: never an error other than the documented ValueErrors,
    every node inside its clip."""
    n_clips = data.draw(st.integers(1, 4))
    frames = [data.draw(st.sampled_from([1, 2, 5, 13, 40])) for _ in range(n_clips)]
    names = [f"c{k}" for k in range(n_clips)]
    source: dict[str, list[tuple[str, MatchWeb]]] = {n: [] for n in names}
    for i in range(n_clips):  # one web per pair, both ways round (as a store gives them)
        for j in range(i, n_clips):
            w = data.draw(webs(rows=frames[i]))
            if w.shape[1] > frames[j]:
                continue
            w = MatchWeb(rate=w.rate, shape=(frames[i], frames[j]), **{
                k: v for k, v in w.to_arrays().items() if k not in ("rate", "shape", "self_pair")})
            source[names[i]].append((names[j], w))
            if j != i:
                source[names[j]].append((names[i], transpose(w)))
    clip = data.draw(st.sampled_from(names))
    if not source[clip]:
        return
    a, b = _query(data.draw, frames[names.index(clip)])
    ms = MatchSearch(source, SearchParams(max_tiers=data.draw(st.sampled_from([1, 3, 20]))),
                     MatchWebParams(min_chain_s=0.0))
    eps = data.draw(st.sampled_from([0.0, 0.3, 1e30]))
    graph = ms.search(Segment(clip, a, b), eps)
    for n in graph.nodes:
        f = frames[names.index(n.segment.clip)]
        assert 0 <= n.segment.start <= n.segment.end < f


def _matches(g, a: int, b: int, eps: float) -> list[tuple]:
    from motionweb.tasks.search import find_matches

    return sorted((m.clip, m.start, m.end, round(m.cost, 9), m.cells.tobytes()) for m in find_matches(g, a, b, eps))


@SETTINGS
@given(st.data())
def test_a_window_graph_walks_as_the_whole_graph(data) -> None:
    """Issue 25 part 5: the graph of rows a0..b0 alone (``walk_graph(..., rows)``) gives every walk
    of rows a..b within a0..b0 the matches (each with its walk) and the nearest matches of the
    whole clip's graph, at ε = 0, mid and huge; the window holds no more states than the whole."""
    fa = data.draw(st.integers(1, 12))
    webs_ = [(f"c{data.draw(st.integers(0, 3))}", data.draw(webs(rows=fa)))
             for _ in range(data.draw(st.integers(1, 5)))]
    a0 = data.draw(st.integers(-2, fa - 1))
    b0 = data.draw(st.integers(max(a0, 0), fa + 2))
    whole, part = walk_graph(webs_), walk_graph(webs_, (a0, b0))
    assert part.n_states <= whole.n_states and part.n_frames == whole.n_frames and part.others == whole.others
    lo, hi = max(a0, 0), min(b0, fa - 1)
    a = data.draw(st.integers(lo, hi))
    b = data.draw(st.integers(a, hi))
    for eps in (0.0, 0.3, 1e30):
        assert _matches(part, a, b, eps) == _matches(whole, a, b, eps)
    for got, want in zip(nearest_matches(part, a, b), nearest_matches(whole, a, b)):
        assert np.array_equal(got, want)


@SETTINGS
@given(st.data())
def test_the_compiled_window_cut_equals_the_reference(data) -> None:
    """``_packed_window`` (compiled, numbering the window's states only) gives, array for array,
    ``naive.ref_cut_rows`` of every packed state, for windows inside, across and outside the
    rows, on webs with switches, two-cell bridges and empty webs."""
    from motionweb.tasks.search import _packed_states, _packed_window

    fa = data.draw(st.integers(1, 12))
    webs_ = [data.draw(webs(rows=fa)) for _ in range(data.draw(st.integers(1, 5)))]
    a = data.draw(st.integers(0, fa - 1))
    b = data.draw(st.integers(a, fa - 1))
    got, want = _packed_window(webs_, a, b), ref_cut_rows(_packed_states(webs_), a, b)
    assert set(got) == set(want)
    for name in want:
        assert got[name].shape == want[name].shape and np.array_equal(got[name], want[name]), name
    assert got["cells"].dtype == np.int32 and got["values"].dtype == np.float32


GRAPH_FIELDS = ("rows", "cols", "values", "nxt", "branch_off", "branch_to", "web_rows", "start_off", "starts",
                "clip_rank")


@SETTINGS
@given(st.data())
def test_packing_equals_the_per_web_reference(data) -> None:
    """All webs of a clip packed at once (vectorised) give the graph the per-web packing gives:
    every array equal, state for state (values: float32 that widen to the reference's float64),
    on 1-6 webs of one row count with switches, two-cell bridges, empty webs and webs of one row."""
    fa = data.draw(st.integers(1, 12))
    webs_ = [(f"c{data.draw(st.integers(0, 3))}", data.draw(webs(rows=fa)))
             for _ in range(data.draw(st.integers(1, 6)))]
    got, ref = walk_graph(webs_), ref_walk_graph(webs_)
    assert got.values.dtype == np.float32 and got.n_frames == ref.n_frames and got.others == ref.others
    for name in GRAPH_FIELDS:
        a, b = getattr(got, name), getattr(ref, name)
        assert a.shape == b.shape and np.array_equal(a.astype(np.float64), b.astype(np.float64)), name
    assert got.dropped_steps == ref.dropped_steps


@SETTINGS
@given(st.data())
def test_a_damaged_packed_graph_is_refused_or_walks_in_bounds(data) -> None:
    """Issue 25 part 5: a graph read back from a file (``WalkGraph.from_arrays``) with any one
    entry of any array set to an extreme or random value is refused with a ValueError, or passes
    the check and then walks (every row band, ε huge) without an index out of bounds (CI runs this
    under NUMBA_BOUNDSCHECK=1)."""
    from motionweb.tasks.search import WalkGraph, find_matches

    fa = data.draw(st.integers(1, 10))
    webs_ = [("x", data.draw(webs(rows=fa))) for _ in range(data.draw(st.integers(1, 3)))]
    g = walk_graph(webs_)
    arrays, meta = g.to_arrays()
    name = data.draw(st.sampled_from([k for k in WalkGraph.STORED if arrays[k].size]))
    bad = {k: v.copy() for k, v in arrays.items()}
    flat = bad[name].reshape(-1)
    i = data.draw(st.integers(0, flat.size - 1))
    big = np.iinfo(flat.dtype).max if flat.dtype.kind == "i" else np.inf
    flat[i] = data.draw(st.sampled_from([-1, -2, 0, 1, g.n_states, g.n_states + 1, fa, big,
                                         data.draw(st.integers(-5, g.n_states + 5))]))
    try:
        h = WalkGraph.from_arrays(bad, meta, g.others)
    except ValueError:
        return
    for a in range(fa):
        for b in range(a, fa):
            find_matches(h, a, b, 1e30)


def test_packing_equals_the_reference_on_a_malformed_web() -> None:
    """A step back, dropped the same way by both packings; a web outside its grid named by both."""
    back = MatchWeb(rate=30.0, shape=(5, 5), paths_cells=[[0, 0], [2, 2], [1, 1], [3, 3]], paths_values=[0.1] * 4,
                    paths_offsets=[0, 4])
    good = MatchWeb(rate=30.0, shape=(5, 3), paths_cells=[[0, 0], [1, 1]], paths_values=[0.2, 0.3],
                    paths_offsets=[0, 2])
    got, ref = walk_graph([("g", good), ("x", back)]), ref_walk_graph([("g", good), ("x", back)])
    assert got.dropped_steps == ref.dropped_steps == 1
    for name in GRAPH_FIELDS:
        assert np.array_equal(getattr(got, name).astype(np.float64), getattr(ref, name).astype(np.float64)), name
    outside = MatchWeb(rate=30.0, shape=(5, 2), paths_cells=[[0, 0], [1, 2]], paths_values=[0.1] * 2,
                       paths_offsets=[0, 2])
    with pytest.raises(ValueError, match="'y'.*outside its 5x2 grid"):
        walk_graph([("g", good), ("y", outside)])


def test_malformed_webs_are_refused_or_cut_not_walked_out_of_bounds() -> None:
    """A web whose cells lie outside its grid or whose junctions name missing cells is refused
    with a ValueError naming the web; steps that go back are dropped, not walked."""
    good = MatchWeb(rate=30.0, shape=(5, 5), paths_cells=[[0, 0], [1, 1], [2, 2]], paths_values=[0.1, 0.1, 0.1],
                    paths_offsets=[0, 3])
    outside = MatchWeb(rate=30.0, shape=(2, 2), paths_cells=[[0, 0], [1, 1], [2, 2]], paths_values=[0.1] * 3,
                       paths_offsets=[0, 3])
    with pytest.raises(ValueError, match="'x'.*outside its 2x2 grid"):
        walk_graph([("x", outside)])
    dangling = MatchWeb(rate=30.0, shape=(5, 5), paths_cells=good.paths_cells, paths_values=good.paths_values,
                        paths_offsets=[0, 3], bridges=[[0, 0, 0, 7]], bridges_cells=[[0, 0], [2, 2]],
                        bridges_values=[0.1, 0.1], bridges_offsets=[0, 2])
    with pytest.raises(ValueError, match="does not exist"):
        walk_graph([("x", dangling)])
    back = MatchWeb(rate=30.0, shape=(5, 5), paths_cells=[[0, 0], [2, 2], [1, 1], [3, 3]], paths_values=[0.1] * 4,
                    paths_offsets=[0, 4])
    g = walk_graph([("x", back)])
    assert g.dropped_steps == 1
    assert {(m.start, m.end) for m in walk_web(back, 0, 3, 1e30)} == set()  # the path is cut at the step back
    for a in range(4):
        for b in range(a, 4):
            for m in walk_web(back, a, b, 1e30):
                assert np.all(np.diff(m.cells.astype(np.int64), axis=0) >= 0)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(0, 1e3, width=32, allow_subnormal=False), min_size=1, max_size=60),
       st.one_of(st.sampled_from([0.0, 1.0, 0.5, 0.05, 1 / 3]), st.floats(0, 1)))
def test_a_quantile_of_sorted_values_is_numpys_of_them_all(values, q) -> None:
    """``quantile_of_sorted`` reads the two order statistics around q·(N − 1): the same float as
    ``np.quantile`` of all the values (numpy's linear rule), any size, any q in [0, 1]."""
    from motionweb.tasks.search import quantile_of_sorted

    v = np.sort(np.array(values, np.float32))
    assert quantile_of_sorted(v, q) == float(np.quantile(v, q))
    assert quantile_of_sorted(v, q) == float(np.quantile(v[::-1].copy(), q))
