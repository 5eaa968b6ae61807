"""Registration (KG04 §4.1, design §6): band kernels vs slow references, known warps recovered
through star and chain edges of a hand-built match graph, curves, common length, errors."""

from __future__ import annotations

import numpy as np
import pytest
from motionweb.store.demo.corpus import generate_clip
from motionweb.store.demo.perturb import pose_noise, random_warp, time_warp_clip
from motionweb.tasks.distance import distance_grid, distance_prepared, prepare_pair
from motionweb.tasks.features import FeatureParams, clip_features, point_weights
from motionweb.tasks.matchgraph import MatchEdge, MatchGraph, MatchNode, Segment
from motionweb.tasks.matchweb.band import optimal_path
from motionweb.tasks.matchweb.minima import local_minima, valid_region
from motionweb.tasks.matchweb.params import MatchWebParams
from motionweb.tasks.register import (
    Band,
    align_segments,
    band_alignment,
    band_valid_region,
    guide_path,
    monotone_knots,
    register,
)
from naive import ref_alignment_cost

CFG = MatchWebParams()
RATE = 30.0


# ---------------------------------------------------------------------------- slow references


def path_ok(path: np.ndarray, n: int, m: int, slope_k: int) -> bool:
    """Corner to corner, unit monotone steps, at most slope_k − 1 consecutive steps on one axis."""
    if tuple(path[0]) != (0, 0) or tuple(path[-1]) != (n - 1, m - 1):
        return False
    run, last = 0, None
    for d in map(tuple, np.diff(path, axis=0)):
        if d not in ((1, 0), (0, 1), (1, 1)):
            return False
        run = run + 1 if d == last and d != (1, 1) else (1 if d != (1, 1) else 0)
        last = d
        if run > slope_k - 1:
            return False
    return True


def random_monotone_path(n: int, m: int, rng: np.random.Generator) -> np.ndarray:
    i = j = 0
    cells = [(0, 0)]
    while (i, j) != (n - 1, m - 1):
        moves = [d for d in ((1, 0), (0, 1), (1, 1)) if i + d[0] < n and j + d[1] < m]
        di, dj = moves[rng.integers(len(moves))]
        i, j = i + di, j + dj
        cells.append((i, j))
    return np.array(cells)


def dense(band: Band, flat: np.ndarray) -> np.ndarray:
    g = np.full((band.n_rows, band.n_cols), np.inf)
    rc = band.cells()
    g[rc[:, 0], rc[:, 1]] = flat
    return g


# ---------------------------------------------------------------------------- band kernels


def test_guide_path_is_unit_step_and_joins_the_corners() -> None:
    cells = np.array([[-3, 1], [-2, 2], [0, 3], [1, 4], [2, 4], [3, 5], [9, 30]])
    path = guide_path(cells, 8, 10)
    assert path_ok(path, 8, 10, slope_k=100)
    assert {(0, 3), (1, 4), (2, 4), (3, 5)} <= set(map(tuple, path))
    assert np.array_equal(guide_path(np.zeros((0, 2)), 3, 5), [[0, 0], [1, 1], [1, 2], [2, 3], [2, 4]])


def test_band_valid_region_is_matchwebs_on_the_band() -> None:
    """On the rectangle the band valid region is matchweb.valid_region; on a band it is
    matchweb.valid_region of the grid with +inf outside the band (inf neighbours count as missing)."""
    rng = np.random.default_rng(0)
    for trial in range(40):
        n, m = rng.integers(4, 16, size=2)
        g = rng.uniform(0.5, 2.0, size=(n, m))
        g[g < 0.7] = np.inf if trial % 3 == 0 else 0.7
        band = Band.rectangle(n, m) if trial % 4 == 0 else Band.around(
            random_monotone_path(n, m, rng), n, m, int(rng.integers(0, 4)))
        rc = band.cells()
        flat = g[rc[:, 0], rc[:, 1]]
        padded = dense(band, flat)
        expect = valid_region(padded, local_minima(padded), 0.15)
        got = band_valid_region(band, flat, 0.15)
        assert np.array_equal(got, expect[rc[:, 0], rc[:, 1]]), trial
        assert not expect[~np.isfinite(padded)].any()


