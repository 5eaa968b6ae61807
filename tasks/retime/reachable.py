"""The shortest timing inside the feasible polygons: reachability on the path (design §8, MPS06 §3.3).

The polygons bound each source frame's (p̈, ṗ²); along the path x = ṗ² obeys dx/du = 2p̈ (u in
source seconds), so a timing is a profile x(u) with (½ dx/du, x) in every frame's polygon: the
time-optimal path parameterization problem of robotics, solved by reachability analysis (TOPP-RA;
Pham & Pham, IEEE T-RO 34(3), 2018) on the source frames with p̈ constant over each frame
interval and inside the polygon of the nearer frame at every instant between (the paper's
first-order interpolation scheme, checked as an output frame is: against its nearest source
frame). A backward pass gives each frame's controllable set (the ṗ² from which the rest of the
clip can still play inside its polygons), a greedy forward pass the fastest profile in them. Both
cut a convex polygon by half-planes, so no LP is needed and the result is exact for the polygons:
the shortest duration any timing inside them reaches (the one a retiming below it cannot meet).

:func:`free_frames` is the greedy below that shortest duration: which source frames to let leave
their polygon so the rest can play faster (``path_timing``).

Cost: O(F · K²) per pass (F frames, K polygon vertices), compiled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from motionweb.tasks.retime.polygons import FeasiblePolygons
from motionweb.store.numba_cache import njit

#: ṗ² floor of a profile (no timing stops the clip): 1e-6 is 1/1000 of normal speed
X_FLOOR = 1e-6
#: candidate units of :func:`free_frames`: at most this many per clip (units of ⌈F / UNITS⌉ frames)
UNITS = 256
#: :func:`free_frames` frees more than the best unit in one step only where they save nearly as
#: much per output frame as the best (this share of its gain)
BATCH_GAIN = 0.8


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


def padded(polys: FeasiblePolygons) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The polygons as (F, K, 2) vertices (padding repeats the last), (F,) vertex counts (0: empty)
    and (2,) the (p̈, ṗ²) box they were clipped to (``polys.box``): what stands in for an empty
    or freed polygon."""
    vs = polys.vertices
    k = max(max((len(v) for v in vs), default=1), 1)
    verts = np.zeros((len(vs), k, 2))
    count = np.zeros(len(vs), np.int64)
    for i, v in enumerate(vs):
        if len(v):
            verts[i, :len(v)] = v
            verts[i, len(v):] = v[-1]
            count[i] = len(v)
    return verts, count, np.asarray(polys.box, float)


@njit(cache=True)
def _clip(pts, n, ca, cx, b):  # pragma: no cover - numba
    """The convex polygon ``pts[:n]`` (a, x) cut to ca·a + cx·x ≤ b (Sutherland-Hodgman): (out, m).

    Bounds: each edge emits at most its start and one crossing, so m ≤ 2n (≤ n + 1 for a convex
    polygon, but rounding can make a thin one zigzag across the line); ``out`` holds 2n + 2.
    """
    out = np.empty((2 * n + 2, 2))
    m = 0
    tol = 1e-12 * (abs(b) + 1.0)  # a point on the line stays, whatever its rounding
    for k in range(n):
        kn = k + 1 if k + 1 < n else 0
        sp = ca * pts[k, 0] + cx * pts[k, 1] - b
        sq = ca * pts[kn, 0] + cx * pts[kn, 1] - b
        sp = 0.0 if abs(sp) <= tol else sp
        sq = 0.0 if abs(sq) <= tol else sq
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
def _frame_polygon(verts, count, i, box):  # pragma: no cover - numba
    """Frame i's polygon, or the (p̈, ṗ²) box |p̈| ≤ box[0], 0 ≤ ṗ² ≤ box[1] where it is empty: (points, n)."""
    if count[i] == 0:
        return np.array([[-box[0], 0.0], [box[0], 0.0], [box[0], box[1]], [-box[0], box[1]]]), 4
    return verts[i], count[i]


