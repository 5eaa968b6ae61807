"""Property-based tests of the compiled kernels that write into buffers sized in advance (issue 22).

Each kernel runs against its slow reference in tests/naive.py over random sizes, the extremes
included: empty inputs, one frame, very unequal sizes, thresholds 0 and huge, bands and windows
of 0 and of the whole grid, NaN and inf values. Run them with ``NUMBA_BOUNDSCHECK=1`` (and a
``NUMBA_CACHE_DIR`` of their own) so that any write or read out of bounds raises IndexError.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from motionweb.tasks.blend import ease_offsets, leg_ik
from motionweb.tasks.distance import _cells_kernel, distance_cells, prepare_pair
from motionweb.tasks.guided_warp.features import knn_mean_distance
from motionweb.tasks.guided_warp.paths import dag_path, fixed_length_path
from motionweb.tasks.matchweb.band import _band_dp_any, band_buffers, band_dp, optimal_path
from motionweb.tasks.matchweb.bridges import find_bridges
from motionweb.tasks.matchweb.minima import find_chains, local_minima, valid_region
from motionweb.tasks.matchweb.params import max_run
from motionweb.tasks.matchweb.refine import (
    AVERAGE,
    TILE,
    TOTAL,
    _crop_to_ends,
    _dp_buffers,
    _eval_band,
    _path_cells_near,
    _position,
    _solve,
    upsample_band,
)
from motionweb.tasks.register import Band, band_alignment, band_valid_region
from motionweb.tasks.retime.objective import _evaluate_kernel
from motionweb.tasks.retime.reachable import _clip, fastest_timing, interval_polygons, padded, set_interval
from motionweb.tasks.retime.simplex import OPTIMAL, DenseLP
from naive import (
    brute_force,
    numpy_ease_offsets,
    numpy_leg_ik,
    polygons_of,
    ref_alignment_cost,
    ref_band_dp,
    ref_bridges,
    ref_chains,
    ref_minima,
    ref_path_cells_near,
    ref_position,
    ref_upsample_band,
    ref_valid,
    slope_ok,
    slow_grid,
)

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def grids(max_rows: int = 7, max_cols: int = 7, min_side: int = 0, specials: bool = True):
    """Small float grids of any shape (empty and one-row ones included), some cells inf (the
    ignored band) and, with ``specials``, NaN."""
    values = st.floats(0.0, 4.0, width=32) | st.just(np.inf)
    if specials:
        values = values | st.just(np.nan)
    shape = st.tuples(st.integers(min_side, max_rows), st.integers(min_side, max_cols))
    return hnp.arrays(np.float32, shape, elements=values)


# ------------------------------------------------------------------------------------ match webs
@SETTINGS
@given(grids())
def test_local_minima_match_the_reference(g: np.ndarray) -> None:
    np.testing.assert_array_equal(local_minima(g), ref_minima(g))


@SETTINGS
@given(grids(), st.sampled_from([0.0, 0.15, 1.0, 1e30]))
def test_valid_region_matches_the_reference(g: np.ndarray, a: float) -> None:
    m = local_minima(g)
    np.testing.assert_array_equal(valid_region(g, m, a), ref_valid(g, m, a))


def test_valid_region_and_chains_refuse_minima_of_another_shape() -> None:
    g = np.zeros((3, 4), np.float32)
    with pytest.raises(ValueError, match="shape"):
        valid_region(g, np.zeros((4, 3), np.uint8), 0.1)
    with pytest.raises(ValueError, match="shape"):
        find_chains(g, np.zeros((2, 4), np.uint8), 3, 1)


@SETTINGS
@given(grids(specials=False), st.integers(1, 4), st.integers(0, 8))
def test_chains_match_the_reference(g: np.ndarray, k: int, min_extent: int) -> None:
    m = local_minima(g)
    cells, offsets = find_chains(g, m, k, min_extent)
    want = ref_chains(g, m, k, min_extent)
    got = [[tuple(c) for c in cells[a:b].tolist()] for a, b in itertools.pairwise(offsets)]
    assert got == want
    assert offsets[0] == 0 and offsets[-1] == len(cells) <= int((m != 0).sum())


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(grids(6, 6, specials=False), st.integers(0, 6), st.sampled_from([0.0, 0.3, 1e30]))
def test_bridges_match_the_reference(g: np.ndarray, L: int, a: float) -> None:
    """Every (C, C') pair the slow enumeration finds, with its least average, and no other; bridge
    cells stay in the grid and keep the slope rule and the length bound."""
    m = local_minima(g)
    valid = valid_region(g, m, a)
    cells, offs = find_chains(g, m, 3, 1)
    br, bc, bo = find_bridges(g, valid, cells, offs, 3, L)
    want = ref_bridges(g.astype(np.float64), valid, cells, offs, L)
    got = {}
    for b in range(len(br)):
        path = bc[bo[b]:bo[b + 1]]
        assert slope_ok(path, 3)
        assert path[-1].sum() - path[0].sum() < max(L, 1)
        got[(int(br[b, 0]), int(br[b, 2]))] = float(g[path[:, 0], path[:, 1]].astype(np.float64).mean())
    assert got.keys() == want.keys()
    for key, v in want.items():
        assert got[key] == pytest.approx(v, rel=1e-5, abs=1e-6)


def test_bridges_refuse_bad_inputs() -> None:
    g = np.zeros((3, 3), np.float32)
    with pytest.raises(ValueError, match="length bound"):
        find_bridges(g, np.ones((3, 3), bool), np.zeros((0, 2)), np.zeros(1), 3, -1)
    with pytest.raises(ValueError, match="valid region"):
        find_bridges(g, np.ones((2, 3), bool), np.zeros((0, 2)), np.zeros(1), 3, 2)
    with pytest.raises(ValueError, match="inside the grid"):
        find_bridges(g, np.ones((3, 3), bool), np.array([[0, 5]]), np.array([0, 1]), 3, 2)


@SETTINGS
@given(grids(6, 6, min_side=1, specials=False), st.integers(1, 5))
def test_band_dp_matches_the_reference(g: np.ndarray, k: int) -> None:
    """The slope-ruled least total cost through the whole grid, on the rectangle (optimal_path)
    and on the same rectangle as a band (registration's band_alignment)."""
    want = ref_alignment_cost(g.astype(np.float64), k)
    n, m = g.shape
    for path in (optimal_path(g, (0, 0), (n - 1, m - 1), k),
                 band_alignment(Band.rectangle(n, m), g.reshape(-1).astype(np.float64), k)):
        if not np.isfinite(want):
            assert path is None
            continue
        assert path is not None and slope_ok(path, k)
        assert tuple(path[0]) == (0, 0) and tuple(path[-1]) == (n - 1, m - 1)
        assert float(g[path[:, 0], path[:, 1]].astype(np.float64).sum()) == pytest.approx(want, rel=1e-6)


def random_band(rows: list[tuple[int, int]], rng: np.random.Generator
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(lo, hi, off, values) of a band whose rows start ``step`` right of the previous one and are
    ``width`` + 1 wide (−1: empty), for (step, width) in ``rows``; values 0-3 (ties), some inf
    and NaN (blocked)."""
    lo = np.cumsum([step for step, _ in rows]).astype(np.int64)
    hi = lo + np.array([width for _, width in rows], np.int64)
    off = np.zeros(len(rows) + 1, np.int64)
    off[1:] = np.cumsum(np.maximum(hi - lo + 1, 0))
    n = int(off[-1])
    vals = rng.integers(0, 4, n).astype(np.float64)
    vals[rng.random(n) < 0.1] = np.inf
    vals[rng.random(n) < 0.05] = np.nan
    return lo, hi, off, vals


@SETTINGS
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(-1, 6)), min_size=0, max_size=12), st.integers(0, 4),
       st.integers(0, 2**32 - 1))
def test_band_dp_equals_the_transition_by_transition_reference(rows, mrun: int, seed: int) -> None:
    """Every (cell, state) of band_dp — cost, length and predecessor — on random bands (empty rows,
    one-cell rows, rows that jump right), with ties (costs 0-3 only), blocked cells (inf, NaN,
    flag 1), terminal cells (flag 2) and sources anywhere: the exact values the reference gives,
    so ties resolve to the same path."""
    rng = np.random.default_rng(seed)
    lo, hi, off, vals = random_band(rows, rng)
    n = len(vals)
    init = np.where(rng.random(n) < 0.3, vals, np.inf)
    flags = rng.choice(np.array([0, 0, 0, 1, 2], np.uint8), n)
    got = band_buffers(n, mrun)
    band_dp(lo, hi, off, vals, init, flags, mrun, *got)
    for g, w in zip(got, ref_band_dp(lo, hi, off, vals, init, flags, mrun), strict=True):
        np.testing.assert_array_equal(g, w)


@SETTINGS
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(-1, 40)), min_size=0, max_size=40), st.integers(0, 2**32 - 1))
def test_the_unrolled_kernel_of_slope_k_3_is_the_loop_kernel(rows, seed: int) -> None:
    """slope_k = 3 (mrun 2, the default) runs band_dp's unrolled kernel: the same costs, lengths
    and predecessors as the kernel with the states in loops, on wider random bands than the
    reference can walk (ties, blocked, terminal cells and sources anywhere)."""
    rng = np.random.default_rng(seed)
    lo, hi, off, vals = random_band(rows, rng)
    n = len(vals)
    init = np.where(rng.random(n) < 0.1, vals, np.inf)
    flags = rng.choice(np.array([0] * 12 + [1, 2], np.uint8), n)
    got, want = band_buffers(n, 2), band_buffers(n, 2)
    band_dp(lo, hi, off, vals, init, flags, 2, *got)
    _band_dp_any(lo, hi, off, vals, init, flags, 2, *want)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)


@pytest.mark.parametrize("mrun", [1, 2, 3])
def test_band_dp_refuses_buffers_too_small(mrun: int) -> None:
    lo, hi, off = np.array([0, 0]), np.array([3, 3]), np.array([0, 4, 8])
    vals, init, flags = np.ones(8), np.full(8, np.inf), np.zeros(8, np.uint8)
    with pytest.raises(ValueError, match="narrower"):
        band_dp(lo, hi, off, vals, init, flags, mrun, *band_buffers(8, mrun - 1))
    with pytest.raises(ValueError, match="shorter"):
        band_dp(lo, hi, off, vals, init, flags, mrun, *band_buffers(7, mrun))


@pytest.mark.parametrize("k", [0, 65, 1000])
def test_slope_k_beyond_the_int8_states_is_refused(k: int) -> None:
    with pytest.raises(ValueError, match="slope_k"):
        max_run(k)


def test_the_largest_slope_k_runs() -> None:
    g = np.ones((3, 70), np.float32)
    path = optimal_path(g, (0, 0), (2, 69), 64)
    assert path is not None and slope_ok(path, 64)


@SETTINGS
@given(grids(6, 6, specials=False), st.sampled_from([0.0, 0.15, 1e30]))
def test_band_valid_region_on_the_rectangle_is_the_grid_rule(g: np.ndarray, a: float) -> None:
    n, m = g.shape
    got = band_valid_region(Band.rectangle(n, m), g.reshape(-1).astype(np.float64), a)
    np.testing.assert_array_equal(got.reshape(n, m), ref_valid(g, ref_minima(g), a))


cell_lists = hnp.arrays(np.int64, st.tuples(st.integers(1, 6), st.just(2)), elements=st.integers(-3, 12))


@SETTINGS
@given(cell_lists, st.sampled_from([1.0, 1.5, 3.0]), st.sampled_from([0.5, 1.5, 4.0]), st.integers(1, 20),
       st.integers(1, 20))
def test_upsample_band_matches_the_reference(cells: np.ndarray, s: float, h: float, fa: int, fb: int) -> None:
    """Any cells (disconnected, outside the grid): the band is the reference's rows, every flat
    index lies below off[-1] and off never decreases."""
    row0, lo, hi, off = upsample_band(cells, s, h, fa, fb)
    want = ref_upsample_band(cells, s, h, fa, fb)
    got = {row0 + t: (int(lo[t]), int(hi[t])) for t in range(len(lo)) if lo[t] <= hi[t]}
    assert got == want
    assert len(off) == len(lo) + 1 and off[0] == 0 and np.all(np.diff(off) >= 0)
    assert off[-1] == sum(b - a + 1 for a, b in want.values())
    assert np.all((lo > hi) | ((lo >= 0) & (hi < fb)))


def monotone_path(rng: np.random.Generator, n: int, mrun: int) -> np.ndarray:
    """(n, 2) cells of a random slope-ruled path (up, right, diagonal; at most ``mrun`` steps in a
    row along one axis), as band_backtrack returns refined chains."""
    cells = [(int(rng.integers(0, 5)), int(rng.integers(0, 5)))]
    run = 0  # > 0: up steps in a row, < 0: right steps in a row
    while len(cells) < n:
        i, j = cells[-1]
        move = int(rng.integers(0, 3))
        if move == 1 and max(run, 0) < mrun:
            cells.append((i + 1, j))
            run = max(run, 0) + 1
        elif move == 2 and max(-run, 0) < mrun:
            cells.append((i, j + 1))
            run = min(run, 0) - 1
        else:
            cells.append((i + 1, j + 1))
            run = 0
    return np.array(cells[:n], np.int64).reshape(-1, 2)


@SETTINGS
@given(st.integers(0, 40), st.integers(0, 3), st.integers(0, 4), st.sampled_from([1.0, 2.4, 3.0]),
       st.integers(0, 2**32 - 1))
def test_path_lookups_match_a_scan_of_the_path(n: int, mrun: int, radius: int, s: float, seed: int) -> None:
    """_path_cells_near and _position bisect the path's monotone rows: the same cells, in the same
    order, as scans of the whole path, for centres on, near and off the path (empty paths, one
    cell, rows of several cells, non-integer centres)."""
    rng = np.random.default_rng(seed)
    path = monotone_path(rng, n, mrun)
    row0, lo, hi, off = upsample_band(path // 2 if n else np.zeros((1, 2), np.int64), 2.0, 1.5, 60, 60)
    centres = [(float(i), float(j)) for i, j in path[:: max(1, n // 4)].tolist()]
    centres += [(float(rng.integers(-3, 30)) * s / 2, float(rng.integers(-3, 30)) * s / 2) for _ in range(4)]
    for ci, cj in centres:
        got = _path_cells_near(row0, lo, hi, off, path, ci, cj, radius).tolist()
        assert got == ref_path_cells_near(row0, lo, hi, off, path, ci, cj, radius)
    probes = path.tolist() + rng.integers(-2, 30, (6, 2)).tolist()
    for i, j in probes:
        assert _position(path, i, j) == ref_position(path, i, j)


@SETTINGS
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(-1, 6)), min_size=1, max_size=14), st.integers(0, 3),
       st.booleans(), st.integers(0, 2**32 - 1))
def test_a_band_cropped_to_its_ends_solves_to_the_same_path(rows, mrun: int, by_average: bool, seed: int) -> None:
    """_solve on the band cropped by _crop_to_ends (the slope-ruled cones of the sources and the
    targets within the rectangle they span) returns the same path as on the whole band: random bands (empty rows, rows
    that jump right), tied costs (0-3), blocked cells (inf, NaN), sources and targets anywhere,
    in any order, overlapping or not reachable."""
    rng = np.random.default_rng(seed)
    lo, hi, off, vals = random_band(rows, rng)
    n = len(vals)
    if n == 0:
        return
    row0 = int(rng.integers(0, 5))
    rank = AVERAGE if by_average else TOTAL
    src = rng.permutation(n)[:int(rng.integers(1, min(n, 6) + 1))].astype(np.int64)
    dst = rng.permutation(n)[:int(rng.integers(1, min(n, 6) + 1))].astype(np.int64)
    want = _solve(row0, lo, hi, off, vals, src, dst, mrun, rank, _dp_buffers(n, mrun))
    cell = {(row0 + t, j): off[t] + j - lo[t] for t in range(len(lo)) for j in range(lo[t], hi[t] + 1)}
    crow0, clo, chi, coff, csrc, cdst = _crop_to_ends(row0, lo, hi, off, src, dst, mrun)
    cvals = np.full(int(coff[-1]), -1.0)
    for t in range(len(clo)):
        for j in range(clo[t], chi[t] + 1):
            cvals[coff[t] + j - clo[t]] = vals[cell[(crow0 + t, j)]]
    assert not np.any(cvals == -1.0) and coff[-1] <= n
    if len(csrc) == 0 or len(cdst) == 0:
        assert len(want) == 0
        return
    got = _solve(crow0, clo, chi, coff, cvals, csrc, cdst, mrun, rank, _dp_buffers(int(coff[-1]) + 3, mrun))
    np.testing.assert_array_equal(got, want)


def test_solve_refuses_scratch_smaller_than_its_band() -> None:
    lo, hi, off = np.array([0, 0]), np.array([2, 2]), np.array([0, 3, 6])
    with pytest.raises(ValueError, match="scratch"):
        _solve(0, lo, hi, off, np.ones(6), np.array([0]), np.array([5]), 1, TOTAL, _dp_buffers(5, 1))


# ------------------------------------------------------------------------------------ distances
@SETTINGS
@given(st.integers(1, 5), st.integers(1, 9), st.integers(0, 12), st.randoms(use_true_random=False))
def test_distance_cells_match_the_slow_grid(fa: int, fb: int, n: int, rnd) -> None:
    rng = np.random.default_rng(rnd.randint(0, 2**31))
    a, b = rng.normal(size=(fa, 4, 3)), rng.normal(size=(fb, 4, 3))
    w = rng.uniform(0.5, 1.5, 4)
    rows, cols = rng.integers(0, fa, n), rng.integers(0, fb, n)
    got = distance_cells(*prepare_pair(a, b, w, np.float64), rows, cols)
    np.testing.assert_allclose(got, slow_grid(a, b, w)[rows, cols], atol=1e-9)


@SETTINGS
@given(st.integers(1, 3 * TILE), st.integers(1, 3 * TILE), st.integers(1, 19), st.integers(-1, 6), st.data())
def test_band_values_are_the_cell_distances_outside_the_self_band(fa: int, fb: int, p: int, band: int, data) -> None:
    """refine._eval_band (runs of cells not evaluated yet, one tasks.distance.distance_row call
    each, the self band's cells inf) gives the bytes of the per-cell kernel, with some cells already
    in the tiles (an overlapping band evaluated them) and again from the filled tiles."""
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31), label="seed"))
    a = (rng.normal(size=(fa, p, 3)) * rng.uniform(1e-3, 10, (fa, p, 1))).astype(np.float32)
    b = rng.normal(size=(fb, p, 3)).astype(np.float32)
    pa, pb = prepare_pair(a, b, rng.uniform(0.5, 1.5, p))
    row0 = int(rng.integers(0, fa))
    nr = int(rng.integers(1, fa - row0 + 1))
    lo = rng.integers(0, fb, nr)
    hi = np.minimum(fb - 1, lo + rng.integers(-1, fb, nr))  # hi < lo: an empty row
    off = np.concatenate([[0], np.cumsum(np.maximum(0, hi - lo + 1))])
    index = np.arange(-(-fa // TILE) * -(-fb // TILE)).reshape(-(-fa // TILE), -(-fb // TILE))
    pool = np.full((index.size, TILE, TILE), np.nan)
    rows = np.repeat(np.arange(row0, row0 + nr), np.maximum(0, hi - lo + 1))
    cols = np.concatenate([np.arange(lo[t], hi[t] + 1) for t in range(nr)] + [np.zeros(0, np.int64)])
    want = np.empty(len(rows))  # one cell_distance call per cell
    _cells_kernel(pa.left, pa.left_y, pa.norms, pb.right, pb.right_y, pb.norms, rows.astype(np.int64),
                  cols.astype(np.int64), want)
    if band >= 0:
        want[np.abs(rows - cols) <= band] = np.inf
    for k in np.flatnonzero(rng.uniform(size=len(rows)) < 0.3):  # already evaluated by another band
        pool[index[rows[k] // TILE, cols[k] // TILE], rows[k] % TILE, cols[k] % TILE] = want[k]
    args = (row0, lo, hi, off, index, pool, pa.left, pa.left_y, pa.norms, pb.right, pb.right_y, pb.norms, band)
    for _ in range(2):
        out = np.full(off[-1], -1.0)
        _eval_band(*args, out)
        assert out.tobytes() == want.tobytes()


def test_distance_cells_refuse_cells_off_the_grid() -> None:
    pa, pb = prepare_pair(np.zeros((2, 3, 3)), np.zeros((3, 3, 3)), np.ones(3))
    with pytest.raises(ValueError, match="grid"):
        distance_cells(pa, pb, np.array([0, 2]), np.array([0, 0]))
    with pytest.raises(ValueError, match="one length"):
        distance_cells(pa, pb, np.array([0, 1]), np.array([0]))


# ------------------------------------------------------------------------------------ guided warp
@settings(max_examples=30, deadline=None)
@given(st.integers(2, 7), st.integers(1, 3), st.data())
def test_warp_paths_match_brute_force(n: int, s: int, data) -> None:
    table = data.draw(hnp.arrays(np.float64, (n, s, s), elements=st.floats(0, 5) | st.just(np.inf)))
    m = data.draw(st.integers(2, n))
    cost, _ = brute_force(table, m)
    try:
        got_path, got = fixed_length_path(table, m)
    except ValueError as e:  # the step limits admit no path of m frames at all
        assert "no warp" in str(e) and not np.isfinite(cost)
        got_path, got = np.zeros(0, np.int64), np.inf
    assert got == pytest.approx(cost) if np.isfinite(cost) else not np.isfinite(got)
    if np.isfinite(got) and m > 2:
        assert len(got_path) == m and got_path[0] == 0 and got_path[-1] == n - 1
    cost, _ = brute_force(table, None)
    _, got = dag_path(table)
    assert got == pytest.approx(cost) if np.isfinite(cost) else not np.isfinite(got)


def test_warp_paths_refuse_what_int8_or_the_windows_cannot_hold() -> None:
    with pytest.raises(ValueError, match="skip"):
        dag_path(np.zeros((4, 128, 128)))
    with pytest.raises(ValueError, match="skip"):
        fixed_length_path(np.zeros((4, 128, 128)), 3)
    table = np.zeros((4, 2, 2))
    with pytest.raises(ValueError, match="one bound per output frame"):
        fixed_length_path(table, 3, np.array([0, 1, 3, 3]), np.array([0, 2, 3, 3]))
    with pytest.raises(ValueError, match="frames 0..3"):
        fixed_length_path(table, 3, np.array([0, 1, 3]), np.array([0, 9, 3]))


@SETTINGS
@given(st.integers(0, 6), st.integers(1, 6), st.integers(1, 8), st.integers(1, 4), st.randoms(use_true_random=False))
def test_knn_mean_matches_brute_force(n: int, r: int, k: int, d: int, rnd) -> None:
    rng = np.random.default_rng(rnd.randint(0, 2**31))
    q, z = rng.normal(size=(n, d)), rng.normal(size=(r, d))
    dist = np.sqrt(((q[:, None] - z[None]) ** 2).sum(-1))
    want = np.sort(dist, axis=1)[:, :min(k, r)].mean(axis=1) if n else np.zeros(0)
    np.testing.assert_allclose(knn_mean_distance(q, z, k, batch_cells=3), want, atol=1e-6)


# ------------------------------------------------------------------------------------ blend
@SETTINGS
@given(st.integers(0, 12), st.integers(-1, 30), st.data())
def test_ease_offsets_match_numpy(n: int, ramp: int, data) -> None:
    plants = data.draw(hnp.arrays(np.bool_, n))
    ankles = data.draw(hnp.arrays(np.float64, (n, 3), elements=st.floats(-2, 2)))
    if ramp < 0:
        ramp = 10**6  # ramps far past the clip's ends
    got, mask = ease_offsets(n, plants, ankles, ramp)
    want, wmask = numpy_ease_offsets(n, plants, ankles, ramp)
    np.testing.assert_allclose(got, want, atol=1e-12)
    np.testing.assert_array_equal(mask, wmask)


def test_ease_offsets_refuse_mismatched_lengths() -> None:
    with pytest.raises(ValueError, match="plant flags"):
        ease_offsets(3, np.ones(5, bool), np.zeros((5, 3)), 2)


@SETTINGS
@given(st.integers(0, 5), st.randoms(use_true_random=False))
def test_leg_ik_matches_numpy(f: int, rnd) -> None:
    rng = np.random.default_rng(rnd.randint(0, 2**31))
    j = 5
    parents = np.array([-1, 0, 1, 2, 3])
    gpos = np.zeros((f, j, 3))
    gpos[:, 1] = rng.normal(size=(f, 3))
    gpos[:, 2] = gpos[:, 1] + [0, -0.45, 0.05] + 0.05 * rng.normal(size=(f, 3))
    gpos[:, 3] = gpos[:, 2] + [0, -0.42, -0.05] + 0.05 * rng.normal(size=(f, 3))
    grot = rng.normal(size=(f, j, 4))
    grot /= np.linalg.norm(grot, axis=-1, keepdims=True)
    target = gpos[:, 3] + 0.2 * rng.normal(size=(f, 3))
    fallback = np.tile([1.0, 0.0, 0.0], (f, 1))
    got = leg_ik(gpos, grot, parents, (1, 2, 3), target, fallback)
    want = numpy_leg_ik(gpos, grot, parents, (1, 2, 3), target, fallback)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)


def test_leg_ik_refuses_short_targets_and_foreign_joints() -> None:
    gpos, grot = np.zeros((3, 4, 3)), np.zeros((3, 4, 4))
    with pytest.raises(ValueError, match="target"):
        leg_ik(gpos, grot, np.array([-1, 0, 1, 2]), (1, 2, 3), np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="chain of joints"):
        leg_ik(gpos, grot, np.array([-1, 0, 1, 2]), (1, 2, 9), np.zeros((3, 3)), np.zeros((3, 3)))


# ------------------------------------------------------------------------------------ retiming
def _polygon(rng: np.random.Generator, kind: int) -> np.ndarray:
    """A random counter-clockwise convex polygon (kind 0), a segment (1), a point (2), a thin sliver of
    nearly collinear vertices (3) or nothing (4)."""
    if kind == 4:
        return np.zeros((0, 2))
    if kind == 2:
        return rng.uniform([-5, 0], [5, 5], (1, 2))
    if kind == 1:
        return np.sort(rng.uniform([-5, 0], [5, 5], (2, 2)), axis=0)
    k = int(rng.integers(3, 9))
    ang = np.sort(rng.uniform(0, 2 * np.pi, k))
    r = np.array([4.0, 1e-9 if kind == 3 else 2.0])
    return np.array([1.0, 3.0]) + np.stack([np.cos(ang), np.sin(ang)], 1) * r


@SETTINGS
@given(st.lists(st.integers(0, 4), min_size=0, max_size=6), st.randoms(use_true_random=False))
def test_fastest_timing_on_any_polygons(kinds: list[int], rnd) -> None:
    """Any number of frames (none, one), any mix of polygons (degenerate, empty, slivers): the
    profile has one ṗ² per frame and every interval polygon fits its row (or its grown row)."""
    rng = np.random.default_rng(rnd.randint(0, 2**31))
    verts = [_polygon(rng, k) for k in kinds]
    polys = polygons_of(verts)
    t = fastest_timing(polys, 30.0)
    assert t.x.shape == (len(verts),)
    assert np.all(t.x > 0) and np.isfinite(t.duration) and t.duration >= 0
    v, c, box = padded(polys)
    qv, qc, _ = interval_polygons(v, c, 1 / 30, box)
    assert np.all(qc <= qv.shape[1])


@SETTINGS
@given(st.integers(0, 12), st.floats(-3, 3), st.floats(-3, 3), st.floats(-2, 2), st.randoms(use_true_random=False))
def test_clip_of_any_point_list_stays_in_its_buffer(n: int, ca: float, cx: float, b: float, rnd) -> None:
    """Sutherland-Hodgman on arbitrary (non-convex, zigzag) point lists emits at most 2n points, all
    on the kept side; on convex ones at most n + 1."""
    rng = np.random.default_rng(rnd.randint(0, 2**31))
    pts = rng.normal(size=(n, 2))
    out, m = _clip(pts, n, ca, cx, b)
    assert 0 <= m <= max(2 * n, 0) and out.shape[0] >= m
    assert np.all(ca * out[:m, 0] + cx * out[:m, 1] <= b + 1e-9 * (1 + abs(b)) + 1e-9)
    zig = np.stack([np.arange(n, dtype=float), np.where(np.arange(n) % 2, 1e-13, -1e-13)], 1)
    out, m = _clip(zig, n, 0.0, 1.0, 0.0)
    assert m <= 2 * n


def test_set_interval_grows_a_row_too_short() -> None:
    """A polygon with more vertices than its row holds widens the rows instead of writing past them."""
    rng = np.random.default_rng(3)
    polys = polygons_of([_polygon(rng, 0) for _ in range(3)])
    v, c, box = padded(polys)
    want_v, want_c, want_m = interval_polygons(v, c, 1 / 30, box)
    qv, qc, meet = np.zeros((3, 1, 2)), np.zeros(3, np.int64), np.ones(3, bool)
    for i in range(3):
        qv = set_interval(v, c, 1 / 30, i, qv, qc, meet, box)
    np.testing.assert_array_equal(qc, want_c)
    np.testing.assert_array_equal(meet, want_m)
    for i in range(3):
        np.testing.assert_array_equal(qv[i, :qc[i]], want_v[i, :want_c[i]])


@SETTINGS
@given(st.integers(1, 4), st.integers(1, 5),
       hnp.arrays(np.float64, st.integers(0, 8), elements=st.floats(-10, 10) | st.sampled_from([np.nan, np.inf, -np.inf])),
       st.randoms(use_true_random=False))
def test_objective_density_reads_only_its_frames(f: int, k: int, u: np.ndarray, rnd) -> None:
    """u outside [0, F − 1] (±inf) reads the end frame, NaN frame 0 — never past the arrays."""
    rng = np.random.default_rng(rnd.randint(0, 2**31))
    verts = rng.normal(size=(f, k, 2))
    count = rng.integers(0, k + 1, f)
    theta = np.sort(rng.uniform(0, 2 * np.pi, (f, k)), axis=1)
    args = (verts, count, rng.uniform(0, 1, (f, k)), rng.integers(0, 2, f).astype(bool), rng.normal(size=(f, 2)),
            rng.uniform(0, 1, f), theta, rng.normal(size=(f, k, 6)), rng.uniform(0, 1, f))
    x = rng.normal(size=(len(u), 2))
    got = _evaluate_kernel(*args, u, x)
    clamped = np.where(np.isnan(u), 0.0, np.clip(u, 0, f - 1))
    want = _evaluate_kernel(*args, clamped, x)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b)


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 4), st.integers(0, 4), st.integers(1, 3), st.randoms(use_true_random=False))
def test_dense_lp_sequence_matches_highs(n: int, m: int, b: int, rnd) -> None:
    from scipy.optimize import linprog

    rng = np.random.default_rng(rnd.randint(0, 2**31))
    M = rng.normal(size=(m, n))
    lp = DenseLP(M, -np.ones(n), np.ones(n), -np.full(m, 0.5), np.full(m, 0.5))
    costs = rng.normal(size=(b, n))
    xs, status = lp.solve_sequence(costs)
    assert len(xs) == len(status) == b
    for c, x, s in zip(costs, xs, status, strict=True):
        ref = linprog(c, A_ub=np.vstack([M, -M]) if m else None, b_ub=np.full(2 * m, 0.5) if m else None,
                      bounds=[(-1, 1)] * n, method="highs")
        assert s == OPTIMAL and ref.status == 0
        assert c @ x == pytest.approx(ref.fun, abs=1e-7)


def test_dense_lp_refuses_more_costs_than_columns() -> None:
    lp = DenseLP(np.ones((1, 2)), -np.ones(2), np.ones(2), [-1.0], [1.0])
    with pytest.raises(ValueError, match="columns"):
        lp.solve_sequence(np.ones((2, 3)))