@pytest.mark.parametrize("slope_k", [1, 2, 3])
def test_band_dp_equals_the_dense_reference(slope_k: int) -> None:
    rng = np.random.default_rng(slope_k)
    feasible = 0
    for trial in range(40):
        n, m = rng.integers(2, 12, size=2)
        m = n if slope_k == 1 else m  # slope 1: diagonal paths only
        g = rng.uniform(0.0, 1.0, size=(n, m))
        band = Band.around(random_monotone_path(n, m, rng), n, m, int(rng.integers(0, 4)))
        rc = band.cells()
        flat = g[rc[:, 0], rc[:, 1]]
        if trial % 2:  # restrict to the valid region as registration does, corners allowed
            valid = band_valid_region(band, flat, 0.15)
            valid[0] = valid[-1] = True
            flat = np.where(valid, flat, np.inf)
        ref = ref_alignment_cost(dense(band, flat), slope_k)
        path = band_alignment(band, flat, slope_k)
        if not np.isfinite(ref):
            assert path is None, trial
            continue
        feasible += 1
        assert path is not None and path_ok(path, n, m, slope_k), trial
        assert np.isclose(dense(band, flat)[path[:, 0], path[:, 1]].sum(), ref, rtol=1e-12), trial
    assert feasible >= 8


def test_monotone_knots_collapse_runs_and_keep_the_corners() -> None:
    cells = np.array([[10, 20], [10, 21], [11, 22], [12, 22], [13, 22], [14, 23], [14, 24]])
    k = monotone_knots(cells)
    assert np.all(np.diff(k, axis=0) > 0)
    assert np.array_equal(k[0], [10, 20]) and np.array_equal(k[-1], [14, 24])
    with pytest.raises(ValueError, match="two frames"):
        monotone_knots(np.array([[3, 4], [3, 5]]))


def test_alignment_outside_the_valid_region_falls_back_on_the_slope_rule() -> None:
    """Unrelated random clouds with a = 0 (valid region = the scattered 1-D minima): no slope-ruled
    path stays in it, so the edge keeps the slope rule only, flagged, and its path is the
    unrestricted optimum."""
    rng = np.random.default_rng(5)
    w = np.full(12, 1 / 12)
    pa, pb = prepare_pair(rng.normal(size=(30, 12, 3)), rng.normal(size=(36, 12, 3)), w, np.float64)
    sa, sb = Segment("a", 0, 29), Segment("b", 0, 35)
    al = align_segments(pa, pb, sa, sb, np.zeros((0, 2)), CFG.model_copy(update={"valid_a": 0.0}), radius=None)
    assert not al.in_valid_region
    g = distance_prepared(pa, pb, slice(0, 30), slice(0, 36))
    assert path_ok(al.cells, 30, 36, CFG.slope_k)
    assert np.isclose(al.cost * len(al.cells), ref_alignment_cost(g, CFG.slope_k), rtol=1e-9)


# ---------------------------------------------------------------------------- known warps


#: 60 Hz frame counts of the warped copies (odd: their 30 Hz frames are exact 60 Hz frames)
COPY_FRAMES = (241, 301, 271, 221)
#: query segment (30 Hz frames of the base clip)
QUERY = (4, 130)


