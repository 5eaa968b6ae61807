"""``timing_distances`` (tasks/retime/polygons.py, MPS06 §3.3): the compiled pass equals the loop
over ``closest_point`` of tests/naive.py, bit for bit, on random polygons of every kind (empty,
one vertex, a segment, degenerate and proper convex polygons), points inside and outside."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from motionweb.tasks.retime.polygons import convex_hull, timing_distances
from naive import ref_timing_distances


def random_polygons(rng: np.random.Generator, n: int) -> SimpleNamespace:
    vertices = []
    for _ in range(n):
        kind = rng.integers(0, 6)
        if kind == 0:
            v = np.zeros((0, 2))
        elif kind == 1:
            v = rng.normal(size=(1, 2))
        elif kind == 2:
            v = rng.normal(size=(2, 2))
        elif kind == 3:  # collinear: zero area
            t = np.sort(rng.uniform(-1, 1, 4))
            v = np.stack([t, 2 * t + 0.5], axis=1)[[0, 3, 1]]
        else:
            pts = rng.normal(scale=rng.uniform(0.1, 10), size=(int(rng.integers(3, 12)), 2))
            v = pts[convex_hull(pts)]
        vertices.append(v)
    return SimpleNamespace(vertices=vertices, center=rng.normal(size=(n, 2)))


@pytest.mark.parametrize("seed", range(8))
def test_compiled_distances_equal_the_loop(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, t = int(rng.integers(1, 60)), int(rng.integers(0, 300))
    polys = random_polygons(rng, n)
    fps = 30.0
    p = rng.uniform(-0.2, n / fps + 0.2, t)  # frames clipped at both ends
    pd = rng.normal(scale=2.0, size=t)
    pdd = rng.normal(scale=5.0, size=t)
    frames, dist, inside = timing_distances(polys, fps, p, pd, pdd)
    ref = ref_timing_distances(polys, fps, p, pd, pdd)
    np.testing.assert_array_equal(frames, ref[0])
    np.testing.assert_array_equal(dist, ref[1])
    np.testing.assert_array_equal(inside, ref[2])
    assert (ref[1] >= 0).all()


def test_inside_points_are_at_distance_zero() -> None:
    """A point strictly inside a proper polygon is at distance 0 and inside; one outside is at
    its distance to the nearest edge (a unit square, closed form)."""
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    polys = SimpleNamespace(vertices=[square], center=np.zeros((1, 2)))
    pd = np.sqrt(np.array([0.5, 0.5, 3.0]))  # ṗ² = 0.5, 0.5, 3
    pdd = np.array([0.5, 2.0, 0.5])
    _, dist, inside = timing_distances(polys, 30.0, np.zeros(3), pd, pdd)
    np.testing.assert_allclose(dist, [0.0, 1.0, 2.0], atol=1e-12)
    assert inside.tolist() == [True, False, False]
