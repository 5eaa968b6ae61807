"""Path timings of a requested duration (tasks/retime/path_timing.py): the exact p(t) of a profile,
durations met inside the polygons, the greedy below the shortest against a from-scratch reference
(tests/naive.py); MPS06 Fig. 1 on CMU 16_06 is in test_retime_cmu.py."""

from __future__ import annotations

import numpy as np
import pytest
from motionweb.tasks.retime.path_timing import (
    BATCH,
    FLIGHT_WEIGHT,
    PathCurve,
    frame_weights,
    profile_of_duration,
)
from motionweb.tasks.retime.polygons import timing_distances
from motionweb.tasks.retime.reachable import BATCH_GAIN, fastest_timing, profile_duration
from naive import box_polygon as box
from naive import greedy_free, in_convex
from naive import polygons_of as polygons


def half_intervals_inside(verts: list[np.ndarray], x: np.ndarray, fps: float, skip: np.ndarray) -> list[int]:
    """Intervals whose held p̈ leaves the nearer frame's polygon on either half (frames in ``skip`` aside)."""
    bad = []
    for i in range(len(x) - 1):
        a, mid = (x[i + 1] - x[i]) * fps / 2, (x[i] + x[i + 1]) / 2
        for j, xx in ((i, x[i]), (i, mid), (i + 1, mid), (i + 1, x[i + 1])):
            if not skip[j] and not in_convex(verts[j], np.array([a, xx]), tol=1e-7):
                bad.append(i)
    return bad


def test_path_curve_is_the_profile_integrated() -> None:
    """p(t) of x = ṗ² linear in source time between frames: p reaches frame i at out[i], ṗ² = x
    there, p̈ the interval's constant; a constant profile gives p = √x t."""
    fps = 50.0
    rng = np.random.default_rng(0)
    x = rng.uniform(0.3, 4.0, 40)
    c = PathCurve.of(x, fps)
    p, pd, pdd = c.evaluate(np.empty(0), c.out)
    np.testing.assert_allclose(p, np.arange(40) / fps, atol=1e-12)
    np.testing.assert_allclose(pd ** 2, x, rtol=1e-9)
    mid = 0.5 * (c.out[1:] + c.out[:-1])
    _, pd_m, pdd_m = c.evaluate(np.empty(0), mid)
    np.testing.assert_allclose(pdd_m, np.diff(x) * fps / 2, rtol=1e-12)
    t = np.linspace(0, c.out[-1], 20001)  # ṗ is p's derivative: compare with finite differences
    p, pd, _ = c.evaluate(np.empty(0), t)
    np.testing.assert_allclose(np.gradient(p, t)[1:-1], pd[1:-1], rtol=2e-3)
    flat = PathCurve.of(np.full(11, 2.25), fps)
    assert flat.out[-1] == pytest.approx(10 / fps / 1.5)
    np.testing.assert_allclose(flat.evaluate(np.empty(0), np.array([0.05]))[0], [0.075])


def walk_polygons(f: int = 60) -> list[np.ndarray]:
    """Polygons that hold the original timing (0, 1): |p̈| ≤ 8, ṗ² from 0.2 to a cap that dips."""
    cap = 4.0 - 2.5 * np.exp(-((np.arange(f) - f / 2) / 4.0) ** 2)
    return [box(8.0, 0.2, c) for c in cap]


@pytest.mark.parametrize("frac", [0.7, 0.85, 1.0, 1.3, 2.0])
def test_durations_within_reach_are_met_inside(frac: float) -> None:
    """Between the fastest and the slowest timing inside every polygon: the duration exactly, every
    interval inside (no frame freed), the original timing at frac 1."""
    fps, verts = 30.0, walk_polygons()
    polys = polygons(verts)
    original = (len(verts) - 1) / fps
    assert fastest_timing(polys, fps).duration < 0.7 * original
    prof = profile_of_duration(polys, fps, frac * original)
    assert prof is not None and not prof.freed.any()
    assert profile_duration(prof.x, 1 / fps) == pytest.approx(frac * original, rel=1e-9)
    assert not half_intervals_inside(verts, prof.x, fps, prof.freed)
    if frac == 1.0:
        np.testing.assert_array_equal(prof.x, 1.0)
    assert 0.0 <= prof.theta <= 1.0


def test_below_the_shortest_the_bottleneck_is_freed() -> None:
    """One frame capped at ṗ² ≤ 1.05 (the rest allow 9): below the fastest timing the greedy frees
    the frames around it, within the polygons' box; the duration is met and every other interval
    is inside."""
    fps, f = 30.0, 60
    verts = [box(30.0, 0.2, 9.0) for _ in range(f)]
    verts[30] = box(30.0, 0.2, 1.05)
    polys = polygons(verts, box=(30.0, 9.0))
    fast = fastest_timing(polys, fps).duration
    prof = profile_of_duration(polys, fps, 0.97 * fast)
    assert prof is not None and prof.freed.any()
    assert set(np.flatnonzero(prof.freed)) <= set(range(26, 35))
    a = np.diff(prof.x) * fps / 2  # freed frames stay in the box the polygons were clipped to, not the default
    assert np.abs(a).max() <= 30.0 + 1e-9 and prof.x.max() <= 9.0 + 1e-9
    assert profile_duration(prof.x, 1 / fps) == pytest.approx(0.97 * fast, rel=1e-9)
    assert not half_intervals_inside(verts, prof.x, fps, prof.freed | np.roll(prof.freed, 1) | np.roll(prof.freed, -1))