@pytest.fixture(scope="module")
def planted():
    """A demo walk (the query) and 4 noisy copies under known random warps, as a match graph:
    chain 0 → 1 → 2 (the edge 1-2 stored reversed), star 0 → 3, 0 → 4, and two edges off the
    shortest-path tree (0-2, 3-4). Edge cells: the unrestricted optimal path on the segment grid,
    for 0-3 shifted by 3 columns (a merged node's web path need not meet its corners)."""
    rng = np.random.default_rng(11)
    base, _ = generate_clip("walk", 0, 7, 60.0)
    fc = FeatureParams()
    feats = {"walk": clip_features(base, RATE, fc)}
    truth = {}
    for c, n_out in enumerate(COPY_FRAMES, start=1):
        warp = random_warp(n_out, base.n_frames, rng)
        feats[f"copy{c}"] = clip_features(pose_noise(time_warp_clip(base, warp), rng), RATE, fc)
        # copy frame at 30 Hz showing base 30 Hz frame u: w⁻¹(2u) / 2 (60 Hz frames of both)
        truth[f"copy{c}"] = lambda u, w=warp: np.interp(2.0 * np.asarray(u, float), w, np.arange(len(w))) / 2.0
    w = point_weights(base.skeleton, fc)
    q0, q1 = QUERY
    nodes = [MatchNode(Segment("walk", q0, q1))]
    for c in range(1, len(COPY_FRAMES) + 1):
        a, b = truth[f"copy{c}"]([q0, q1])
        nodes.append(MatchNode(Segment(f"copy{c}", round(a), round(b)), tier=1, cost=1.0))

    def cells(u: int, v: int) -> np.ndarray:
        su, sv = nodes[u].segment, nodes[v].segment
        g = distance_grid(feats[su.clip][su.start:su.end + 1], feats[sv.clip][sv.start:sv.end + 1], w)
        return optimal_path(g, (0, 0), (su.n_frames - 1, sv.n_frames - 1), CFG.slope_k) + [su.start, sv.start]

    c03 = cells(0, 3) + [0, 3]
    edges = [MatchEdge(0, 1, 1.0, cells(0, 1)), MatchEdge(2, 1, 1.0, cells(1, 2)[:, ::-1]),
             MatchEdge(0, 2, 5.0, cells(0, 2)), MatchEdge(0, 3, 1.0, c03[c03[:, 1] <= nodes[3].segment.end]),
             MatchEdge(0, 4, 1.5, cells(0, 4)), MatchEdge(3, 4, 3.0, cells(3, 4))]
    graph = MatchGraph(RATE, nodes, edges)
    return graph, feats, w, truth


def test_registration_recovers_known_warps(planted) -> None:
    graph, feats, w, truth = planted
    reg = register(graph, feats, w, CFG)
    assert reg.nodes[0] == 0 and sorted(reg.nodes) == [0, 1, 2, 3, 4]
    tree = {(graph.nodes[reg.nodes[p]].segment.clip, s.clip) for p, s in zip(reg.parents[1:], reg.segments[1:],
                                                                           strict=True)}
    assert tree == {("walk", "copy1"), ("copy1", "copy2"), ("walk", "copy3"), ("walk", "copy4")}
    assert sorted(e.edge for e in reg.edges) == [0, 1, 3, 4]
    assert np.allclose(reg.distances, [{0: 0.0, 1: 1.0, 2: 2.0, 3: 1.0, 4: 1.5}[k] for k in reg.nodes])
    assert all(e.alignment.in_valid_region for e in reg.edges)
    u = reg.u
    assert np.array_equal(reg.frames[:, 0], u)
    for c in range(1, 5):
        clip = reg.segments[c].clip
        err = reg.frames[:, c] - truth[clip](u)
        rms = float(np.sqrt(np.mean(err ** 2)))
        assert rms <= 1.5, (clip, rms)
        assert np.abs(err).max() <= 4.0, clip
    # the band holds far fewer cells than the segment rectangles
    for e in reg.edges:
        sp, sc = graph.nodes[e.parent].segment, graph.nodes[e.child].segment
        assert e.alignment.n_cells < 0.5 * sp.n_frames * sc.n_frames


