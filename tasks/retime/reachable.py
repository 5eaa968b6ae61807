"""The shortest timing inside the feasible polygons: reachability on the path (design §8, MPS06 §3.3).

The polygons bound each source frame's (p̈, ṗ²); along the path x = ṗ² obeys dx/du = 2p̈ (u in
source seconds), so a timing is a profile x(u) with (½ dx/du, x) in every frame's polygon: the
time-optimal path parameterization problem of robotics, solved by reachability analysis (TOPP-RA;
Pham & Pham, IEEE T-RO 34(3), 2018) on the source frames with p̈ constant over each frame
interval. A backward pass gives each frame's controllable set (the ṗ² from which the rest of the
clip can still play inside its polygons), a greedy forward pass the fastest profile in them. Both
cut a convex polygon by half-planes, so no LP is needed and the result is exact for the polygons:
the shortest duration any timing inside them reaches (the one a retiming below it cannot meet).

Cost: O(F · K) (F frames, K polygon vertices), compiled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from motionweb.tasks.retime.polygons import FeasiblePolygons
from numba import njit

#: ṗ² floor of a profile (no timing stops the clip): 1e-6 is 1/1000 of normal speed
X_FLOOR = 1e-6
#: (p̈, ṗ²) box standing in for an empty polygon (RetimeParams' default pdd_max, speed_max²): the
#: timing is then not inside, whatever the box
BOX = (40.0, 36.0)


@dataclass(frozen=True, eq=False)
class PathTiming:
    """A timing of source frames as ṗ² per frame (p̈ constant between frames).

    Attributes:
        x: (F,) ṗ² at each source frame; duration: output seconds of the profile;
        inside: every frame's (p̈, ṗ²) lies in its polygon (no frame without one, no broken chain);
        broken: frames whose polygon is empty or from which no later frame can be reached inside
            (each restarts the backward pass), empty for a certificate.
    """

    x: np.ndarray
    duration: float
    inside: bool
    broken: np.ndarray


def padded(polys: FeasiblePolygons) -> tuple[np.ndarray, np.ndarray]:
    """The polygons as (F, K, 2) vertices (padding repeats the last) and (F,) vertex counts (0: empty)."""
    vs = polys.vertices
    k = max(max((len(v) for v in vs), default=1), 1)
    verts = np.zeros((len(vs), k, 2))
    count = np.zeros(len(vs), np.int64)
    for i, v in enumerate(vs):
        if len(v):
            verts[i, :len(v)] = v
            verts[i, len(v):] = v[-1]
            count[i] = len(v)
    return verts, count


@njit(cache=True)
def _clip(pts, n, ca, cx, b):  # pragma: no cover - numba
    """The convex polygon ``pts[:n]`` (a, x) cut to ca·a + cx·x ≤ b (Sutherland-Hodgman): (out, m)."""
    out = np.empty((n + 2, 2))
    m = 0
    for k in range(n):
        kn = k + 1 if k + 1 < n else 0
        sp = ca * pts[k, 0] + cx * pts[k, 1] - b
        sq = ca * pts[kn, 0] + cx * pts[kn, 1] - b
        if sp <= 0.0:
            out[m] = pts[k]
            m += 1
        if (sp < 0.0 < sq) or (sq < 0.0 < sp):
            w = sp / (sp - sq)
            out[m, 0] = pts[k, 0] + w * (pts[kn, 0] - pts[k, 0])
            out[m, 1] = pts[k, 1] + w * (pts[kn, 1] - pts[k, 1])
            m += 1
        if n == 1:
            break
    return out, m


@njit(cache=True)
def _frame_polygon(verts, count, i):  # pragma: no cover - numba
    """Frame i's polygon, or :data:`BOX` where it is empty: (points, n)."""
    if count[i] == 0:
        return np.array([[-BOX[0], 0.0], [BOX[0], 0.0], [BOX[0], BOX[1]], [-BOX[0], BOX[1]]]), 4
    return verts[i], count[i]


@njit(cache=True)
def _backward(verts, count, d):  # pragma: no cover - numba
    """Controllable sets [lo, hi] of ṗ² per frame (TOPP-RA's backward pass) and where the chain broke."""
    f = verts.shape[0]
    lo = np.zeros(f)
    hi = np.zeros(f)
    broken = np.zeros(f, np.bool_)
    pts, n = _frame_polygon(verts, count, f - 1)
    lo[f - 1], hi[f - 1] = pts[:n, 1].min(), pts[:n, 1].max()
    broken[f - 1] = count[f - 1] == 0
    for i in range(f - 2, -1, -1):
        pts, n = _frame_polygon(verts, count, i)
        # x_{i+1} = x_i + 2 d a_i must lie in [lo_{i+1}, hi_{i+1}]
        cut, m = _clip(pts, n, 2.0 * d, 1.0, hi[i + 1])
        cut, m = _clip(cut, m, -2.0 * d, -1.0, -lo[i + 1])
        broken[i] = count[i] == 0
        if m == 0:  # no way on inside: restart the chain from this frame's own polygon
            broken[i] = True
            cut, m = pts, n
        lo[i], hi[i] = cut[:m, 1].min(), cut[:m, 1].max()
    return lo, hi, broken


@njit(cache=True)
def _forward(verts, count, d, lo, hi):  # pragma: no cover - numba
    """The fastest profile in the controllable sets (TOPP-RA's greedy forward pass)."""
    f = verts.shape[0]
    x = np.empty(f)
    x[0] = hi[0]
    for i in range(f - 1):
        pts, n = _frame_polygon(verts, count, i)
        xi = min(max(x[i], pts[:n, 1].min()), pts[:n, 1].max())
        amin, amax = np.inf, -np.inf
        for k in range(n):  # the a-range of the polygon on the line ṗ² = xi
            kn = k + 1 if k + 1 < n else 0
            y0, y1 = pts[k, 1], pts[kn, 1]
            if min(y0, y1) - 1e-12 <= xi <= max(y0, y1) + 1e-12:
                if abs(y1 - y0) < 1e-15:
                    amin, amax = min(amin, pts[k, 0], pts[kn, 0]), max(amax, pts[k, 0], pts[kn, 0])
                else:
                    a = pts[k, 0] + (pts[kn, 0] - pts[k, 0]) * (xi - y0) / (y1 - y0)
                    amin, amax = min(amin, a), max(amax, a)
        top = min(xi + 2.0 * d * amax, hi[i + 1])
        bottom = max(xi + 2.0 * d * amin, lo[i + 1])
        x[i + 1] = top if top >= bottom else (hi[i + 1] if xi + 2.0 * d * amin > hi[i + 1] else lo[i + 1])
    return np.maximum(x, X_FLOOR)


def fastest_timing(polys: FeasiblePolygons, fps: float) -> PathTiming:
    """The shortest timing whose every source frame lies inside its polygon (TOPP-RA, MPS06 §3.3).

    Exact for the polygons given, with p̈ constant between source frames: no timing that stays
    inside them is shorter. Where a polygon is empty or the chain breaks the timing is not
    ``inside`` and ``broken`` says where. O(F · K).
    """
    verts, count = padded(polys)
    lo, hi, broken = _backward(verts, count, 1.0 / fps)
    x = _forward(verts, count, 1.0 / fps, lo, hi)
    s = np.sqrt(x)
    where = np.flatnonzero(broken)
    return PathTiming(x=x, duration=float((2.0 / fps / (s[1:] + s[:-1])).sum()), inside=not len(where), broken=where)