@pytest.mark.parametrize("seed", range(4))
def test_the_greedy_against_its_from_scratch_reference(seed: int) -> None:
    """The compiled greedy (incremental interval polygons, BATCH units a step) frees what the
    from-scratch reference frees, and ends on the same profile; with and without frame weights."""
    rng = np.random.default_rng(seed)
    fps, f = 30.0, 40
    verts = [box(rng.uniform(5, 20), 0.1, rng.uniform(1.5, 6.0)) for _ in range(f)]
    polys = polygons(verts)
    target = (0.9 if seed % 2 else 0.95) * fastest_timing(polys, fps).duration
    weight = None if seed < 2 else rng.choice([1.0, FLIGHT_WEIGHT], f)
    prof = profile_of_duration(polys, fps, target, weight=weight)
    freed, x = greedy_free(verts, fps, target, batch=BATCH, batch_gain=BATCH_GAIN, weight=weight)
    assert prof is not None and freed.sum() >= 2
    np.testing.assert_array_equal(prof.freed, freed)
    assert profile_duration(x, 1 / fps) <= target + 1e-12
    np.testing.assert_allclose(prof.x, 1 + prof.theta * (x - 1), rtol=1e-9)


def test_equal_bottlenecks_are_freed_together() -> None:
    """Four equal bottlenecks: one step ranks them alike and frees them together (the batch);
    kernel and reference agree, and all four go."""
    fps, f = 30.0, 40
    verts = [box(30.0, 0.2, 9.0) for _ in range(f)]
    for i in (5, 15, 25, 35):
        verts[i] = box(30.0, 0.2, 1.05)
    polys = polygons(verts)
    target = 0.62 * fastest_timing(polys, fps).duration
    prof = profile_of_duration(polys, fps, target)
    freed, _ = greedy_free(verts, fps, target, batch=BATCH, batch_gain=BATCH_GAIN)
    assert prof is not None
    np.testing.assert_array_equal(prof.freed, freed)
    assert all(freed[i - 1:i + 2].any() for i in (5, 15, 25, 35))


def test_the_greedy_buys_time_on_the_ground_before_the_flight() -> None:
    """Two equal bottlenecks, either one enough: unweighted the first goes (ties by frame); when
    the first lies in a flight (frame_weights: no foot down) the one on the ground goes instead."""
    fps, f = 30.0, 40
    verts = [box(30.0, 0.2, 9.0) for _ in range(f)]
    for i in (10, 30):
        verts[i] = box(30.0, 0.2, 1.05)
    polys = polygons(verts)
    both = fastest_timing(polys, fps).duration
    one = fastest_timing(polygons([np.zeros((0, 2)) if i == 30 else v for i, v in enumerate(verts)]), fps).duration
    target = one + 0.3 * (both - one)
    ground = np.ones(f, bool)
    ground[8:13] = False
    plain = profile_of_duration(polys, fps, target)
    weighted = profile_of_duration(polys, fps, target, weight=frame_weights(ground))
    assert plain is not None and weighted is not None
    assert plain.freed[9:12].any() and not plain.freed[28:33].any()
    assert weighted.freed[28:33].any() and not weighted.freed[8:13].any()
    np.testing.assert_array_equal(frame_weights(ground)[7:14], [1, FLIGHT_WEIGHT, FLIGHT_WEIGHT, FLIGHT_WEIGHT,
                                                                FLIGHT_WEIGHT, FLIGHT_WEIGHT, 1])


def test_out_of_reach_gives_none() -> None:
    """Too short to leave the polygons on at most half the frames, or longer than the slowest."""
    fps, verts = 30.0, walk_polygons()
    polys = polygons(verts)
    original = (len(verts) - 1) / fps
    assert profile_of_duration(polys, fps, 0.1 * original) is None
    slow = [box(8.0, 0.9, 1.1) for _ in verts]
    assert profile_of_duration(polygons(slow), fps, 2.0 * original) is None


def test_timing_distances_check_the_nearest_frame() -> None:
    """An output frame is checked against its nearest source frame's polygon, with the relative tolerance."""
    fps = 10.0
    polys = polygons([box(1.0, 0.5, 2.0), box(1.0, 3.0, 4.0)])
    frames, dist, inside = timing_distances(polys, fps, np.array([0.0, 0.04, 0.06, 0.1]), np.array([1.0, 1.0, 1.0, 1.9]),
                                            np.array([0.0, 1.5, 0.0, 0.0]))
    np.testing.assert_array_equal(frames, [0, 0, 1, 1])
    np.testing.assert_allclose(dist, [0.0, 0.5, 2.0, 0.0], atol=1e-12)
    np.testing.assert_array_equal(inside, [True, False, False, True])