@njit(cache=True)
def _cut_shifted(cut, c, poly, m, shift):  # pragma: no cover - numba
    """Cut ``cut[:c]`` (a, x) to the points whose (a, x + shift·a) lies in the convex polygon
    ``poly[:m]``: each of its edges, and its bounding box, as a half-plane na·a + nx·x' ≤ b, which
    in (a, x) is (na + shift·nx)·a + nx·x ≤ b. (out, n)."""
    bounds = ((1.0, 0.0, poly[:m, 0].max()), (-1.0, 0.0, -poly[:m, 0].min()),
              (0.0, 1.0, poly[:m, 1].max()), (0.0, -1.0, -poly[:m, 1].min()))
    for na, nx, b in bounds:
        cut, c = _clip(cut, c, na + shift * nx, nx, b)
    for k in range(m):
        if c == 0:
            break
        kn = k + 1 if k + 1 < m else 0
        na, nx = poly[kn, 1] - poly[k, 1], poly[k, 0] - poly[kn, 0]  # outward normal (counter-clockwise)
        if na == 0.0 and nx == 0.0:
            continue
        cut, c = _clip(cut, c, na + shift * nx, nx, na * poly[k, 0] + nx * poly[k, 1])
    return cut, c


@njit(cache=True)
def _interval_polygon(verts, count, i, d, box):  # pragma: no cover - numba
    """The (p̈, ṗ²) = (a, x_i) of frame i whose p̈ held over the interval to frame i + 1 stays
    inside the polygon of the nearer frame at every instant: x runs linearly from x_i to
    x_i + 2 d a, the first half checked against frame i's polygon, the second against frame
    i + 1's, so (convexity) both ends of each half must lie in its polygon (TOPP-RA's first-order
    interpolation scheme, with the check an output frame gets). The last frame: its own polygon.
    (points, n), n = 0 when no such a exists."""
    pts, n = _frame_polygon(verts, count, i, box)
    cut = pts[:n].copy()
    if i == verts.shape[0] - 1:
        return cut, n
    nxt, m = _frame_polygon(verts, count, i + 1, box)
    cut, c = _cut_shifted(cut, n, pts, n, d)
    if c:
        cut, c = _cut_shifted(cut, c, nxt, m, d)
    if c:
        cut, c = _cut_shifted(cut, c, nxt, m, 2.0 * d)
    return cut, c


@njit(cache=True)
def set_interval(verts, count, d, i, qv, qc, meet, box):  # pragma: no cover - numba
    """Store frame i's :func:`_interval_polygon` in ``qv[i], qc[i]`` (its own polygon where the
    two frames' do not meet, ``meet[i]`` False); returns ``qv``, widened (a copy) when the polygon
    has more vertices than its rows hold.

    Bounds: the cut polygon is the intersection of at most 4K + 12 half-planes (K = verts' width),
    within the 4K + 16 columns :func:`interval_polygons` gives ``qv``; rounding can add vertices
    (:func:`_clip`), and then ``qv`` grows rather than being written past.
    """
    q, n = _interval_polygon(verts, count, i, d, box)
    meet[i] = n > 0
    if n == 0:
        q, n = _frame_polygon(verts, count, i, box)
    if n > qv.shape[1]:
        wider = np.zeros((qv.shape[0], 2 * n, 2))
        wider[:, :qv.shape[1]] = qv
        qv = wider
    qv[i, :n] = q[:n]
    qc[i] = n
    return qv


@njit(cache=True)
def interval_polygons(verts, count, d, box):  # pragma: no cover - numba
    """Every frame's :func:`_interval_polygon`: (F, K', 2) vertices, (F,) counts, (F,) whether the
    frame's polygon meets the next one's. O(F · K²).

    Bounds: (F, 4K + 16) vertex rows, widened by :func:`set_interval` if a polygon needs more."""
    f = verts.shape[0]
    qv = np.zeros((f, 4 * verts.shape[1] + 16, 2))
    qc = np.zeros(f, np.int64)
    meet = np.ones(f, np.bool_)
    for i in range(f):
        qv = set_interval(verts, count, d, i, qv, qc, meet, box)
    return qv, qc, meet


@njit(cache=True)
def _backward(qv, qc, d):  # pragma: no cover - numba
    """Controllable sets [lo, hi] of ṗ² per frame (TOPP-RA's backward pass) over the interval
    polygons, and where no way on inside was left.

    Bounds: writes frames 0..F−1 of its (F,) outputs; no frames, empty outputs."""
    f = qv.shape[0]
    lo = np.zeros(f)
    hi = np.zeros(f)
    broken = np.zeros(f, np.bool_)
    if f == 0:
        return lo, hi, broken
    n = qc[f - 1]
    lo[f - 1], hi[f - 1] = qv[f - 1, :n, 1].min(), qv[f - 1, :n, 1].max()
    for i in range(f - 2, -1, -1):
        pts, n = qv[i], qc[i]
        # x_{i+1} = x_i + 2 d a_i must lie in [lo_{i+1}, hi_{i+1}]
        cut, m = _clip(pts, n, 2.0 * d, 1.0, hi[i + 1])
        cut, m = _clip(cut, m, -2.0 * d, -1.0, -lo[i + 1])
        if m == 0:  # no way on inside: restart the chain from this frame's own polygon
            broken[i] = True
            cut, m = pts, n
        lo[i], hi[i] = cut[:m, 1].min(), cut[:m, 1].max()
    return lo, hi, broken


