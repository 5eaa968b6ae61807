"""The guided warp driver, its parameters and result, and the linear baseline (HDP07 §3-4; design §7)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from motionweb.store.kinematics import (
    resample,
)
from motionweb.store.motion import Motion
from motionweb.tasks.guided_warp.features import (
    feature_spec,
    local_scores,
    motion_track,
    reference_features,
    torso_positions,
)
from motionweb.tasks.guided_warp.heuristic import band_windows, coarse_solution
from motionweb.tasks.guided_warp.paths import dag_path, feasible_windows, fixed_length_path
from motionweb.tasks.guided_warp.postprocess import apply_warp, smooth_warp
from motionweb.tasks.guided_warp.reduction import Keytime, reduce_to_compression
from motionweb.tasks.params.warp import WarpParams

# ----------------------------------------------------------------------------------------------------------
# Results


@dataclass(frozen=True, eq=False)
class WarpResult:
    """A computed time warp.

    Attributes:
        frames: (m,) int, the discrete path in *working* input frames (after upsampling/reversal).
        raw_times: (m,) float, that path as source times in original input frames.
        times: (m,) float, the smoothed warp: output frame p shows the input at ``times[p]`` frames.
        cost: objective value (HDP07 eq. 1) of the discrete path (0 for the linear baseline).
        motion: the warped motion (input skeleton, fps and units), or None when not resampled.
        keytimes: the (input frame, output frame) pairs the warp interpolates, endpoints included.
        upsample: integer upsampling factor of the reduction to compression (1 = none).
        backward: whether the input was reversed.
        heuristic: whether the §3.3 band heuristic was used (and did not fall back to the full search).
        timings: seconds spent in 'features', 'objective', 'optimization', 'heuristic', 'postprocess'.
    """

    frames: np.ndarray
    raw_times: np.ndarray
    times: np.ndarray
    cost: float
    motion: Motion | None
    keytimes: list[Keytime]
    upsample: int = 1
    backward: bool = False
    heuristic: bool = False
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def n_out(self) -> int:
        return len(self.times)

    def speed(self) -> np.ndarray:
        """(m,) local playback speed: source frames per output frame (central differences)."""
        return np.gradient(self.times)


# Drivers


def check_compatible(motion: Motion, reference: Motion) -> None:
    """Same skeleton (names and hierarchy) and a reference of at least 3 frames, else ValueError."""
    a, b = motion.skeleton, reference.skeleton
    if a.n_joints != b.n_joints or a.signature() != b.signature():
        raise ValueError(
            f"input and reference have different skeletons ({a.n_joints} vs {b.n_joints} joints, "
            f"signature {a.signature()} vs {b.signature()}); HDP07 needs the same skeleton"
        )
    if reference.n_frames < 3:
        raise ValueError(f"the reference needs at least 3 frames, got {reference.n_frames}")


def _with_fps(reference: Motion, fps: float) -> Motion:
    return reference if abs(reference.fps - fps) < 1e-9 else resample(reference, fps)


def guided_warp(
    motion: Motion,
    reference: Motion | None = None,
    *,
    n_out: int | None,
    keytimes: Sequence[Keytime] = (),
    params: WarpParams | None = None,
    fast: bool = False,
    backward: bool = False,
    up: str = "y",
    resample_motion: bool = True,
    scores: dict | None = None,
) -> WarpResult:
    """Guided time warp of ``motion`` towards the timing of ``reference`` (HDP07 §3).

    Args:
        motion: the input x_1..x_n.
        reference: the timing model z_1..z_r (same skeleton); None uses the input itself (§4.1).
        n_out: output frame count m (at the input's fps), or None for the unconstrained warp.
        keytimes: intermediate (input frame, output frame) pairs the warp must interpolate.
        params: the warp's parameters (:class:`WarpParams`: skip s, k of the kNN score, prefilter,
            feature weights and normalisation, heuristic rate and band, smoothing).
        fast: use the §3.3 heuristic (coarse solve at 1/``params.heuristic_rate``, then a full-rate
            search within ``params.band`` working frames of it; falls back to the full search if the
            band is empty).
        backward: play the input backwards (keytime input frames then decrease).
        resample_motion: build the output motion (else ``motion`` in the result is None).
        scores: a dict the caller keeps for one (``motion``, ``reference``, ``params``, ``up``): the
            local scores (n, s, s) are stored in it by working input (upsample factor, direction)
            and reused, since they do not depend on the output length or the keytimes (HDP07
            §3.2: f scores input triples against the reference), which then cost only the path
            (the editing sessions of ``motionweb app``); the result is the same as without it.

    Cost: O(n s² (r + D)) for the scores and O(m n s²) for the path (O(n s²) unconstrained).
    """
    p = params if params is not None else WarpParams()
    skip, neighbours, filter_width = p.skip, p.neighbours, p.filter_width
    reference = motion if reference is None else reference
    check_compatible(motion, reference)
    n0 = motion.n_frames
    red = reduce_to_compression(n0, n_out, keytimes, skip, backward)
    timings: dict[str, float] = {}

    key = (red.upsample, red.backward, red.n)
    table = None if scores is None else scores.get(key)
    if table is None:
        t0 = time.perf_counter()
        track0 = motion_track(motion, filter_width, up)
        ref_track = motion_track(_with_fps(reference, motion.fps), filter_width, up)
        track = track0.sample(red.to_source(np.arange(red.n), n0))
        spec = feature_spec(ref_track, p.weights, p.normalize, p.root_motion)
        ref_f = reference_features(ref_track, spec)
        timings["features"] = time.perf_counter() - t0

        t0 = time.perf_counter()
        table = local_scores(track, ref_f, skip, spec, neighbours)
        timings["objective"] = time.perf_counter() - t0
        if scores is not None:
            scores[key] = table

    used_heuristic = False
    t0 = time.perf_counter()
    if red.m is None:
        path, cost = dag_path(table)
        timings["optimization"] = time.perf_counter() - t0
        if not np.isfinite(cost):
            raise ValueError("no admissible warp: every path through the input has an infinite score")
    else:
        lo, hi = feasible_windows(red.n, red.m, skip, red.keys)
        path, cost = np.zeros(0, dtype=np.int64), np.inf
        if fast:
            coarse = coarse_solution(table, red, skip, p.heuristic_rate)
            if coarse is not None:
                blo, bhi = band_windows(coarse, red.m, p.band, lo, hi)
                if np.all(blo <= bhi):
                    path, cost = fixed_length_path(table, red.m, blo, bhi)
            used_heuristic = bool(np.isfinite(cost))
            timings["heuristic"] = time.perf_counter() - t0
        if not np.isfinite(cost):
            t1 = time.perf_counter()
            path, cost = fixed_length_path(table, red.m, lo, hi)
            timings["optimization"] = time.perf_counter() - t1
        if not np.isfinite(cost):
            raise ValueError("no admissible warp satisfies the constraints")

    t0 = time.perf_counter()
    raw = red.to_source(path, n0)
    anchors = [o for _, o in red.keys]
    times = smooth_warp(raw, p.smooth_width, anchors)
    out = None
    if resample_motion:
        out = replace(apply_warp(motion, times, p.adaptive_smoothing), name=f"{motion.name}_warped", content_hash="",
                      source=None)
    timings["postprocess"] = time.perf_counter() - t0
    keys_src = [(float(red.to_source(np.array([i]), n0)[0]), float(o)) for i, o in red.keys]
    if red.m is None:
        keys_src = [(float(raw[0]), 0.0), (float(raw[-1]), float(len(raw) - 1))]
    return WarpResult(frames=path, raw_times=raw, times=times, cost=float(cost), motion=out,
                      keytimes=keys_src, upsample=red.upsample, backward=red.backward,
                      heuristic=used_heuristic, timings=timings)


def linear_warp(motion: Motion, n_out: int, keytimes: Sequence[Keytime] = (), adaptive: bool = True,
                resample_motion: bool = True) -> WarpResult:
    """The spline-free baseline: a piecewise-linear warp through the keytimes (HDP07 §4.1, Fig. 2)."""
    n0 = motion.n_frames
    if n_out < 2:
        raise ValueError(f"the output needs at least 2 frames, got {n_out}")
    full = [(0.0, 0.0), *sorted((float(i), float(o)) for i, o in keytimes), (float(n0 - 1), float(n_out - 1))]
    ins = np.array([i for i, _ in full])
    outs = np.array([o for _, o in full])
    if np.any(np.diff(outs) <= 0) or np.any(np.diff(ins) <= 0):
        raise ValueError("keytimes must be strictly increasing in input and output time")
    times = np.interp(np.arange(n_out), outs, ins)
    out = replace(apply_warp(motion, times, adaptive), name=f"{motion.name}_linear") if resample_motion else None
    return WarpResult(frames=np.round(times).astype(np.int64), raw_times=times, times=times, cost=0.0,
                      motion=out, keytimes=list(zip(ins.tolist(), outs.tolist(), strict=True)))


def pose_error(a: Motion, b: Motion, up: str = "y") -> float:
    """RMS distance of heading-frame joint positions between two equally long motions (file units)."""
    if a.n_frames != b.n_frames:
        raise ValueError(f"motions differ in length ({a.n_frames} vs {b.n_frames} frames)")
    pa = torso_positions(motion_track(a, 1, up))
    pb = torso_positions(motion_track(b, 1, up))
    return float(np.sqrt(np.mean(np.sum((pa - pb) ** 2, axis=-1))))


def playback_speed(times: np.ndarray, f0: float, f1: float) -> float:
    """Mean playback speed of source frames f0..f1 under a warp: source time per output time.

    ``times`` (m,) is the (increasing) source frame of each output frame, e.g. ``WarpResult.times``;
    1 means the span plays at its original speed (HDP07 §4.1's preservation measure)."""
    out = np.arange(len(times))
    return (f1 - f0) / (np.interp(f1, times, out) - np.interp(f0, times, out))
