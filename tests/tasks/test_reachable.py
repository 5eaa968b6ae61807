"""The shortest timing inside the feasible polygons (TOPP-RA): a closed form, broken chains and an
exhaustive reference (tests/naive.py); 16_06 (MPS06 Fig. 1) is in test_retime_cmu.py."""

from __future__ import annotations

import numpy as np
import pytest
from motionweb.tasks.retime.reachable import fastest_timing
from motionweb.tasks.retime.report import shortest_duration
from naive import box_polygon as box
from naive import grid_fastest, in_convex
from naive import polygons_of as polygons


def test_bang_bang_between_two_normal_speed_frames() -> None:
    """|p̈| ≤ a, ṗ² ≤ X, first and last frame at ṗ = 1: accelerate at a, cruise at √X, brake at a
    (the continuous bang-bang solution, exact when the switches fall on frames). The end frames'
    polygons are the line ṗ² = 1, which the half intervals next to them are checked against, so
    the ramps start one frame in."""
    fps, a, X, f = 100.0, 5.0, 4.0, 301
    verts = [box(a, 1.0, 1.0)] + [box(a, 0.0, X)] * (f - 2) + [box(a, 1.0, 1.0)]
    t = fastest_timing(polygons(verts), fps)
    u = np.arange(f) / fps
    up, down = np.maximum(u - u[1], 0), np.maximum(u[-2] - u, 0)
    want = np.minimum.reduce([np.full(f, X), 1 + 2 * a * up, 1 + 2 * a * down])
    np.testing.assert_allclose(t.x, want, atol=1e-9)
    ramp = (np.sqrt(X) - 1) / a  # each ramp: (X − 1) / 2a = 0.3 s of source, 30 frames
    cruise = u[-2] - u[1] - (X - 1) / a
    assert t.duration == pytest.approx(2 / fps + 2 * ramp + cruise / np.sqrt(X), rel=1e-9)
    assert t.inside and not len(t.broken)


def test_an_unreachable_frame_breaks_the_chain() -> None:
    """A frame that must play at ṗ² ≥ 9 right after one capped at 1 with |p̈| ≤ 1 cannot be
    reached inside; an empty polygon neither: both are named and the duration is inf."""
    fps = 100.0
    verts = [box(1.0, 0.5, 1.0)] * 5 + [box(1.0, 9.0, 9.5)] + [box(1.0, 0.5, 1.0)] * 5
    t = fastest_timing(polygons(verts), fps)
    assert not t.inside and 4 in t.broken.tolist()
    assert shortest_duration(polygons(verts), fps) == np.inf
    empty = [box(1.0, 0.5, 1.0)] * 4 + [np.zeros((0, 2))] + [box(1.0, 0.5, 1.0)] * 4
    t = fastest_timing(polygons(empty), fps)
    assert not t.inside and 4 in t.broken.tolist()


@pytest.mark.parametrize("seed", range(6))
def test_random_polygons_against_an_exhaustive_search(seed: int) -> None:
    """Random convex polygons (and a thin sliver): the profile lies in every polygon, is no longer
    than the best of all ṗ² profiles on a grid and no shorter than every frame at its top speed."""
    rng = np.random.default_rng(seed)
    fps, f = 10.0, 4
    verts = []
    for i in range(f):
        if i == 2 and seed % 2:  # a thin flight-like sliver
            c = rng.uniform(0.8, 2.0)
            verts.append(np.array([[-0.3, c - 0.2], [0.3, c], [0.3, c + 0.2], [-0.3, c]]))
            continue
        ang = np.sort(rng.uniform(0, 2 * np.pi, 7))
        pts = np.stack([rng.uniform(2, 6) * np.cos(ang), 1.5 + rng.uniform(0.5, 1.4) * np.sin(ang)], axis=1)
        verts.append(pts)
    t = fastest_timing(polygons(verts), fps)
    assert t.inside
    for i in range(f - 1):  # p̈ held over the interval: each half inside its nearer frame's polygon
        a, mid = (t.x[i + 1] - t.x[i]) * fps / 2, (t.x[i] + t.x[i + 1]) / 2
        for j, x in ((i, t.x[i]), (i, mid), (i + 1, mid), (i + 1, t.x[i + 1])):
            assert in_convex(verts[j], np.array([a, x]), tol=1e-7), (i, j)
    assert verts[-1][:, 1].min() - 1e-9 <= t.x[-1] <= verts[-1][:, 1].max() + 1e-9
    grid = np.linspace(0.05, 3.0, 16)
    best = grid_fastest(verts, fps, grid)
    assert np.isfinite(best) and t.duration <= best + 1e-9
    top = np.sqrt([v[:, 1].max() for v in verts])  # each frame at its own top speed: a lower bound
    assert t.duration >= (2 / fps / (top[1:] + top[:-1])).sum() - 1e-12


def test_an_empty_polygon_takes_the_box_the_polygons_were_clipped_to() -> None:
    """An empty polygon (or a freed one) stands for the whole (p̈, ṗ²) box of the clip's polygons
    (``FeasiblePolygons.box``, the user's pdd_max and speed_max²), not a fixed default."""
    fps = 30.0
    verts = [box(40.0, 0.0, 36.0)] * 10 + [np.zeros((0, 2))] + [box(40.0, 0.0, 36.0)] * 10
    at = {}
    for cap in (4.0, 36.0):
        t = fastest_timing(polygons(verts, box=(40.0, cap)), fps)
        assert not t.inside and t.broken.tolist() == [10]
        at[cap] = t.x[10]
    assert at[4.0] <= 4.0 + 1e-9 < at[36.0]