@njit(cache=True)
def _forward(qv, qc, d, lo, hi, fastest):  # pragma: no cover - numba
    """The fastest (slowest) profile in the controllable sets: TOPP-RA's greedy forward pass.

    Bounds: writes frames 0..F−1 of its (F,) output; no frames, an empty profile."""
    f = qv.shape[0]
    x = np.empty(f)
    if f == 0:
        return x
    x[0] = hi[0] if fastest else lo[0]
    for i in range(f - 1):
        pts, n = qv[i], qc[i]
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
        if top >= bottom:
            x[i + 1] = top if fastest else bottom
        else:  # the chain broke here: restart at the nearest end of the next controllable set
            x[i + 1] = hi[i + 1] if xi + 2.0 * d * amin > hi[i + 1] else lo[i + 1]
    return np.maximum(x, X_FLOOR)


@njit(cache=True)
def interval_profile(qv, qc, d, fastest):  # pragma: no cover - numba
    """The fastest (``fastest``) or slowest profile over interval polygons (:func:`interval_polygons`)
    and the frames where no way on inside was left."""
    lo, hi, broken = _backward(qv, qc, d)
    return _forward(qv, qc, d, lo, hi, fastest), broken


@njit(cache=True)
def profile_duration(x, d):  # pragma: no cover - numba
    """Output seconds of a profile x = ṗ² (F,) on source frames ``d`` seconds apart (p̈ constant between)."""
    t = 0.0
    for i in range(x.shape[0] - 1):
        t += 2.0 * d / (np.sqrt(x[i]) + np.sqrt(x[i + 1]))
    return t


@njit(cache=True)
def _spent(x, freed, s, e, weight):  # pragma: no cover - numba
    """Output frames checked against the polygons of source frames s..e−1 freed, or against their
    neighbours' over the intervals that touch them (half each): 1/√x per source frame, each
    times its ``weight``."""
    f = x.shape[0]
    out = 0.0
    for j in range(s, e):
        out += weight[j] / np.sqrt(x[j])
    if s > 0 and not freed[s - 1]:
        out += 0.5 * weight[s - 1] / np.sqrt(x[s - 1])
    if e < f and not freed[e]:
        out += 0.5 * weight[e] / np.sqrt(x[e])
    return out


@njit(cache=True)
def _all_spent(x, freed, starts, unit):  # pragma: no cover - numba
    """Output frames left outside by all freed units (:func:`_spent` summed, unweighted)."""
    f = x.shape[0]
    ones = np.ones(f)
    out = 0.0
    for s in starts:
        if freed[s]:
            out += _spent(x, freed, s, min(s + unit, f), ones)
    return out


@njit(cache=True)
def _set_units(verts, cnt, d, s, e, qv, qc, meet, box):  # pragma: no cover - numba
    """Recompute the interval polygons that frames s..e−1 enter (frames s−1..e−1); returns ``qv``
    (widened when needed, :func:`set_interval`).

    Bounds: writes rows max(s − 1, 0)..e − 1 < F (e ≤ F)."""
    for i in range(max(s - 1, 0), e):
        qv = set_interval(verts, cnt, d, i, qv, qc, meet, box)
    return qv


