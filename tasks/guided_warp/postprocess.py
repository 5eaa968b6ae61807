"""Postprocessing of a discrete warp: moving average, slerp resampling, adaptive smoothing (HDP07 §3.4)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from motionweb.store.kinematics import (
    quat_normalize,
    sample_motion,
)
from motionweb.store.motion import Motion

# Postprocessing (HDP07 §3.4)


def smooth_warp(times: np.ndarray, width: int, anchors: Sequence[int] = ()) -> np.ndarray:
    """Moving average of a warp over ``width`` output frames (HDP07 §3.4).

    Each span between anchors (keytime output frames; the ends always) is padded by odd reflection
    about its end values, so the anchors keep their exact times and linear warps are unchanged;
    a strictly increasing warp stays strictly increasing.
    """
    t = np.asarray(times, dtype=np.float64).copy()
    if width <= 1 or len(t) < 3:
        return t
    half = width // 2
    cuts = sorted({0, len(t) - 1, *(int(a) for a in anchors)})
    out = t.copy()
    for c0, c1 in itertools.pairwise(cuts):
        seg = t[c0:c1 + 1]
        h = min(half, len(seg) - 1)
        if h < 1:
            continue
        left = 2.0 * seg[0] - seg[h:0:-1]
        right = 2.0 * seg[-1] - seg[-2:-h - 2:-1]
        padded = np.concatenate([left, seg, right])
        kernel = np.ones(2 * h + 1) / (2 * h + 1)
        out[c0:c1 + 1] = np.convolve(padded, kernel, mode="valid")
    out[cuts] = t[cuts]  # equal in exact arithmetic; remove the round-off
    return out


def apply_warp(motion: Motion, times: np.ndarray, adaptive: bool = True, max_taps: int = 33) -> Motion:
    """Resample ``motion`` at fractional source frames ``times`` (slerp), HDP07 §3.4.

    With ``adaptive``, output frame p is the average of the input over a source window as wide as
    the local compression c_p = (t_{p+1} - t_{p-1}) / 2 frames (a box spanning c_p - 1 frame
    intervals, so nothing changes where c_p <= 1): each window is sampled at evenly spaced taps
    (normalised quaternion mean, hemisphere-aligned).
    """
    times = np.asarray(times, dtype=np.float64)
    base = sample_motion(motion, times)
    if not adaptive or len(times) < 3:
        return base
    c = np.abs(np.gradient(times))
    width = np.maximum(c - 1.0, 0.0)  # a box of c frames spans c - 1 frame intervals
    taps = int(min(max_taps, max(1, math.ceil(width.max()) + 1)))
    if taps <= 1:
        return base
    if taps % 2 == 0:
        taps += 1
    offs = np.linspace(-0.5, 0.5, taps)
    sample_t = np.clip(times[:, None] + width[:, None] * offs[None, :], 0.0, motion.n_frames - 1)
    many = sample_motion(motion, sample_t.ravel())
    m, j = len(times), motion.skeleton.n_joints
    q = many.rotations.reshape(m, taps, j, 4)
    centre = q[:, taps // 2: taps // 2 + 1]
    q = np.where(np.sum(q * centre, axis=-1, keepdims=True) < 0.0, -q, q)
    rot = quat_normalize(q.mean(axis=1))
    root = many.root_positions.reshape(m, taps, 3).mean(axis=1)
    trans = {k: tr.reshape(m, taps, 3).mean(axis=1) for k, tr in many.translations.items()}
    return replace(base, rotations=rot, root_positions=root, translations=trans)


# ----------------------------------------------------------------------------------------------------------