def test_band_and_dense_registrations_agree(planted) -> None:
    graph, feats, w, _ = planted
    banded, full = register(graph, feats, w, CFG), register(graph, feats, w, CFG, band_s=None)
    assert banded.nodes == full.nodes
    for a, b in zip(banded.edges, full.edges, strict=True):
        assert a.alignment.n_cells < b.alignment.n_cells / 3
        if a.edge == 3:  # guide shifted by 3 frames: the band's optimum is near the dense one
            assert a.alignment.cost <= 1.01 * b.alignment.cost
        else:  # guide = the dense optimum without the valid region: the band holds the optimum
            assert np.array_equal(a.alignment.cells, b.alignment.cells)
    assert np.abs(banded.frames - full.frames).max() <= 1.0


def test_edge_curves_increase_strictly_and_interpolate_endpoints(planted) -> None:
    graph, feats, w, _ = planted
    reg = register(graph, feats, w, CFG)
    for e in reg.edges:
        sp, sc = graph.nodes[e.parent].segment, graph.nodes[e.child].segment
        x = np.linspace(sp.start, sp.end, 20 * sp.n_frames)
        y = e(x)
        assert np.all(np.diff(y) > 0)
        assert y[0] == sc.start and np.isclose(y[-1], sc.end, atol=1e-9)
        assert np.array_equal(e.alignment.cells[0], [sp.start, sc.start])
        assert np.array_equal(e.alignment.cells[-1], [sp.end, sc.end])
    assert np.all(np.diff(reg.frames, axis=0) > 0)


def test_common_length_resampling(planted) -> None:
    graph, feats, w, _ = planted
    reg = register(graph, feats, w, CFG)
    starts = [s.start for s in reg.segments]
    ends = [s.end for s in reg.segments]
    for length in (50, 127, 400):
        r = reg.resample(length)
        assert r.shape == (length, 5)
        assert np.all(np.diff(r, axis=0) > 0)
        assert np.allclose(r[0], starts, atol=1e-9) and np.allclose(r[-1], ends, atol=1e-9)
    assert np.allclose(reg.resample(), reg.frames)
    assert np.allclose(reg.warp(reg.u[3:6]), reg.frames[3:6])
    with pytest.raises(ValueError, match="query's frames"):
        reg.warp([QUERY[1] + 1])


# ---------------------------------------------------------------------------- errors


def test_errors_name_the_node_and_clip(planted) -> None:
    graph, feats, w, _ = planted
    lonely = MatchGraph(RATE, graph.nodes + [MatchNode(Segment("copy1", 0, 30))], graph.edges)
    with pytest.raises(ValueError, match=r"node 5 \(clip 'copy1', frames 0..30\) is not connected"):
        register(lonely, feats, w, CFG)
    with pytest.raises(ValueError, match=r"no features for clip 'copy3' \(node 3\)"):
        register(graph, {k: v for k, v in feats.items() if k != "copy3"}, w, CFG)
    far = MatchGraph(RATE, graph.nodes[:1] + [MatchNode(Segment("copy1", 100, 900))], [MatchEdge(0, 1, 1.0)])
    with pytest.raises(ValueError, match="node 1: frames 100..900 of clip 'copy1' outside"):
        register(far, feats, w, CFG)
    steep = MatchGraph(RATE, graph.nodes[:1] + [MatchNode(Segment("copy1", 0, 30))], [MatchEdge(1, 0, 1.0)])
    with pytest.raises(ValueError, match=r"edge 0 \(node 0 -> node 1\): no slope-ruled time alignment"):
        register(steep, feats, w, CFG)  # 127 query frames onto 31: slope above k = 3
    bad = MatchGraph(RATE, graph.nodes[:2], [MatchEdge(0, 1, -1.0)])
    with pytest.raises(ValueError, match="edge 0"):
        register(bad, feats, w, CFG)
    with pytest.raises(ValueError, match="no nodes"):
        register(MatchGraph(RATE), feats, w, CFG)