@njit(cache=True)
def free_frames(verts, count, d, duration, unit, max_outside, batch, box, weight):  # pragma: no cover - numba
    """Greedy: free units of ``unit`` source frames (polygon → box) until the fastest profile of
    the rest lasts ≤ ``duration``. Each step ranks the units by the output seconds their freeing
    saves per output frame it leaves outside, each frame counted ``weight`` (F,) times
    (:func:`_spent`), and frees the best, then up to
    ``batch`` − 1 more in rank order while they gain at least :data:`BATCH_GAIN` of the best and
    their savings, summed, stay within what is still missing. Then restores, in order, freed units
    no longer needed. Returns (freed mask, fastest profile, success); fails when nothing helps or
    more than ``max_outside`` output frames are left outside in the end (the steps give up at
    twice that).

    Bounds: ``unit`` ≥ 1 (checked by the callers' wrapper, else ValueError here); units start at
    0, unit, … < F and end at min(s + unit, F); ``weight`` has F entries. No frames: nothing to free."""
    f = count.shape[0]
    if unit < 1:
        raise ValueError("free_frames: unit must be >= 1")
    if weight.shape[0] != f or verts.shape[0] != f:
        raise ValueError("free_frames: verts, count and weight must have one row per frame")
    cnt = count.copy()
    freed = np.zeros(f, np.bool_)
    qv, qc, meet = interval_polygons(verts, cnt, d, box)
    x, _ = interval_profile(qv, qc, d, True)
    dur = profile_duration(x, d)
    starts = np.arange(0, f, unit)
    gain = np.empty(starts.shape[0])
    saving = np.empty(starts.shape[0])
    while dur > duration:
        gain[:] = -1.0
        for k in range(starts.shape[0]):
            s = starts[k]
            e = min(s + unit, f)
            if freed[s] or cnt[s:e].max() == 0:
                continue
            lo = max(s - 1, 0)
            saved_v, saved_c, saved_m, saved_cnt = qv[lo:e].copy(), qc[lo:e].copy(), meet[lo:e].copy(), cnt[s:e].copy()
            cnt[s:e] = 0
            qv = _set_units(verts, cnt, d, s, e, qv, qc, meet, box)
            x2, _ = interval_profile(qv, qc, d, True)
            cnt[s:e] = saved_cnt
            qv[lo:e, :saved_v.shape[1]], qc[lo:e], meet[lo:e] = saved_v, saved_c, saved_m
            saving[k] = dur - profile_duration(x2, d)
            gain[k] = saving[k] / _spent(x2, freed, s, e, weight)
        if starts.shape[0] == 0:
            return freed, x, False
        order = np.argsort(-gain, kind="mergesort")
        if gain[order[0]] <= 0.0:
            return freed, x, False
        taken = 0.0
        for r in range(min(batch, order.shape[0])):
            k = order[r]
            if gain[k] <= 0.0 or (r > 0 and (gain[k] < BATCH_GAIN * gain[order[0]] or taken + saving[k] > dur - duration)):
                break
            taken += saving[k]
            s = starts[k]
            e = min(s + unit, f)
            freed[s:e] = True
            cnt[s:e] = 0
            qv = _set_units(verts, cnt, d, s, e, qv, qc, meet, box)
        x, _ = interval_profile(qv, qc, d, True)
        dur = profile_duration(x, d)
        if _all_spent(x, freed, starts, unit) > 2.0 * max_outside:  # beyond what the restores could win back
            return freed, x, False
    for s in starts:  # restore what the later choices made unnecessary
        e = min(s + unit, f)
        if not freed[s]:
            continue
        cnt[s:e] = count[s:e]
        qv = _set_units(verts, cnt, d, s, e, qv, qc, meet, box)
        x2, _ = interval_profile(qv, qc, d, True)
        if profile_duration(x2, d) <= duration:
            freed[s:e] = False
            x = x2
        else:
            cnt[s:e] = 0
            qv = _set_units(verts, cnt, d, s, e, qv, qc, meet, box)
    return freed, x, _all_spent(x, freed, starts, unit) <= max_outside


def extreme_profile(verts: np.ndarray, count: np.ndarray, d: float, fastest: bool,
                    box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fastest (``fastest``) or slowest profile inside the padded polygons (:func:`padded`) of
    frames ``d`` s apart, and where the chain broke (an empty polygon, two frames' polygons that do
    not meet, or no way on inside)."""
    qv, qc, meet = interval_polygons(verts, count, d, box)
    x, broken = interval_profile(qv, qc, d, fastest)
    return x, broken | (count == 0) | ~meet


def fastest_timing(polys: FeasiblePolygons, fps: float) -> PathTiming:
    """The shortest timing whose every instant lies inside its nearest source frame's polygon
    (TOPP-RA, MPS06 §3.3).

    Exact for the polygons given, with p̈ constant between source frames: no such timing is
    shorter. Where a polygon is empty or the chain breaks the timing is not ``inside`` and
    ``broken`` says where. O(F · K²).
    """
    verts, count, box = padded(polys)
    x, broken = extreme_profile(verts, count, 1.0 / fps, True, box)
    where = np.flatnonzero(broken)
    return PathTiming(x=x, duration=profile_duration(x, 1.0 / fps), inside=not len(where), broken=where)
