"""Small motions and skeletons shared by the tests (imported by module name: ``from fixtures import ...``)."""

from __future__ import annotations

import numpy as np
from motionweb.store.kinematics import quat_from_axis_angle, quat_from_euler
from motionweb.store.motion import Motion, Skeleton

ROT_CH = ("Zrotation", "Xrotation", "Yrotation")
G = 9.81
THIGH = SHANK = 0.45


def tiny_motion(frames: int, fps: float, names: tuple[str, ...] = ("hips", "knee")) -> Motion:
    sk = Skeleton(
        names=names,
        parents=np.arange(len(names)) - 1,
        offsets=np.tile([0.0, -0.4, 0.0], (len(names), 1)),
        channels=(("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),)
        + (("Zrotation", "Xrotation", "Yrotation"),) * (len(names) - 1),
    )
    rot = np.zeros((frames, len(names), 4))
    rot[..., 0] = 1.0
    root = np.zeros((frames, 3))
    root[:, 2] = np.linspace(0, 1, frames)
    return Motion(skeleton=sk, fps=fps, root_positions=root, rotations=rot)


def small_skeleton(unit: str = "m") -> Skeleton:
    """A 9-joint body (hips, spine, head, two legs with knees, two arms), offsets in ``unit`` (m or cm)."""
    k = {"m": 1.0, "cm": 100.0}[unit]
    names = ("hips", "spine", "head", "lleg", "lknee", "rleg", "rknee", "larm", "rarm")
    parents = np.array([-1, 0, 1, 0, 3, 0, 5, 1, 1])
    offs = k * np.array([[0, 0, 0], [0, .3, 0], [0, .3, 0], [.1, 0, 0], [0, -.45, 0], [-.1, 0, 0], [0, -.45, 0],
                         [.2, .25, 0], [-.2, .25, 0]])
    ch = (("Xposition", "Yposition", "Zposition", *ROT_CH),) + (ROT_CH,) * 8
    return Skeleton(names, parents, offs, ch)


def wiggle(n: int, fps: float, seed: int, unit: str = "m") -> Motion:
    """(n frames) random smooth joint rotations and a root wandering forward at ~1 m/s, on
    :func:`small_skeleton` in ``unit``."""
    rng = np.random.default_rng(seed)
    sk = small_skeleton(unit)
    t = np.arange(n) / fps
    ang = np.zeros((n, sk.n_joints, 3))
    for j in range(sk.n_joints):
        for a in range(3):
            for _ in range(3):
                ang[:, j, a] += rng.uniform(2, 13) * np.sin(2 * np.pi * rng.uniform(0.1, 1.2) * t + rng.uniform(0, 6))
    yaw = np.cumsum(rng.normal(0, 0.3, n)) / fps * 20
    ang[:, 0, 2] += yaw
    root = np.stack([np.cumsum(np.sin(np.deg2rad(yaw))) / fps, np.full(n, 0.95),
                     np.cumsum(np.cos(np.deg2rad(yaw))) / fps], axis=1)
    root *= {"m": 1.0, "cm": 100.0}[unit]
    return Motion(sk, fps, root, quat_from_euler(ang, "ZXY"), name=f"wiggle{seed}", unit=unit)


def jumper_skeleton() -> Skeleton:
    """Pelvis, chest and two 3-joint legs (hip, knee, ankle with a toe end site), metres, Y up."""
    names = ("pelvis", "chest", "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle")
    parents = np.array([-1, 0, 0, 2, 3, 0, 5, 6])
    offsets = np.array([[0, 0, 0], [0, 0.3, 0], [0.1, -0.05, 0], [0, -THIGH, 0], [0, -SHANK, 0],
                        [-0.1, -0.05, 0], [0, -THIGH, 0], [0, -SHANK, 0]], dtype=float)
    rot = ("Zrotation", "Xrotation", "Yrotation")
    channels = (("Xposition", "Yposition", "Zposition") + rot,) + (rot,) * 7
    ends = {1: np.array([0, 0.4, 0.0]), 4: np.array([0, -0.05, 0.15]), 7: np.array([0, -0.05, 0.15])}
    return Skeleton(names, parents, offsets, channels, ends)


def hermite(y0: float, v0: float, y1: float, v1: float, T: float, t: np.ndarray) -> np.ndarray:
    s = t / T
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * y0 + h10 * T * v0 + h01 * y1 + h11 * T * v1


def synthetic_jump(fps: float = 40.0, g: float = G, v0: float = 2.0, stand: float = 0.4, bend: float = 0.4
                   ) -> tuple[Motion, tuple[float, float]]:
    """An in-place jump whose flight is exactly ballistic under gravity ``g`` (pose frozen in flight).

    Returns the motion and the flight interval (take-off, landing) in seconds.
    """
    y_stand, y_low, y_off = 0.95, 0.75, 0.98
    phases = [stand, bend, 0.3, 2 * v0 / g, 0.3, bend, stand]
    ends = np.cumsum(phases)
    n = int(np.floor(ends[-1] * fps)) + 1
    t = np.arange(n) / fps
    y = np.empty(n)
    for i, ti in enumerate(t):
        k = int(np.searchsorted(ends, ti, side="right"))
        k = min(k, len(phases) - 1)
        s = ti - (ends[k - 1] if k else 0.0)
        y[i] = [lambda s: y_stand,
                lambda s: hermite(y_stand, 0, y_low, 0, phases[1], s),
                lambda s: hermite(y_low, 0, y_off, v0, phases[2], s),
                lambda s: y_off + v0 * s - 0.5 * g * s * s,
                lambda s: hermite(y_off, -v0, y_low, 0, phases[4], s),
                lambda s: hermite(y_low, 0, y_stand, 0, phases[5], s),
                lambda s: y_stand][k](s)
    takeoff, landing = ends[2], ends[3]
    # legs: ankle 0.05 above the ground under the hip; frozen at the take-off pose in flight
    d = np.where((t > takeoff) & (t < landing), y_off, y) - 0.05 - 0.05
    d = np.minimum(d, THIGH + SHANK - 1e-6)
    knee = np.pi - np.arccos((THIGH**2 + SHANK**2 - d**2) / (2 * THIGH * SHANK))
    hip = knee / 2
    x = np.array([1.0, 0.0, 0.0])
    rot = np.zeros((n, 8, 4))
    rot[..., 0] = 1.0
    for base in (2, 5):
        rot[:, base] = quat_from_axis_angle(x, -hip)
        rot[:, base + 1] = quat_from_axis_angle(x, knee)
        rot[:, base + 2] = quat_from_axis_angle(x, -hip)
    rot[:, 1] = quat_from_axis_angle(x, 0.1 * np.sin(t))  # a little chest sway
    root = np.zeros((n, 3))
    root[:, 1] = y
    motion = Motion(jumper_skeleton(), fps, root, rot, name="synthetic_jump", unit="m")
    return motion, (float(takeoff), float(landing))
