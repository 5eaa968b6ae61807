"""A timing of the requested duration along the path, inside the polygons where it can be (design §8, MPS06 §3.3).

MPS06 pulls a smooth spline p(t) toward the feasible polygons (Eqn. 14); near the shortest
duration such a spline cannot follow polygons that change frame by frame. Here the timing is
built on the source frames instead, from the reachability profiles of :mod:`.reachable`
(x = ṗ² per source frame, p̈ constant between frames):

* a duration between the fastest and the slowest timing inside every polygon is met inside them:
  the profile moves from the original timing (x = 1) toward the fastest (slowest) one by the
  same fraction θ everywhere, x_θ = 1 + θ (x_ext − 1), θ by bisection. The set of profiles inside
  the polygons is convex (each constraint is linear in two neighbouring x), so x_θ is inside
  wherever the original timing is;
* a duration below the fastest leaves the polygons on as few output frames as a greedy finds
  (:func:`.reachable.free_frames`): it frees (replaces by the (p̈, ṗ²) box the polygons were
  clipped to) the source frames that buy the most output time per output frame left outside
  (a frame in flight counting :data:`FLIGHT_WEIGHT` frames, so the flight keeps its speed while
  the ground phases can pay), until the fastest timing of the rest fits, then restores any freed frame no longer needed;
  the profile then moves from the original toward that fastest one as above;
* the timing is the exact piecewise-quadratic p(t) of the profile (:class:`PathCurve`).

Cost: O(F · K²) per reachability pass (F source frames, K polygon vertices); the greedy runs
O(F / w) passes per freed unit of w frames (w = ⌈F / 256⌉), so O(n_freed · F² · K² / w) in all,
compiled (16_06, 407 frames, in half its length: 0.2 s).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from motionweb.tasks.retime.objective import BakedObjective, objective_kernel
from motionweb.tasks.retime.polygons import FeasiblePolygons
from motionweb.tasks.retime.reachable import UNITS, extreme_profile, free_frames, padded, profile_duration
from motionweb.tasks.retime.spline import RetimeResult

#: units the greedy may free per step (reachable.free_frames): one step ranks them all, so
#: taking the top few whose savings still fit cuts the steps ~BATCH-fold
BATCH = 8
#: a freed flight frame counts as this many output frames outside: a ballistic flight played
#: faster is what a viewer sees first (MPS06 §4.1: "leaving the flight phase intact"), so the
#: greedy buys time on the ground first
FLIGHT_WEIGHT = 10.0


@dataclass(frozen=True, eq=False)
class PathCurve:
    """p(t) of a profile x = ṗ² on source frames (F,): p̈ = (x[i+1] − x[i]) / (2 d) on each frame
    interval, so p is piecewise quadratic in t and ṗ continuous (MPS06 Eqn. 3-4).

    Attributes:
        x: (F,) ṗ² at the source frames; fps: source frames per second;
        out: (F,) output time at which p reaches each source frame (out[-1]: the duration).
    """

    x: np.ndarray
    fps: float
    out: np.ndarray

    @classmethod
    def of(cls, x: np.ndarray, fps: float) -> PathCurve:
        s = np.sqrt(x)
        return cls(x=x, fps=fps, out=np.concatenate([[0.0], np.cumsum(2.0 / fps / (s[1:] + s[:-1]))]))

    def evaluate(self, z: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """p, ṗ, p̈ at output times ``t`` (``z`` unused: the curve has no free parameters)."""
        t = np.clip(np.asarray(t, float), 0.0, self.out[-1])
        i = np.clip(np.searchsorted(self.out, t, side="right") - 1, 0, len(self.x) - 2)
        d = 1.0 / self.fps
        a = (self.x[i + 1] - self.x[i]) / (2.0 * d)
        tau = t - self.out[i]
        v0 = np.sqrt(self.x[i])
        return i * d + v0 * tau + 0.5 * a * tau * tau, v0 + a * tau, a


@dataclass(frozen=True, eq=False)
class PathProfile:
    """A profile of one duration: x (F,) ṗ²; freed (F,) source frames left outside their polygon
    by construction; theta: how far it moved from the original timing toward the extreme one."""

    x: np.ndarray
    freed: np.ndarray
    theta: float


def profile_of_duration(polys: FeasiblePolygons, fps: float, duration: float, max_outside: float = 0.5,
                        weight: np.ndarray | None = None) -> PathProfile | None:
    """A profile lasting ``duration`` output seconds, inside the polygons where it can be (module doc).

    ``weight`` (F,): how many output frames outside a freed source frame counts as in the greedy's
    ranking (default 1 each; :func:`frame_weights`).

    None for a clip of one frame, where the greedy cannot reach the duration with at most
    ``max_outside`` of the output frames left outside, or where no profile inside is slow enough.
    O(F · K²) inside the reachable range; the greedy's cost below it (module doc).
    """
    verts, count, box = padded(polys)
    f = len(count)
    if f < 2:
        return None
    d = 1.0 / fps
    one = np.ones(f)
    original = (f - 1) * d
    freed = np.zeros(f, bool)
    if abs(duration - original) <= 1e-12 * original:
        return PathProfile(x=one, freed=freed, theta=0.0)
    ext, _ = extreme_profile(verts, count, d, duration < original, box)
    if duration < original and profile_duration(ext, d) > duration:
        w = np.ones(f) if weight is None else np.asarray(weight, dtype=np.float64)
        freed, ext, ok = free_frames(verts, count, d, duration, max(1, -(-f // UNITS)), max_outside * duration * fps,
                                     BATCH, box, w)
        if not ok:
            return None
    elif duration > original and profile_duration(ext, d) < duration:
        return None
    lo, hi = 0.0, 1.0
    slower = duration > original
    for _ in range(100):  # x_θ's duration runs from the original's (θ = 0) to the extreme's (θ = 1)
        mid = 0.5 * (lo + hi)
        longer = profile_duration(1.0 + mid * (ext - 1.0), d) > duration
        lo, hi = (lo, mid) if longer == slower else (mid, hi)
    theta = 0.5 * (lo + hi)
    return PathProfile(x=1.0 + theta * (ext - 1.0), freed=freed, theta=theta)


def path_objective(obj: BakedObjective, curve: PathCurve, n_s: int) -> float:
    """MPS06 Eqn. 14 of a path timing on ``n_s`` midpoint samples (the spline's estimate, each
    sample its own control point: p, ṗ, p̈ weights one-hot). O(S · K)."""
    duration = float(curve.out[-1])
    edges = np.linspace(0.0, duration, n_s + 1)
    p, pd, pdd = curve.evaluate(np.empty(0), 0.5 * (edges[1:] + edges[:-1]))
    c = np.stack([p, pd, pdd], axis=1).ravel()
    ctrl = (3 * np.arange(n_s)[:, None] + np.array([0, 1, 2, 2])).astype(np.int64)
    w = np.zeros((3, n_s, 4))
    w[0, :, 0] = w[1, :, 1] = w[2, :, 2] = 1.0
    value, _ = objective_kernel(obj.verts, obj.count, obj.inv_len2, obj.solid, obj.center, obj.theta0, obj.theta,
                                obj.coef, obj.alpha, ctrl, w, c, float(curve.fps), duration / n_s)
    return float(value)


def frame_weights(in_contact: np.ndarray) -> np.ndarray:
    """(F,) the greedy's count per freed source frame: :data:`FLIGHT_WEIGHT` for a frame with no
    foot down (``in_contact`` (F,) bool), 1 otherwise."""
    return np.where(in_contact, 1.0, FLIGHT_WEIGHT)


def path_timing(polys: FeasiblePolygons, obj: BakedObjective, fps: float, duration: float,
                samples_per_frame: int, weight: np.ndarray | None = None) -> RetimeResult | None:
    """The path timing of ``duration`` (:func:`profile_of_duration`, ``weight`` as there) sampled
    at the output frames, with its MPS06 Eqn. 14 value, its integral sampled at ``samples_per_frame``
    per source frame at the fastest playback (required: ``SplineParams`` holds the default); None
    where there is none."""
    t0 = time.perf_counter()
    prof = profile_of_duration(polys, fps, duration, weight=weight)
    if prof is None:
        return None
    curve = PathCurve.of(prof.x, fps)
    total = float(curve.out[-1])
    n_out = round(total * fps) + 1
    t = np.minimum(np.arange(n_out) / fps, total)
    p, pd, pdd = curve.evaluate(np.empty(0), t)
    n_s = int(np.ceil(samples_per_frame * len(prof.x) * max(float(np.sqrt(prof.x).max()), 1.0)))
    freed = int(prof.freed.sum())
    toward = "slowest" if duration > (len(prof.x) - 1) / fps else "fastest"
    return RetimeResult(spline=curve, z=np.empty(0), t=t, p=p, pd=pd, pdd=pdd, objective=path_objective(obj, curve, n_s),
                        n_samples=n_s, iterations=0, seconds=time.perf_counter() - t0, converged=True, kind="path",
                        message=f"path timing: θ = {prof.theta:.4f} toward the {toward} timing inside the polygons; "
                                f"{freed} source frames freed")
