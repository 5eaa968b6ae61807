"""Perturbations of a demo clip for tests and benchmarks: smooth random time warps and small pose noise."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from motionweb.store.kinematics import quat_from_axis_angle, quat_mul, sample_motion
from motionweb.store.motion import Motion


def time_warp_clip(motion: Motion, warp_frames: np.ndarray) -> Motion:
    """The clip sampled at fractional source frames ``warp_frames`` (slerp rotations, lerp root)."""
    out = sample_motion(motion, np.asarray(warp_frames, dtype=np.float64))
    return replace(out, name=f"{motion.name}_warped", source=None, content_hash="")


def random_warp(n_out: int, n_in: int, rng: np.random.Generator,
                speed_range: tuple[float, float] = (0.7, 1.5)) -> np.ndarray:
    """A smooth, strictly increasing, non-linear warp: source frame index per output frame, from 0
    to n_in - 1 exactly, with local speed (source frames per output frame) inside speed_range."""
    lo, hi = speed_range
    if n_out < 2 or n_in < 2:
        raise ValueError("random_warp needs at least 2 frames on each side")
    mean = (n_in - 1) / (n_out - 1)
    if not (0 < lo < mean < hi):
        raise ValueError(f"mean speed {mean:.3f} (= (n_in-1)/(n_out-1)) must lie strictly inside {speed_range}")
    x = (np.arange(n_out - 1) + 0.5) / (n_out - 1)
    z = np.zeros_like(x)
    for _ in range(3):
        z += rng.uniform(0.3, 1.0) * np.sin(2 * np.pi * rng.uniform(0.5, 2.5) * x + rng.uniform(0, 2 * np.pi))
    z -= z.mean()
    amp = 0.9 * min(hi - mean, mean - lo) / max(float(np.max(np.abs(z))), 1e-12)
    speed = mean + amp * z
    warp = np.concatenate([[0.0], np.cumsum(speed)])
    warp *= (n_in - 1) / warp[-1]
    warp[-1] = n_in - 1
    return warp


def pose_noise(motion: Motion, rng: np.random.Generator, deg: float = 1.0, metres: float = 0.003) -> Motion:
    """``motion`` with small white pose noise: every joint turned by a random rotation of normal
    angle (σ = ``deg`` degrees) about a random axis each frame, the root moved by σ = ``metres``."""
    f, j = motion.rotations.shape[:2]
    axes = rng.normal(size=(f, j, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    dq = quat_from_axis_angle(axes, np.deg2rad(rng.normal(0.0, deg, size=(f, j))))
    return replace(motion, rotations=quat_mul(motion.rotations, dq),
                   root_positions=motion.root_positions + rng.normal(0.0, metres / motion.metres(), size=(f, 3)))


