"""A seeded, procedural, synthetic demo corpus: the project's own data (no downloads).

Every clip is built from a plan (root path, foot plants, upper-body angles, effector targets) and
turned into joint rotations by analytic two-bone IK for legs and arms, so the ground truth (foot
stance intervals, exact ballistic flights, effector targets at apex frames) holds by construction.
Units are metres, Y is up, the character faces +Z in its rest pose, quaternions are (w, x, y, z).

Public API: :func:`humanoid_skeleton`, :data:`CATEGORIES`, :func:`generate_clip`,
:func:`walk_then_jump`, :func:`time_warp_clip`, :func:`random_warp`, :func:`pose_noise`,
:func:`write_demo_corpus`.
"""

from __future__ import annotations

import json
import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from motionweb.store.bvh import write_bvh
from motionweb.store.kinematics import (
    forward_kinematics,
    heading_angle,
    quat_from_axis_angle,
    quat_from_matrix,
    quat_inv,
    quat_mul,
    quat_rotate,
    quat_to_matrix,
    sample_motion,
)
from motionweb.store.motion import Motion, Skeleton

#: gravity (m/s²) used by every ballistic flight.
G = 9.81
#: the clip categories of the demo corpus.
CATEGORIES: tuple[str, ...] = ("walk", "run", "jump", "kick", "punch", "reach", "hop", "sit", "idle")
SIDES = ("left", "right")

_ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
_ROT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
_X = np.array([1.0, 0.0, 0.0])
_Y = np.array([0.0, 1.0, 0.0])
_Z = np.array([0.0, 0.0, 1.0])

# name, parent, offset (m, for a 1.75 m adult), end-site offset
_LAYOUT: tuple[tuple[str, str | None, tuple[float, float, float], tuple[float, float, float] | None], ...] = (
    ("Hips", None, (0.0, 0.0, 0.0), None),
    ("Spine", "Hips", (0.0, 0.10, 0.0), None),
    ("Spine1", "Spine", (0.0, 0.12, 0.0), None),
    ("Spine2", "Spine1", (0.0, 0.12, 0.0), None),
    ("Neck", "Spine2", (0.0, 0.16, 0.0), None),
    ("Head", "Neck", (0.0, 0.10, 0.0), (0.0, 0.16, 0.0)),
    ("LeftShoulder", "Spine2", (0.03, 0.12, 0.0), None),
    ("LeftArm", "LeftShoulder", (0.15, 0.0, 0.0), None),
    ("LeftForeArm", "LeftArm", (0.0, -0.29, 0.0), None),
    ("LeftHand", "LeftForeArm", (0.0, -0.26, 0.0), (0.0, -0.09, 0.0)),
    ("RightShoulder", "Spine2", (-0.03, 0.12, 0.0), None),
    ("RightArm", "RightShoulder", (-0.15, 0.0, 0.0), None),
    ("RightForeArm", "RightArm", (0.0, -0.29, 0.0), None),
    ("RightHand", "RightForeArm", (0.0, -0.26, 0.0), (0.0, -0.09, 0.0)),
    ("LeftUpLeg", "Hips", (0.09, -0.06, 0.0), None),
    ("LeftLeg", "LeftUpLeg", (0.0, -0.43, 0.0), None),
    ("LeftFoot", "LeftLeg", (0.0, -0.42, 0.0), None),
    ("LeftToeBase", "LeftFoot", (0.0, -0.06, 0.13), (0.0, 0.0, 0.05)),
    ("RightUpLeg", "Hips", (-0.09, -0.06, 0.0), None),
    ("RightLeg", "RightUpLeg", (0.0, -0.43, 0.0), None),
    ("RightFoot", "RightLeg", (0.0, -0.42, 0.0), None),
    ("RightToeBase", "RightFoot", (0.0, -0.06, 0.13), (0.0, 0.0, 0.05)),
)
_NOMINAL_HEIGHT = 1.75
#: height of the toe joint (ball of the foot) above the ground when the foot is flat, at 1.75 m.
_TOE_RADIUS = 0.02


def humanoid_skeleton(height: float = _NOMINAL_HEIGHT) -> Skeleton:
    """A 22-joint humanoid in metres (Y up, facing +Z, arms hanging), scaled to ``height``.

    The root ``Hips`` has 6 channels, every other joint ``Zrotation Xrotation Yrotation``; end sites
    sit on the head, the hands and the toes. At zero rotations the figure stands with straight
    legs, flat feet (toe joints 2 cm above the ground once the root is at standing height).
    """
    s = height / _NOMINAL_HEIGHT
    names = tuple(n for n, *_ in _LAYOUT)
    parents = np.array([-1 if p is None else names.index(p) for _, p, _, _ in _LAYOUT])
    offsets = np.array([o for _, _, o, _ in _LAYOUT]) * s
    channels = tuple(_ROOT_CHANNELS if p is None else _ROT_CHANNELS for _, p, _, _ in _LAYOUT)
    ends = {k: np.array(e) * s for k, (_, _, _, e) in enumerate(_LAYOUT) if e is not None}
    return Skeleton(names=names, parents=parents, offsets=offsets, channels=channels, end_sites=ends)


# --------------------------------------------------------------------------------------------------
# small math helpers (vectorized over frames)


def _smooth(u: np.ndarray | float) -> np.ndarray:
    """Cubic ease 3u² - 2u³ on [0, 1] (clamped): C1 with zero end slopes."""
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _hermite(t: np.ndarray, kt: Any, kp: Any, kv: Any = None) -> np.ndarray:
    """C1 cubic Hermite through knots (times kt (K,), values kp (K, D), slopes kv (K, D), zero by
    default), constant outside the knot range. Returns (F, D)."""
    t = np.asarray(t, dtype=np.float64)
    kt = np.asarray(kt, dtype=np.float64)
    kp = np.asarray(kp, dtype=np.float64).reshape(len(kt), -1)
    kv = np.zeros_like(kp) if kv is None else np.asarray(kv, dtype=np.float64).reshape(kp.shape)
    if len(kt) == 1:
        return np.broadcast_to(kp[0], (len(t), kp.shape[1])).copy()
    i = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, len(kt) - 2)
    h = (kt[i + 1] - kt[i])[:, None]
    s = np.clip((t - kt[i])[:, None] / h, 0.0, 1.0)
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1) * kp[i] + (s3 - 2 * s2 + s) * h * kv[i]
            + (-2 * s3 + 3 * s2) * kp[i + 1] + (s3 - s2) * h * kv[i + 1])


def _qaxis(axis: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    angle = np.asarray(angle, dtype=np.float64)
    return quat_from_axis_angle(np.broadcast_to(axis, angle.shape + (3,)), angle)


def _qypr(yaw: Any, pitch: Any = 0.0, roll: Any = 0.0) -> np.ndarray:
    """Ry(yaw) · Rx(pitch) · Rz(roll) (radians, broadcast). Positive pitch leans +Y toward +Z."""
    yaw, pitch, roll = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (yaw, pitch, roll)))
    return quat_mul(_qaxis(_Y, yaw), quat_mul(_qaxis(_X, pitch), _qaxis(_Z, roll)))


def _rot_y(yaw: Any, v: np.ndarray) -> np.ndarray:
    return quat_rotate(_qaxis(_Y, yaw), v)


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0)


def _wrap(a: np.ndarray | float) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


# --------------------------------------------------------------------------------------------------
# rig geometry and analytic IK


@dataclass(frozen=True)
class Rig:
    """Lengths derived from a :func:`humanoid_skeleton` that the generators and IK need."""

    skeleton: Skeleton
    thigh: float
    shin: float
    upper_arm: float
    forearm: float
    hip_offset: dict[str, np.ndarray]
    toe_offset: np.ndarray
    ankle_height: float
    stand_height: float

    @classmethod
    def from_skeleton(cls, sk: Skeleton) -> Rig:
        o = sk.offsets
        scale = float(np.linalg.norm(o[sk.index("LeftLeg")])) / 0.43
        ankle_h = -o[sk.index("LeftToeBase")][1] + _TOE_RADIUS * scale
        thigh = float(np.linalg.norm(o[sk.index("LeftLeg")]))
        shin = float(np.linalg.norm(o[sk.index("LeftFoot")]))
        return cls(
            skeleton=sk, thigh=thigh, shin=shin,
            upper_arm=float(np.linalg.norm(o[sk.index("LeftForeArm")])),
            forearm=float(np.linalg.norm(o[sk.index("LeftHand")])),
            hip_offset={"left": o[sk.index("LeftUpLeg")].copy(), "right": o[sk.index("RightUpLeg")].copy()},
            toe_offset=o[sk.index("LeftToeBase")].copy(),
            ankle_height=float(ankle_h),
            stand_height=float(ankle_h + thigh + shin - o[sk.index("LeftUpLeg")][1]),
        )

    @property
    def leg(self) -> float:
        return self.thigh + self.shin

    @property
    def arm(self) -> float:
        return self.upper_arm + self.forearm


def two_bone_ik(base: np.ndarray, target: np.ndarray, l1: float, l2: float, pole: np.ndarray,
                rest_dir: np.ndarray, rest_pole: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Analytic two-bone IK (hinge middle joint), vectorized over frames.

    Returns the global rotation matrices (F, 3, 3) of the upper and lower bones and the distance
    (F,) by which the end misses ``target`` (0 unless the target is out of reach). In the rest pose
    the bones point along ``rest_dir`` and the middle joint bends toward ``rest_pole``; the solved
    middle joint bends toward ``pole``.
    """
    d_vec = target - base
    d = np.linalg.norm(d_vec, axis=-1)
    u = d_vec / np.where(d > 1e-12, d, 1.0)[:, None]
    dc = np.clip(d, abs(l1 - l2) + 1e-6, (l1 + l2) * (1.0 - 1e-9))
    cos_a = np.clip((l1 * l1 + dc * dc - l2 * l2) / (2.0 * l1 * dc), -1.0, 1.0)
    sin_a = np.sqrt(1.0 - cos_a * cos_a)
    p = _unit(pole - np.sum(pole * u, axis=-1, keepdims=True) * u)
    n = np.cross(u, p)
    knee = base + l1 * (cos_a[:, None] * u + sin_a[:, None] * p)
    end = base + dc[:, None] * u
    b1 = (knee - base) / l1
    b2 = (end - knee) / l2
    r0 = np.stack([rest_dir, np.cross(np.cross(rest_dir, rest_pole), rest_dir), np.cross(rest_dir, rest_pole)], -1)

    def frame(b: np.ndarray) -> np.ndarray:
        return np.stack([b, np.cross(n, b), n], axis=-1) @ r0.T

    return frame(b1), frame(b2), np.abs(d - dc)


# --------------------------------------------------------------------------------------------------
# foot plants and tracks


@dataclass(frozen=True)
class Plant:
    """One foot contact: flat with the ankle fixed on [t_on, t_heel], then the heel rises (the
    foot pivots about the fixed toe joint) to ``heel_pitch`` radians at t_off."""

    t_on: float
    t_off: float
    ankle: np.ndarray
    yaw: float
    t_heel: float | None = None
    heel_pitch: float = 0.0

    def toe(self, rig: Rig) -> np.ndarray:
        return self.ankle + _rot_y(self.yaw, rig.toe_offset)

    def pivot_ankle(self, rig: Rig, alpha: np.ndarray) -> np.ndarray:
        """Ankle positions (n, 3) with the heel raised by ``alpha`` about the toe joint."""
        alpha = np.atleast_1d(np.asarray(alpha, dtype=np.float64))
        return self.toe(rig) - quat_rotate(_qypr(self.yaw, alpha), rig.toe_offset)

    def end_state(self, rig: Rig) -> tuple[np.ndarray, float]:
        if self.t_heel is None:
            return self.ankle, 0.0
        return self.pivot_ankle(rig, np.array([self.heel_pitch]))[0], self.heel_pitch


@dataclass
class FootTrack:
    """Per-frame ankle position (F, 3), foot yaw and pitch (F,) radians, stance mask (F,)."""

    ankle: np.ndarray
    yaw: np.ndarray
    pitch: np.ndarray
    stance: np.ndarray


def foot_track(rig: Rig, t: np.ndarray, plants: list[Plant], lift: float) -> FootTrack:
    """Ankle/foot trajectory through a time-ordered list of plants; swings ease between them with a
    sin² lift of ``lift`` metres. The toe joint is fixed over every [t_on, t_off]."""
    f = len(t)
    ankle = np.empty((f, 3))
    yaw = np.empty(f)
    pitch = np.zeros(f)
    stance = np.zeros(f, dtype=bool)
    first = plants[0]
    m = t < first.t_on
    ankle[m], yaw[m] = first.ankle, first.yaw
    for k, p in enumerate(plants):
        th = p.t_off if p.t_heel is None else p.t_heel
        m = (t >= p.t_on) & (t <= th)
        ankle[m], yaw[m], pitch[m], stance[m] = p.ankle, p.yaw, 0.0, True
        m = (t > th) & (t <= p.t_off)
        if m.any():
            a = p.heel_pitch * _smooth((t[m] - th) / (p.t_off - th))
            ankle[m], yaw[m], pitch[m], stance[m] = p.pivot_ankle(rig, a), p.yaw, a, True
        end_ankle, end_pitch = p.end_state(rig)
        if k + 1 < len(plants):
            q = plants[k + 1]
            m = (t > p.t_off) & (t < q.t_on)
            u = (t[m] - p.t_off) / (q.t_on - p.t_off)
            s = _smooth(u)[:, None]
            ankle[m] = end_ankle + s * (q.ankle - end_ankle) + (lift * np.sin(np.pi * u) ** 2)[:, None] * _Y
            pitch[m] = end_pitch * (1.0 - s[:, 0])
            yaw[m] = p.yaw + s[:, 0] * _wrap(q.yaw - p.yaw)
        else:
            m = t > p.t_off
            ankle[m], yaw[m], pitch[m] = end_ankle, p.yaw, end_pitch
    return FootTrack(ankle, yaw, pitch, stance)


def _override(track: FootTrack, w: np.ndarray, ankle: np.ndarray, pitch: np.ndarray | None = None) -> None:
    """Blend a free (non-planted) ankle path into a track with per-frame weight w (in place)."""
    wc = w[:, None]
    track.ankle = (1.0 - wc) * track.ankle + wc * ankle
    if pitch is not None:
        track.pitch = (1.0 - w) * track.pitch + w * pitch
    track.stance = track.stance & (w <= 0.0)


# --------------------------------------------------------------------------------------------------
# the plan: what a generator produces, turned into a Motion by `build_motion`


@dataclass
class Plan:
    """Everything that drives one clip, in the clip's local frame (start heading +Z).

    Angles are radians. ``spine`` is (F, 3) total torso pitch/yaw/roll spread over the three
    spine joints; ``head`` (F, 3) pitch/yaw/roll split over neck and head; ``arms`` per side (F, 3)
    shoulder flexion, abduction, elbow flexion used by FK; ``hands`` per side (blend (F,), target
    (F, 3)) pulls the wrist onto a target by IK where the blend is 1.
    """

    t: np.ndarray
    root_pos: np.ndarray
    root_rot: np.ndarray
    feet: dict[str, FootTrack]
    spine: np.ndarray
    head: np.ndarray
    arms: dict[str, np.ndarray]
    hands: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass
class ClipSpec:
    """A generator's output: the plan plus the ground truth it knows (times in seconds, local frame)."""

    plan: Plan
    actions: list[dict[str, Any]]
    targets: list[dict[str, Any]]
    flights: list[tuple[float, float]]
    plants: dict[str, list[Plant]]
    params: dict[str, Any]


def _arm_quats(angles: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    sign = 1.0 if side == "left" else -1.0
    shoulder = quat_mul(_qaxis(_Z, sign * angles[:, 1]), _qaxis(_X, -angles[:, 0]))
    elbow = _qaxis(_X, -angles[:, 2])
    return shoulder, elbow


def build_motion(rig: Rig, plan: Plan, fps: float, name: str = "") -> tuple[Motion, float]:
    """Joint rotations for a plan (leg and arm IK); returns the motion and the worst IK miss (m)."""
    sk = rig.skeleton
    idx = sk.index
    f = len(plan.t)
    rot = np.zeros((f, sk.n_joints, 4))
    rot[..., 0] = 1.0
    rot[:, 0] = plan.root_rot
    third = _qypr(plan.spine[:, 1] / 3, plan.spine[:, 0] / 3, plan.spine[:, 2] / 3)
    for j in ("Spine", "Spine1", "Spine2"):
        rot[:, idx(j)] = third
    half = _qypr(plan.head[:, 1] / 2, plan.head[:, 0] / 2, plan.head[:, 2] / 2)
    rot[:, idx("Neck")] = half
    rot[:, idx("Head")] = half
    for side, prefix in zip(SIDES, ("Left", "Right"), strict=True):
        shoulder, elbow = _arm_quats(plan.arms[side], side)
        rot[:, idx(prefix + "Arm")] = shoulder
        rot[:, idx(prefix + "ForeArm")] = elbow
    worst = 0.0
    r_root = quat_to_matrix(plan.root_rot)
    lateral = quat_rotate(plan.root_rot, _X)
    for side, prefix in zip(SIDES, ("Left", "Right"), strict=True):
        foot = plan.feet[side]
        hip = plan.root_pos + quat_rotate(plan.root_rot, rig.hip_offset[side])
        ankle = _soft_reach(hip, foot.ankle, 0.9 * rig.leg, 0.985 * rig.leg, ~foot.stance)
        u = _unit(ankle - hip)
        out = lateral if side == "left" else -lateral
        pole = np.cross(u, lateral) + 0.08 * out
        r1, r2, miss = two_bone_ik(hip, ankle, rig.thigh, rig.shin, pole, -_Y, _Z)
        worst = max(worst, float(np.max(miss[foot.stance], initial=0.0)))
        rot[:, idx(prefix + "UpLeg")] = quat_from_matrix(np.swapaxes(r_root, -1, -2) @ r1)
        rot[:, idx(prefix + "Leg")] = quat_from_matrix(np.swapaxes(r1, -1, -2) @ r2)
        q_shin = quat_from_matrix(r2)
        rot[:, idx(prefix + "Foot")] = quat_mul(quat_inv(q_shin), _qypr(foot.yaw, foot.pitch))
        # the toes stay level while the heel is up (they bend at the ball of the foot)
        rot[:, idx(prefix + "ToeBase")] = _qaxis(_X, -np.maximum(foot.pitch, 0.0))
    motion = Motion(skeleton=sk, fps=fps, root_positions=plan.root_pos, rotations=rot, name=name,
                    unit="m", scale_to_m=1.0)
    if plan.hands:
        gpos, grot = forward_kinematics(motion)
        for side, prefix in zip(SIDES, ("Left", "Right"), strict=True):
            if side not in plan.hands:
                continue
            blend, target = plan.hands[side]
            shoulder = gpos[:, idx(prefix + "Arm")]
            wrist = gpos[:, idx(prefix + "Hand")]
            goal = wrist + blend[:, None] * (target - wrist)
            q_clav = grot[:, idx(prefix + "Shoulder")]
            lat = quat_rotate(grot[:, idx("Spine2")], _X)
            out = lat if side == "left" else -lat
            u = _unit(goal - shoulder)
            pole = np.cross(lat, u) + 0.6 * out - 0.3 * _Y
            r1, r2, miss = two_bone_ik(shoulder, goal, rig.upper_arm, rig.forearm, pole, -_Y, -_Z)
            worst = max(worst, float(np.max(miss[blend >= 1.0], initial=0.0)))
            rot[:, idx(prefix + "Arm")] = quat_from_matrix(np.swapaxes(quat_to_matrix(q_clav), -1, -2) @ r1)
            rot[:, idx(prefix + "ForeArm")] = quat_from_matrix(np.swapaxes(r1, -1, -2) @ r2)
        motion = replace(motion, rotations=rot)
    return motion, worst


def _soft_reach(base: np.ndarray, target: np.ndarray, r0: float, r1: float, mask: np.ndarray) -> np.ndarray:
    """Pull targets (where ``mask``) smoothly toward ``base`` so that their distance never exceeds
    r1: distances above r0 are squashed by a tanh (C1 at r0)."""
    d_vec = target - base
    d = np.linalg.norm(d_vec, axis=-1)
    squashed = np.where(d > r0, r0 + (r1 - r0) * np.tanh((d - r0) / (r1 - r0)), d)
    scale = np.where(mask & (d > 1e-12), squashed / np.where(d > 1e-12, d, 1.0), 1.0)
    return base + d_vec * scale[:, None]


def _max_root_heights(rig: Rig, root_xz_pos: np.ndarray, root_rot: np.ndarray, feet: dict[str, FootTrack],
                      reach: float) -> np.ndarray:
    """(F,) highest root height keeping every planted ankle within ``reach`` of its hip (inf if none)."""
    lim = np.full(len(root_rot), np.inf)
    for side in SIDES:
        off = quat_rotate(root_rot, rig.hip_offset[side])
        hip = root_xz_pos + off
        ft = feet[side]
        dh2 = (hip[:, 0] - ft.ankle[:, 0]) ** 2 + (hip[:, 2] - ft.ankle[:, 2]) ** 2
        h = ft.ankle[:, 1] + np.sqrt(np.maximum(reach * reach - dh2, 0.0)) - off[:, 1]
        lim = np.where(ft.stance, np.minimum(lim, h), lim)
    return lim


def _root_height_for(rig: Rig, root_xz: np.ndarray, rot: np.ndarray, ankles: dict[str, np.ndarray],
                     reach: float) -> float:
    """Highest root height at one instant keeping the given ankles within ``reach`` of the hips."""
    best = np.inf
    for side, a in ankles.items():
        off = quat_rotate(rot, rig.hip_offset[side])
        hip = np.array([root_xz[0], 0.0, root_xz[2]]) + off
        dh2 = (hip[0] - a[0]) ** 2 + (hip[2] - a[2]) ** 2
        best = min(best, a[1] + math.sqrt(max(reach * reach - dh2, 0.0)) - off[1])
    return float(best)


def _neutral_plan(rig: Rig, t: np.ndarray, feet: dict[str, FootTrack]) -> Plan:
    f = len(t)
    return Plan(t=t, root_pos=np.zeros((f, 3)), root_rot=_qypr(np.zeros(f)), feet=feet,
                spine=np.zeros((f, 3)), head=np.zeros((f, 3)),
                arms={s: np.tile([0.0, math.radians(6.0), math.radians(12.0)], (f, 1)) for s in SIDES})


def _level_head(plan: Plan, pelvis_pitch: np.ndarray, gain: float = 0.8) -> None:
    plan.head[:, 0] = -gain * (plan.spine[:, 0] + pelvis_pitch)
    plan.head[:, 1] += -0.5 * plan.spine[:, 1]


def _times(duration: float, fps: float) -> np.ndarray:
    return np.arange(round(duration * fps) + 1) / fps


def _lat(side: str) -> float:
    return 1.0 if side == "left" else -1.0


# --------------------------------------------------------------------------------------------------
# locomotion: walk and run


@dataclass(frozen=True)
class Gait:
    """Parameters of a steady gait along an arc (speed m/s, turn rad/s, cadence steps/s)."""

    speed: float
    turn: float
    cadence: float
    duty: float
    width: float
    lift: float
    bob: float
    sway: float
    lean: float
    pelvis_yaw: float
    heel_frac: float
    heel_pitch: float
    arm_swing: float
    elbow: float
    run: bool
    phase: float = 0.0
    anchor: float = 0.42
    toe_out: float = math.radians(4.0)

    @property
    def period(self) -> float:
        return 2.0 / self.cadence

    def path(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Root ground path (n, 3) and heading (n,) at times t."""
        t = np.asarray(t, dtype=np.float64)
        yaw = self.turn * t
        if abs(self.turn) < 1e-9:
            x, z = np.zeros_like(t), self.speed * t
        else:
            x = self.speed * (1.0 - np.cos(yaw)) / self.turn
            z = self.speed * np.sin(yaw) / self.turn
        return np.stack([x, np.zeros_like(t), z], -1), yaw

    def left_on(self) -> float:
        """A left touchdown time."""
        return self.phase * self.period

    def plants(self, rig: Rig, t_lo: float, t_hi: float) -> dict[str, list[Plant]]:
        per, stance = self.period, self.duty * self.period
        out: dict[str, list[Plant]] = {}
        for side, shift in (("left", 0.0), ("right", 0.5 * per)):
            k0 = math.floor((t_lo - self.left_on() - shift) / per) - 1
            k1 = math.ceil((t_hi - self.left_on() - shift) / per) + 1
            lst = []
            for k in range(k0, k1 + 1):
                on = self.left_on() + shift + k * per
                ta = on + self.anchor * stance
                p, yaw = self.path(np.array([ta]))
                pos = p[0] + _rot_y(yaw[0], _X * _lat(side) * self.width / 2) + _Y * rig.ankle_height
                lst.append(Plant(t_on=on, t_off=on + stance, ankle=pos, yaw=float(yaw[0] - _lat(side) * self.toe_out),
                                 t_heel=on + self.heel_frac * stance, heel_pitch=self.heel_pitch))
            out[side] = lst
        return out

    def cycle(self, t: np.ndarray) -> np.ndarray:
        """Gait phase angle, 0 at a left touchdown."""
        return 2.0 * np.pi * (t - self.left_on()) / self.period

    def root(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Root ground position with sway (n, 3), bob (n,), rotation (n, 4); height excluded."""
        p, yaw = self.path(t)
        ph = self.cycle(t)
        mid = ph - np.pi * self.duty  # 0 at left mid-stance
        p = p + (self.sway * np.cos(mid))[:, None] * _rot_y(yaw, _X)
        bob = (-1.0 if self.run else 1.0) * self.bob * np.cos(2.0 * mid)
        rot = _qypr(yaw - self.pelvis_yaw * np.cos(ph), self.lean * 0.5, 0.0)
        return p, bob, rot

    def upper(self, plan: Plan, t: np.ndarray) -> None:
        ph = self.cycle(t)
        c = np.cos(ph)
        plan.spine[:, 0] = self.lean * 0.6
        plan.spine[:, 1] = 1.3 * self.pelvis_yaw * c
        for side in SIDES:
            sw = -_lat(side) * self.arm_swing * c
            plan.arms[side][:, 0] = math.radians(4.0) + sw
            plan.arms[side][:, 1] = math.radians(10.0 if self.run else 6.0)
            plan.arms[side][:, 2] = self.elbow + 0.4 * np.maximum(sw, 0.0)


def _gait_clip(rig: Rig, gait: Gait, duration: float, fps: float, label: str) -> ClipSpec:
    t = _times(duration, fps)
    plants = gait.plants(rig, 0.0, t[-1])
    feet = {s: foot_track(rig, t, plants[s], gait.lift) for s in SIDES}
    plan = _neutral_plan(rig, t, feet)
    ground, bob, rot = gait.root(t)
    lim = _max_root_heights(rig, ground, rot, feet, 0.975 * rig.leg)
    base = float(min(np.min(lim - bob), rig.stand_height - 0.01))
    plan.root_pos = ground + (base + bob)[:, None] * _Y
    plan.root_rot = rot
    gait.upper(plan, t)
    _level_head(plan, np.full(len(t), gait.lean * 0.5))
    flights = _flight_gaps(plants, 0.0, float(t[-1]))
    params = {"speed": gait.speed, "turn_rate_deg_s": math.degrees(gait.turn), "cadence": gait.cadence,
              "duty_factor": gait.duty, "step_width": gait.width, "stride_length": gait.speed * gait.period,
              "root_height": base, "bob": gait.bob}
    return ClipSpec(plan, [{"label": label, "t0": 0.0, "t1": float(t[-1])}], [], flights, plants, params)


def _flight_gaps(plants: dict[str, list[Plant]], t_lo: float, t_hi: float) -> list[tuple[float, float]]:
    """Time intervals inside (t_lo, t_hi) where no foot is planted."""
    iv = sorted((p.t_on, p.t_off) for s in SIDES for p in plants[s])
    gaps, reach = [], -np.inf
    for a, b in iv:
        if a > reach > t_lo and a < t_hi:
            gaps.append((float(reach), float(a)))
        reach = max(reach, b)
    return gaps


def _walk_gait(v: int, rng: np.random.Generator) -> Gait:
    speed = (0.95, 1.3, 1.6)[v % 3] * (1.0 + 0.04 * rng.uniform(-1, 1)) * (1.0 + 0.05 * (v // 3))
    turn = math.radians((0.0, 30.0, -22.0, 40.0, -40.0, 12.0)[v % 6] + rng.uniform(-4, 4))
    return Gait(speed=speed, turn=turn, cadence=1.45 + 0.38 * speed, duty=0.63 - 0.03 * (speed - 1.0),
                width=0.2 + 0.02 * rng.uniform(-1, 1), lift=0.07 + 0.02 * speed, bob=0.012 + 0.008 * speed,
                sway=0.02, lean=math.radians(3.0 + 3.0 * speed), pelvis_yaw=math.radians(4.0 + 2.0 * speed),
                heel_frac=0.62, heel_pitch=math.radians(28.0 + 6.0 * speed), arm_swing=math.radians(9.0 + 9.0 * speed),
                elbow=math.radians(14.0), run=False, phase=float(rng.uniform(0, 1)))


def _run_gait(v: int, rng: np.random.Generator) -> Gait:
    speed = (2.6, 3.2, 3.8)[v % 3] * (1.0 + 0.04 * rng.uniform(-1, 1)) * (1.0 + 0.05 * (v // 3))
    turn = math.radians((0.0, -24.0, 30.0, 45.0, -45.0, 15.0)[v % 6] + rng.uniform(-4, 4))
    return Gait(speed=speed, turn=turn, cadence=2.55 + 0.12 * speed, duty=0.40 - 0.02 * (speed - 3.0),
                width=0.14, lift=0.16 + 0.03 * speed, bob=G / (2.0 * np.pi * (2.55 + 0.12 * speed)) ** 2, sway=0.01, lean=math.radians(8.0 + 2.0 * speed),
                pelvis_yaw=math.radians(7.0), heel_frac=0.4, heel_pitch=math.radians(38.0),
                arm_swing=math.radians(28.0), elbow=math.radians(85.0), run=True, phase=float(rng.uniform(0, 1)))


def _gen_walk(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    return _gait_clip(rig, _walk_gait(v, rng), 4.0 + 0.5 * rng.uniform(0, 1), fps, "walk")


def _gen_run(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    return _gait_clip(rig, _run_gait(v, rng), 3.0 + 0.5 * rng.uniform(0, 1), fps, "run")


# --------------------------------------------------------------------------------------------------
# shared pose helpers for the stationary and jumping clips


def _keys(t: np.ndarray, knots: list[tuple[float, Any]]) -> np.ndarray:
    """Values eased between (time, value) knots (zero slopes), (F, D)."""
    kt = np.array([k for k, _ in knots])
    kp = np.array([np.atleast_1d(np.asarray(v, dtype=np.float64)) for _, v in knots])
    return _hermite(t, kt, kp)


def _pulse(t: np.ndarray, t_a: float, t_apex: float, t_b: float, hold: float = 0.0) -> np.ndarray:
    """0 -> 1 (eased) on [t_a, t_apex], 1 for ``hold`` seconds, back to 0 by t_b."""
    up = _smooth((t - t_a) / (t_apex - t_a))
    down = 1.0 - _smooth((t - t_apex - hold) / (t_b - t_apex - hold))
    return np.where(t <= t_apex, up, np.where(t <= t_apex + hold, 1.0, down))


def _snap(t: float, fps: float) -> float:
    """The frame time nearest to t."""
    return round(t * fps) / fps


def _standing_plants(rig: Rig, feet: dict[str, tuple[float, float, float]], t_end: float) -> dict[str, list[Plant]]:
    """One plant per foot lasting the whole clip; feet[side] = (x, z, yaw)."""
    return {s: [Plant(t_on=-1.0, t_off=t_end + 1.0, ankle=np.array([x, rig.ankle_height, z]), yaw=yaw)]
            for s, (x, z, yaw) in feet.items()}


def _apply_root(plan: Plan, pos: np.ndarray, yaw: np.ndarray, pitch: np.ndarray, roll: Any = 0.0) -> None:
    plan.root_pos = pos
    plan.root_rot = _qypr(yaw, pitch, roll)


def _hip(rig: Rig, plan: Plan, side: str, i: int) -> np.ndarray:
    return plan.root_pos[i] + quat_rotate(plan.root_rot[i], rig.hip_offset[side])


def _dir(elev: float, azim: float) -> np.ndarray:
    return np.array([math.sin(azim) * math.cos(elev), math.sin(elev), math.cos(azim) * math.cos(elev)])


# --------------------------------------------------------------------------------------------------
# jumps: crouch, take-off, exact ballistic flight, landing, recovery


@dataclass
class Jump:
    """A two-footed jump planned from a still, ready stance."""

    root_t: list[float]
    root_p: list[np.ndarray]
    root_v: list[np.ndarray]
    t0: float
    t1: float
    p0: np.ndarray
    v0: np.ndarray
    plants: dict[str, list[Plant]]
    carry: dict[str, tuple[list[float], list[np.ndarray]]]
    pose: list[tuple[float, np.ndarray]]  # (time, [pelvis pitch, spine pitch, arm flex, elbow])
    actions: list[dict[str, Any]]
    t_end: float
    params: dict[str, Any]

    def root(self, t: np.ndarray) -> np.ndarray:
        """Root positions; on [t0, t1] exactly the parabola under gravity."""
        out = _hermite(t, self.root_t, np.array(self.root_p), np.array(self.root_v))
        m = (t >= self.t0) & (t <= self.t1)
        dt = (t[m] - self.t0)[:, None]
        out[m] = self.p0 + self.v0 * dt - 0.5 * G * dt * dt * _Y
        return out


def plan_jump(rig: Rig, t_ready: float, root_ready: np.ndarray, stance: dict[str, Plant], apex: float,
              distance: float, width: float = 0.2) -> Jump:
    """Plan a jump: ``apex`` metres of root rise after take-off, ``distance`` metres of flight
    along +Z. ``stance`` holds each foot's current plant (its t_off is replaced by the take-off)."""
    t_c = t_ready + 0.45
    t0 = t_c + 0.25
    crouch = 0.2 + 0.1 * apex
    heel = math.radians(30.0)
    feet_z = float(np.mean([p.ankle[2] for p in stance.values()]))
    feet_x = float(np.mean([p.ankle[0] for p in stance.values()]))
    take = {s: replace(p, t_off=t0, t_heel=t0 - 0.13, heel_pitch=heel) for s, p in stance.items()}
    pitch0, pitch1 = math.radians(5.0), math.radians(12.0)
    z0 = feet_z + 0.04 + 0.07 * distance
    ank0 = {s: p.pivot_ankle(rig, np.array([heel]))[0] for s, p in take.items()}
    y0 = _root_height_for(rig, np.array([feet_x, 0.0, z0]), _qypr(0.0, pitch0), ank0, 0.965 * rig.leg)
    ahead = 0.10
    rel_land = {s: np.array([_lat(s) * width / 2, rig.ankle_height, ahead]) for s in SIDES}
    y1 = _root_height_for(rig, np.zeros(3), _qypr(0.0, pitch1), rel_land, 0.95 * rig.leg)
    vy = math.sqrt(2.0 * G * apex)
    tf = (vy + math.sqrt(vy * vy + 2.0 * G * (y0 - y1))) / G
    vh = distance / tf
    p0 = np.array([feet_x, y0, z0])
    v0 = np.array([0.0, vy, vh])
    t1 = t0 + tf
    p1 = p0 + v0 * tf - 0.5 * G * tf * tf * _Y
    v1 = v0 - G * tf * _Y
    land = {s: Plant(t_on=t1, t_off=t1 + 100.0, ankle=np.array([p1[0], 0.0, p1[2]]) + rel_land[s] * [1, 0, 1]
                     + rig.ankle_height * _Y, yaw=stance[s].yaw) for s in SIDES}
    t_abs = 0.25
    depth = max(0.16 + 0.2 * apex, abs(v1[1]) * t_abs / 3.0)
    t_a = t1 + t_abs
    p_a = np.array([p1[0], y1 - depth, p1[2] + 0.4 * vh * t_abs])
    t_r = t_a + 0.6 + 0.3 * apex
    land_z = p1[2] + ahead
    p_r = np.array([p1[0], root_ready[1], land_z - 0.01])
    zero = np.zeros(3)
    root_t = [t_ready, t_c, t0, t1, t_a, t_r]
    root_p = [root_ready, root_ready + np.array([0.0, -crouch, -0.05]), p0, p1, p_a, p_r]
    root_v = [zero, zero, v0, v1, zero, zero]
    mid = 0.5 * (t0 + t1)
    rel0 = {s: ank0[s] - p0 for s in SIDES}
    rel1 = {s: land[s].ankle - p1 for s in SIDES}
    carry = {s: ([t0, mid, t1], [rel0[s], 0.5 * (rel0[s] + rel1[s]) + (0.15 + 0.3 * apex) * _Y, rel1[s]])
             for s in SIDES}
    pose = [
        (t_ready, np.array([0.0, 0.0, 0.07, 0.2])),
        (t_c, np.array([0.45, 0.35, -0.8, 0.3])),
        (t0, np.array([pitch0, 0.05, 1.6, 0.5])),
        (mid, np.array([pitch0, 0.1, 1.7, 0.5])),
        (t1, np.array([pitch1, 0.15, 0.7, 0.4])),
        (t_a, np.array([0.4, 0.35, 0.3, 0.4])),
        (t_r, np.array([0.0, 0.0, 0.07, 0.2])),
    ]
    actions = [{"label": "crouch", "t0": t_ready, "t1": t_c}, {"label": "takeoff", "t0": t_c, "t1": t0},
               {"label": "flight", "t0": t0, "t1": t1}, {"label": "landing", "t0": t1, "t1": t_a},
               {"label": "recover", "t0": t_a, "t1": t_r}]
    plants = {s: [take[s], land[s]] for s in SIDES}
    params = {"apex_height": apex, "distance": distance, "flight_time": tf, "takeoff_velocity": v0,
              "landing_velocity": v1, "takeoff_height": y0, "landing_height": y1}
    return Jump(root_t, root_p, root_v, t0, t1, p0, v0, plants, carry, pose, actions, t_r, params)


def _apply_jump(rig: Rig, plan: Plan, jump: Jump, weight: np.ndarray | None = None) -> None:
    """Drive root, flight feet and jump poses of ``plan`` from the jump (poses blended in by weight)."""
    t = plan.t
    root = jump.root(t)
    pose = _keys(t, jump.pose)
    w = np.ones(len(t)) if weight is None else weight
    m = (t > jump.t0) & (t < jump.t1)
    for s in SIDES:
        kt, rel = jump.carry[s]
        ankle = root + _hermite(t, kt, np.array(rel))
        _override(plan.feet[s], m.astype(np.float64), ankle)
    plan.root_pos = np.where(t[:, None] >= jump.root_t[0], root, plan.root_pos)
    yaw = np.zeros(len(t))
    rot = _qypr(yaw, pose[:, 0])
    blend = (w[:, None] > 0)
    plan.root_rot = np.where(blend & (t[:, None] >= jump.root_t[0]), rot, plan.root_rot)
    plan.spine[:, 0] = (1 - w) * plan.spine[:, 0] + w * pose[:, 1]
    for s in SIDES:
        plan.arms[s][:, 0] = (1 - w) * plan.arms[s][:, 0] + w * pose[:, 2]
        plan.arms[s][:, 2] = (1 - w) * plan.arms[s][:, 2] + w * pose[:, 3]
    _level_head(plan, pose[:, 0], 0.6)


def _gen_jump(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    apex = (0.25, 0.35, 0.45)[v % 3] + 0.03 * rng.uniform(-1, 1)
    distance = (0.0, 0.6, 1.1)[(v + v // 3) % 3] + 0.1 * rng.uniform(0, 1)
    width = 0.2 + 0.02 * rng.uniform(-1, 1)
    t_ready = 0.4 + 0.2 * rng.uniform(0, 1)
    stance = {s: Plant(t_on=-1.0, t_off=100.0, ankle=np.array([_lat(s) * width / 2, rig.ankle_height, 0.0]),
                       yaw=-_lat(s) * math.radians(5.0)) for s in SIDES}
    ready = np.array([0.0, rig.stand_height - 0.02, 0.0])
    jump = plan_jump(rig, t_ready, ready, stance, apex, distance, width)
    t = _times(jump.t_end + 0.5, fps)
    feet = {s: foot_track(rig, t, jump.plants[s], 0.0) for s in SIDES}
    plan = _neutral_plan(rig, t, feet)
    plan.root_pos = np.broadcast_to(ready, (len(t), 3)).copy()
    _apply_jump(rig, plan, jump)
    actions = [{"label": "stand", "t0": 0.0, "t1": t_ready}, *jump.actions,
               {"label": "stand", "t0": jump.t_end, "t1": float(t[-1])}]
    return ClipSpec(plan, actions, [], [(jump.t0, jump.t1)], jump.plants, jump.params)


def walk_then_jump(seed: int = 0, fps: float = 60.0) -> tuple[Motion, dict[str, Any]]:
    """About 2-3 s of straight walking, a stop, then a forward jump with an exact ballistic flight
    of at least 0.5 s and a landing (the guided-warp test clip)."""
    rig = Rig.from_skeleton(humanoid_skeleton())
    rng = _rng("walk_then_jump", 0, seed)
    gait = replace(_walk_gait(1, rng), turn=0.0)
    plants = gait.plants(rig, 0.0, 8.0)
    t_min = 1.9 + 0.3 * rng.uniform(0, 1)
    _, side_a, ia = min((p.t_on, s, i) for s in SIDES for i, p in enumerate(plants[s]) if p.t_on >= t_min)
    side_b = "right" if side_a == "left" else "left"
    a_plant = plants[side_a][ia]
    t_a = a_plant.t_on
    b_list = [p for p in plants[side_b] if p.t_on < t_a]
    b_next = next(p for p in plants[side_b] if p.t_on > t_a)
    b_final = Plant(t_on=b_next.t_on, t_off=100.0, yaw=b_next.yaw,
                    ankle=np.array([-a_plant.ankle[0], rig.ankle_height, a_plant.ankle[2]]))
    a_final = replace(a_plant, t_off=100.0, t_heel=None, heel_pitch=0.0)
    stop_plants = {side_a: [p for p in plants[side_a] if p.t_on < t_a] + [a_final], side_b: b_list + [b_final]}
    ground_a, _, _ = gait.root(np.array([t_a]))
    z_stop = a_plant.ankle[2] + 0.05
    t_d = 2.0 * (z_stop - ground_a[0, 2]) / gait.speed
    t_ready = max(t_a + t_d, b_final.t_on) + 0.25
    stance = {side_a: a_final, side_b: b_final}
    ready_y = rig.stand_height - 0.03
    jump = plan_jump(rig, t_ready, np.array([0.0, ready_y, z_stop]), stance, 0.42 + 0.02 * rng.uniform(0, 1),
                     0.5 + 0.2 * rng.uniform(0, 1), gait.width)
    all_plants = {s: stop_plants[s][:-1] + jump.plants[s] for s in SIDES}
    t = _times(jump.t_end + 0.6, fps)
    feet = {s: foot_track(rig, t, all_plants[s], gait.lift) for s in SIDES}
    plan = _neutral_plan(rig, t, feet)
    # walking root, then an eased stop (velocity v(1 - smooth(u)) along +Z), then the jump
    ground, bob, rot = gait.root(t)
    pre = t <= t_a
    lim = _max_root_heights(rig, ground[pre], rot[pre], {s: FootTrack(f.ankle[pre], f.yaw[pre], f.pitch[pre],
                                                                       f.stance[pre]) for s, f in feet.items()},
                            0.975 * rig.leg)
    base = float(min(np.min(lim - bob[pre]), rig.stand_height - 0.01))
    u = np.clip((t - t_a) / t_d, 0.0, 1.0)
    s_u = _smooth(u)
    fade = 1.0 - s_u
    ga, _, _ = gait.root(np.array([t_a]))
    z = np.where(pre, ground[:, 2], ga[0, 2] + gait.speed * t_d * (u - u ** 3 + 0.5 * u ** 4))
    x = np.where(pre, ground[:, 0], ground[:, 0] * fade)
    y = np.where(pre, base + bob, (base + bob) * fade + ready_y * s_u)
    plan.root_pos = np.stack([x, y, z], -1)
    ph = gait.cycle(t)
    wfade = np.where(pre, 1.0, fade)
    plan.root_rot = _qypr(-gait.pelvis_yaw * np.cos(ph) * wfade, gait.lean * 0.5 * wfade)
    gait.upper(plan, t)
    plan.spine *= wfade[:, None]
    for s in SIDES:
        plan.arms[s] = plan.arms[s] * wfade[:, None] + np.array([0.07, math.radians(6.0), 0.2]) * (1 - wfade[:, None])
    _level_head(plan, gait.lean * 0.5 * wfade)
    _apply_jump(rig, plan, jump, weight=(t >= t_ready).astype(np.float64))
    actions = [{"label": "walk", "t0": 0.0, "t1": t_a}, {"label": "stop", "t0": t_a, "t1": t_ready}, *jump.actions,
               {"label": "stand", "t0": jump.t_end, "t1": float(t[-1])}]
    flights = [(jump.t0, jump.t1)]
    params = {"speed": gait.speed, "cadence": gait.cadence, "walk_root_height": base, **jump.params}
    spec = ClipSpec(plan, actions, [], flights, all_plants, params)
    return _finish(rig, spec, "walk_then_jump", 0, seed, fps, rng, "walk_then_jump")


# --------------------------------------------------------------------------------------------------
# stationary clips: kick, punch, reach, sit, idle


def _stationary(rig: Rig, duration: float, fps: float, feet: dict[str, tuple[float, float, float]]
                ) -> tuple[np.ndarray, Plan, dict[str, list[Plant]]]:
    t = _times(duration, fps)
    plants = _standing_plants(rig, feet, float(t[-1]))
    plan = _neutral_plan(rig, t, {s: foot_track(rig, t, plants[s], 0.0) for s in SIDES})
    return t, plan, plants


def _gen_kick(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    side = ("right", "left")[v % 2]
    sup = "left" if side == "right" else "right"
    elev = math.radians((-32.0, -14.0, 4.0)[v % 3] + rng.uniform(-4, 4))
    azim = math.radians(-_lat(side) * rng.uniform(-6.0, 12.0))
    t_shift = 0.4 + 0.2 * rng.uniform(0, 1)
    t_lift = t_shift + 0.3
    t_apex = _snap(t_lift + 0.42 + 0.1 * rng.uniform(0, 1), fps)
    t_down = t_apex + 0.5
    t_end = t_down + 0.9
    t, plan, plants = _stationary(rig, t_end + 0.6, fps, {s: (_lat(s) * 0.1, 0.0, -_lat(s) * 0.08) for s in SIDES})
    stand = np.array([0.0, rig.stand_height - 0.02, 0.0])
    shifted = stand + np.array([_lat(sup) * 0.06, -0.04, 0.0])
    leaned = shifted + np.array([0.0, -0.02, -0.04])
    root = _keys(t, [(0.0, stand), (t_shift, shifted), (t_lift, shifted), (t_apex, leaned), (t_down, shifted),
                     (t_end, stand)])
    pitch = _keys(t, [(t_lift, 0.0), (t_apex, -0.18), (t_down, 0.0)])[:, 0]
    _apply_root(plan, root, np.zeros(len(t)), pitch)
    plan.spine[:, 0] = _keys(t, [(t_lift, 0.0), (t_apex, 0.1), (t_down, 0.0)])[:, 0]
    guard = _keys(t, [(0.0, [0.07, 0.1, 0.2]), (t_shift, [0.6, 0.35, 1.7]), (t_down, [0.6, 0.35, 1.7]),
                      (t_end, [0.07, 0.1, 0.2])])
    for s in SIDES:
        plan.arms[s] = guard.copy()
    _level_head(plan, pitch)
    i = round(t_apex * fps)
    target = _hip(rig, plan, side, i) + 0.88 * rig.leg * _dir(elev, azim)
    start = plants[side][0].ankle
    b = _pulse(t, t_lift, t_apex, t_down)
    chamber = np.array([0.0, 0.28, 0.12])
    ankle = start + b[:, None] * (target - start) + (4.0 * b * (1.0 - b))[:, None] * chamber
    w = ((t > t_lift) & (t < t_down)).astype(np.float64)
    _override(plan.feet[side], w, ankle, math.radians(25.0) * b)
    effector = ("Left" if side == "left" else "Right") + "Foot"
    targets = [{"name": "kick", "effector": effector, "t": t_apex, "local": target}]
    actions = [{"label": "shift", "t0": t_shift - 0.4, "t1": t_lift},
               {"label": "kick", "t0": t_lift, "t1": t_down, "apex": t_apex},
               {"label": "recover", "t0": t_down, "t1": t_end}]
    plants[side] = [replace(plants[side][0], t_off=t_lift), replace(plants[side][0], t_on=t_down)]
    params = {"side": side, "elevation_deg": math.degrees(elev), "azimuth_deg": math.degrees(azim),
              "target_height": float(target[1])}
    return ClipSpec(plan, actions, targets, [], plants, params)


def _hand_targets(rig: Rig, plan: Plan, fps: float,
                  strikes: list[tuple[str, float, float, float, np.ndarray, float]]) -> list[dict[str, Any]]:
    """Pull wrists onto targets: strikes are (side, t_start, t_apex, t_end, direction, hold); each
    target sits at 0.92 arm lengths from the shoulder at the apex frame. Sets plan.hands."""
    motion, _ = build_motion(rig, plan, fps)
    gpos, _ = forward_kinematics(motion)
    t = plan.t
    blend = {s: np.zeros(len(t)) for s in SIDES}
    goal = {s: np.zeros((len(t), 3)) for s in SIDES}
    out = []
    for side, t_a, t_apex, t_b, direction, hold in strikes:
        prefix = "Left" if side == "left" else "Right"
        i = round(t_apex * fps)
        target = gpos[i, rig.skeleton.index(prefix + "Arm")] + 0.92 * rig.arm * direction
        b = _pulse(t, t_a, t_apex, t_b, hold)
        m = (t >= t_a) & (t <= t_b)
        blend[side][m] = b[m]
        goal[side][m] = target
        out.append({"name": "strike", "effector": prefix + "Hand", "t": t_apex, "local": target})
    plan.hands = {s: (blend[s], goal[s]) for s in SIDES if np.any(blend[s] > 0)}
    return out


def _gen_punch(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    lead = ("left", "right")[v % 2]
    back = "right" if lead == "left" else "left"
    feet = {lead: (_lat(lead) * 0.11, 0.14, 0.25), back: (_lat(back) * 0.11, -0.14, 0.35)}
    n = 3
    t_first = 0.8 + 0.2 * rng.uniform(0, 1)
    gap = 0.65 + 0.1 * rng.uniform(0, 1)
    t_end = t_first + gap * (n - 1) + 1.0
    t, plan, plants = _stationary(rig, t_end, fps, feet)
    ready = np.array([0.0, rig.stand_height - 0.06, 0.0])
    plan.root_pos = ready + (0.01 * np.sin(2 * np.pi * 1.5 * t))[:, None] * _Y
    sides = [lead, back, lead] if v % 3 != 2 else [back, lead, back]
    elevs = rng.permutation(np.radians([6.0, -6.0, -18.0])) + np.radians(rng.uniform(-3, 3, n))
    twist = np.zeros(len(t))
    strikes = []
    for k, side in enumerate(sides):
        t_apex = _snap(t_first + k * gap, fps)
        t_a, t_b = t_apex - 0.14, t_apex + 0.26
        azim = -_lat(side) * math.radians(8.0 + 6.0 * rng.uniform(0, 1))
        strikes.append((side, t_a, t_apex, t_b, _dir(float(elevs[k]), azim), 0.0))
        twist += -_lat(side) * 0.3 * _pulse(t, t_a, t_apex, t_b)
    _apply_root(plan, plan.root_pos, 0.35 * twist, np.full(len(t), 0.08))
    plan.spine[:, 0] = 0.12
    plan.spine[:, 1] = 0.65 * twist
    for s in SIDES:
        plan.arms[s] = np.tile([0.55, 0.3, 2.0], (len(t), 1))
    _level_head(plan, np.full(len(t), 0.08))
    plan.head[:, 1] = -twist
    targets = _hand_targets(rig, plan, fps, strikes)
    for tg in targets:
        tg["name"] = "punch"
    actions = [{"label": "guard", "t0": 0.0, "t1": strikes[0][1]}]
    actions += [{"label": "punch", "t0": a, "t1": b, "apex": ap, "side": sd} for sd, a, ap, b, _, _ in strikes]
    params = {"lead": lead, "punch_sides": sides, "elevations_deg": np.degrees(elevs)}
    return ClipSpec(plan, actions, targets, [], plants, params)


def _gen_reach(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    level = ("low", "mid", "high")[v % 3]
    side = ("right", "left")[int(rng.integers(0, 2))]
    t_a = 0.5 + 0.2 * rng.uniform(0, 1)
    t_apex = _snap(t_a + 0.9 + 0.2 * rng.uniform(0, 1), fps)
    hold = 0.3
    t_b = t_apex + hold + 0.9
    t, plan, plants = _stationary(rig, t_b + 0.7, fps, {s: (_lat(s) * 0.11, 0.0, -_lat(s) * 0.1) for s in SIDES})
    b = _pulse(t, t_a, t_apex, t_b, hold)
    pose = {"low": (0.3, 0.7, -0.26, -0.1, -70.0), "mid": (0.08, 0.25, -0.03, -0.02, -12.0),
            "high": (0.0, -0.1, 0.0, 0.0, 62.0)}[level]
    pelvis, spine, dy, dz, elev = pose
    stand = np.array([0.0, rig.stand_height - 0.02, 0.0])
    root = stand + b[:, None] * np.array([_lat(side) * 0.03, dy, dz])
    yaw = -_lat(side) * 0.15 * b
    _apply_root(plan, root, yaw, pelvis * b)
    plan.spine[:, 0] = spine * b
    plan.spine[:, 1] = -_lat(side) * 0.2 * b
    other = "left" if side == "right" else "right"
    plan.arms[other][:, 0] += 0.3 * b
    _level_head(plan, pelvis * b, 0.5)
    azim = -_lat(side) * math.radians(rng.uniform(-15.0, 25.0))
    direction = _dir(math.radians(elev + rng.uniform(-5, 5)), azim)
    targets = _hand_targets(rig, plan, fps, [(side, t_a, t_apex, t_b, direction, hold)])
    targets[0]["name"] = f"reach_{level}"
    actions = [{"label": "stand", "t0": 0.0, "t1": t_a},
               {"label": "reach", "t0": t_a, "t1": t_b, "apex": t_apex, "hold_end": t_apex + hold},
               {"label": "stand", "t0": t_b, "t1": float(t[-1])}]
    params = {"level": level, "side": side, "target_height": float(targets[0]["local"][1])}
    return ClipSpec(plan, actions, targets, [], plants, params)


def _gen_sit(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    seat = (0.42, 0.47, 0.52)[v % 3] + 0.02 * rng.uniform(-1, 1)
    t1 = 0.5 + 0.3 * rng.uniform(0, 1)
    t2 = _snap(t1 + 1.3 + 0.2 * rng.uniform(0, 1), fps)
    t3 = t2 + 1.0 + 0.4 * rng.uniform(0, 1)
    t4 = t3 + 1.3 + 0.2 * rng.uniform(0, 1)
    t, plan, plants = _stationary(rig, t4 + 0.5, fps, {s: (_lat(s) * 0.12, 0.05, -_lat(s) * 0.1) for s in SIDES})
    stand = np.array([0.0, rig.stand_height - 0.015, 0.0])
    seated = np.array([0.0, seat + 0.1, -0.32])
    mid_down = np.array([0.0, 0.5 * (stand[1] + seated[1]) + 0.04, -0.2])
    mid_up = np.array([0.0, 0.5 * (stand[1] + seated[1]) + 0.02, -0.12])
    root = _keys(t, [(t1, stand), (0.5 * (t1 + t2), mid_down), (t2, seated), (t3, seated),
                     (0.5 * (t3 + t4), mid_up), (t4, stand)])
    lean = _keys(t, [(t1, 0.0), (0.5 * (t1 + t2), 0.55), (t2, 0.1), (t3, 0.1), (t3 + 0.45 * (t4 - t3), 0.7),
                     (t4, 0.0)])[:, 0]
    _apply_root(plan, root, np.zeros(len(t)), 0.5 * lean)
    plan.spine[:, 0] = 0.6 * lean
    seated_w = _keys(t, [(t1, 0.0), (t2, 1.0), (t3, 1.0), (t4, 0.0)])[:, 0]
    for s in SIDES:
        plan.arms[s][:, 0] += 0.5 * seated_w
        plan.arms[s][:, 2] += 0.5 * seated_w
    _level_head(plan, 0.5 * lean, 0.6)
    actions = [{"label": "stand", "t0": 0.0, "t1": t1}, {"label": "sit_down", "t0": t1, "t1": t2},
               {"label": "seated", "t0": t2, "t1": t3}, {"label": "stand_up", "t0": t3, "t1": t4},
               {"label": "stand", "t0": t4, "t1": float(t[-1])}]
    targets = [{"name": "seat", "effector": "Hips", "t": t2, "local": seated}]
    return ClipSpec(plan, actions, targets, [], plants, {"seat_height": seat})


def _gen_idle(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    duration = 4.0 + rng.uniform(0, 1)
    w = 0.11 + 0.02 * rng.uniform(-1, 1)
    t, plan, plants = _stationary(rig, duration, fps, {s: (_lat(s) * w, 0.02 * rng.uniform(-1, 1),
                                                           -_lat(s) * 0.12) for s in SIDES})
    f_sway = rng.uniform(0.2, 0.35)
    f_breath = rng.uniform(0.22, 0.32)
    ph = rng.uniform(0, 2 * np.pi, 4)
    x = 0.035 * np.sin(2 * np.pi * f_sway * t + ph[0])
    y = rig.stand_height - 0.015 - 0.008 * (1 + np.sin(2 * np.pi * f_sway * 2 * t + ph[1])) \
        + 0.003 * np.sin(2 * np.pi * f_breath * t)
    root = np.stack([x, y, 0.01 * np.sin(2 * np.pi * 0.5 * f_sway * t + ph[2])], -1)
    _apply_root(plan, root, 0.05 * np.sin(2 * np.pi * 0.5 * f_sway * t + ph[3]), np.full(len(t), 0.03),
                -1.2 * x)
    plan.spine[:, 0] = 0.02 * np.sin(2 * np.pi * f_breath * t)
    plan.spine[:, 2] = 1.0 * x
    looks = np.sort(rng.uniform(0.5, duration - 0.5, 3))
    plan.head[:, 1] = _keys(t, [(k, rng.uniform(-0.5, 0.5)) for k in looks])[:, 0]
    for s in SIDES:
        plan.arms[s][:, 0] += 0.04 * np.sin(2 * np.pi * f_sway * t + ph[0] + _lat(s))
    actions = [{"label": "idle", "t0": 0.0, "t1": float(t[-1])}]
    return ClipSpec(plan, actions, [], [], plants, {"sway_hz": f_sway, "breath_hz": f_breath})


# --------------------------------------------------------------------------------------------------
# hop: one-legged hops with exact ballistic flights


def _ballistic_root(t: np.ndarray, knots: list[tuple[float, np.ndarray, np.ndarray]],
                    flights: list[tuple[float, np.ndarray, np.ndarray, float]]) -> np.ndarray:
    """Hermite through (time, position, velocity) knots, exactly ballistic on each (t0, p0, v0, t1)."""
    out = _hermite(t, [k[0] for k in knots], np.array([k[1] for k in knots]), np.array([k[2] for k in knots]))
    for t0, p0, v0, t1 in flights:
        m = (t >= t0) & (t <= t1)
        dt = (t[m] - t0)[:, None]
        out[m] = p0 + v0 * dt - 0.5 * G * dt * dt * _Y
    return out


def _gen_hop(rig: Rig, v: int, rng: np.random.Generator, fps: float) -> ClipSpec:
    sup = ("left", "right")[v % 2]
    free = "right" if sup == "left" else "left"
    n_hops = 3
    vh = (0.0, 0.45, 0.8)[v % 3] + 0.05 * rng.uniform(0, 1)
    apex = 0.09 + 0.04 * rng.uniform(0, 1)
    vy = math.sqrt(2.0 * G * apex)
    ts = 0.3
    heel = math.radians(25.0)
    width = 0.2
    xs = _lat(sup) * 0.07
    ready_y = rig.stand_height - 0.03
    low_y = ready_y - 0.12
    t_lift = 0.4 + 0.2 * rng.uniform(0, 1)
    t_b = t_lift + 0.6
    sup_plant = Plant(t_on=-1.0, t_off=100.0, ankle=np.array([_lat(sup) * width / 2, rig.ankle_height, 0.0]),
                      yaw=-_lat(sup) * math.radians(5.0))
    zero = np.zeros(3)
    knots = [(0.0, np.array([0.0, ready_y + 0.01, 0.0]), zero), (t_b - 0.25, np.array([xs, ready_y, 0.0]), zero),
             (t_b, np.array([xs, low_y, 0.0]), zero)]
    plants_sup: list[Plant] = []
    flights: list[tuple[float, np.ndarray, np.ndarray, float]] = []
    actions: list[dict[str, Any]] = [{"label": "lift_leg", "t0": t_lift, "t1": t_b - 0.25}]
    pitch = math.radians(6.0)
    rot = _qypr(0.0, pitch)
    cur, t_bottom, dz = sup_plant, t_b, vh * ts / 4.0
    for k in range(n_hops):
        t0 = t_bottom + ts / 2.0
        take = replace(cur, t_off=t0, t_heel=t0 - 0.1, heel_pitch=heel)
        plants_sup.append(take)
        z0 = knots[-1][1][2] + dz
        y0 = _root_height_for(rig, np.array([xs, 0.0, z0]), rot, {sup: take.pivot_ankle(rig, np.array([heel]))[0]},
                              0.96 * rig.leg)
        ahead = vh * ts / 2.0
        rel = {sup: np.array([_lat(sup) * width / 2 - xs, rig.ankle_height, ahead])}
        y1 = _root_height_for(rig, np.zeros(3), rot, rel, 0.95 * rig.leg)
        tf = (vy + math.sqrt(vy * vy + 2.0 * G * (y0 - y1))) / G
        p0, v0 = np.array([xs, y0, z0]), np.array([0.0, vy, vh])
        t1 = t0 + tf
        p1, v1 = p0 + v0 * tf - 0.5 * G * tf * tf * _Y, v0 - G * tf * _Y
        knots += [(t0, p0, v0), (t1, p1, v1)]
        flights.append((t0, p0, v0, t1))
        actions.append({"label": "hop", "t0": t_bottom, "t1": t1})
        cur = Plant(t_on=t1, t_off=100.0, ankle=np.array([_lat(sup) * width / 2, rig.ankle_height, p1[2] + ahead]),
                    yaw=sup_plant.yaw)
        if k + 1 < n_hops:
            t_bottom = t1 + ts / 2.0
            knots.append((t_bottom, np.array([xs, low_y, p1[2] + ahead]), np.array([0.0, 0.0, vh])))
            dz = ahead
    plants_sup.append(cur)
    t_abs = 0.25
    depth = max(0.12, abs(v1[1]) * t_abs / 3.0)
    t_a = t1 + t_abs
    knots.append((t_a, np.array([xs, y1 - depth, p1[2] + 0.4 * vh * t_abs]), zero))
    t_rec = t_a + 0.5
    knots.append((t_rec, np.array([xs, ready_y, cur.ankle[2]]), zero))
    t_down = t_rec + 0.4
    knots.append((t_down + 0.3, np.array([0.0, ready_y + 0.01, cur.ankle[2]]), zero))
    t_end = t_down + 0.7
    actions += [{"label": "landing", "t0": t1, "t1": t_a}, {"label": "recover", "t0": t_a, "t1": t_rec},
                {"label": "lower_leg", "t0": t_rec, "t1": t_down}]
    t = _times(t_end, fps)
    free_plants = [Plant(t_on=-1.0, t_off=t_lift, ankle=np.array([_lat(free) * width / 2, rig.ankle_height, 0.0]),
                         yaw=-_lat(free) * math.radians(5.0)),
                   Plant(t_on=t_down, t_off=t_end + 1.0, yaw=-_lat(free) * math.radians(5.0),
                         ankle=np.array([_lat(free) * width / 2, rig.ankle_height, cur.ankle[2]]))]
    plants = {sup: plants_sup, free: free_plants}
    feet = {s: foot_track(rig, t, plants[s], 0.05) for s in SIDES}
    plan = _neutral_plan(rig, t, feet)
    plan.root_pos = _ballistic_root(t, knots, flights)
    carried = plan.root_pos + np.array([_lat(free) * 0.1 - xs, -0.52, -0.22])
    w = _smooth((t - t_lift) / (t_b - 0.25 - t_lift)) * (1.0 - _smooth((t - t_rec) / (t_down - t_rec)))
    _override(plan.feet[free], w, carried, 0.3 * w)
    for fl in flights:  # the support foot follows the root in the air
        t0, p0, _, t1 = fl
        i0 = next(p for p in plants_sup if abs(p.t_off - t0) < 1e-12)
        i1 = next(p for p in plants_sup if abs(p.t_on - t1) < 1e-12)
        r0 = i0.pivot_ankle(rig, np.array([heel]))[0] - p0
        p1 = _ballistic_root(np.array([t1]), knots, flights)[0]
        r1 = i1.ankle - p1
        rel = _hermite(t, [t0, 0.5 * (t0 + t1), t1], np.array([r0, 0.5 * (r0 + r1) + 0.08 * _Y, r1]))
        m = ((t > t0) & (t < t1)).astype(np.float64)
        _override(plan.feet[sup], m, plan.root_pos + rel)
    plan.root_rot = _qypr(np.zeros(len(t)), np.full(len(t), pitch))
    plan.spine[:, 0] = 0.08
    lift = _smooth((t - t_lift) / 0.4) * (1.0 - _smooth((t - t_rec) / 0.5))
    for s in SIDES:
        plan.arms[s][:, 0] += lift * (0.25 + 0.15 * np.sin(2 * np.pi * t / (ts + 0.35)))
        plan.arms[s][:, 1] += 0.35 * lift
        plan.arms[s][:, 2] += 0.6 * lift
    _level_head(plan, np.full(len(t), pitch))
    params = {"support": sup, "hops": n_hops, "horizontal_speed": vh, "apex_height": apex,
              "flight_times": [fl[3] - fl[0] for fl in flights]}
    return ClipSpec(plan, actions, [], [(fl[0], fl[3]) for fl in flights], plants, params)


# --------------------------------------------------------------------------------------------------
# putting it together


def _rng(category: str, variant: int, seed: int) -> np.random.Generator:
    return np.random.default_rng([int(seed) & 0xFFFFFFFF, zlib.crc32(category.encode()), int(variant)])


def _frame_interval(t0: float, t1: float, fps: float, n: int) -> tuple[int, int]:
    return int(np.clip(round(t0 * fps), 0, n - 1)), int(np.clip(round(t1 * fps), 0, n - 1))


def _finish(rig: Rig, spec: ClipSpec, category: str, variant: int, seed: int, fps: float,
            rng: np.random.Generator, name: str) -> tuple[Motion, dict[str, Any]]:
    """Place the clip in the world (random start heading and position), build it, write the truth."""
    motion, ik_miss = build_motion(rig, spec.plan, fps, name)
    yaw0 = float(rng.uniform(-np.pi, np.pi))
    shift = np.array([rng.uniform(-2.0, 2.0), 0.0, rng.uniform(-2.0, 2.0)])
    q0 = _qaxis(_Y, np.array(yaw0))
    root = quat_rotate(q0, motion.root_positions) + shift
    rots = motion.rotations.copy()
    rots[:, 0] = quat_mul(q0, rots[:, 0])
    motion = replace(motion, root_positions=root, rotations=rots)
    n = motion.n_frames
    h0 = float(heading_angle(rots[0, 0]))
    origin = root[0] * np.array([1.0, 0.0, 1.0])

    def to_start(p: np.ndarray) -> np.ndarray:
        return _rot_y(-h0, p - origin)

    actions = []
    for a in spec.actions:
        s, e = _frame_interval(a["t0"], a["t1"], fps, n)
        item = {"label": a["label"], "start_s": a["t0"], "end_s": a["t1"], "start_frame": s, "end_frame": e}
        if "apex" in a:
            item["apex_s"] = a["apex"]
            item["apex_frame"] = round(float(a["apex"]) * fps)
        actions.append(item)
    targets = []
    for tg in spec.targets:
        world = quat_rotate(q0, tg["local"]) + shift
        targets.append({"name": tg["name"], "effector": tg["effector"], "apex_s": tg["t"],
                        "apex_frame": round(float(tg["t"]) * fps), "position": to_start(world), "world": world})
    flights = []
    for a, b in spec.flights:
        s, e = math.ceil(a * fps - 1e-9), math.floor(b * fps + 1e-9)
        if s <= e and s < n and e >= 0:
            flights.append({"start_s": a, "end_s": b, "start_frame": max(s, 0), "end_frame": min(e, n - 1),
                            "duration": b - a, "ballistic": category in _BALLISTIC})
    contacts: dict[str, list[list[int]]] = {}
    heel: dict[str, list[list[int]]] = {}
    for side in SIDES:
        contacts[side], heel[side] = [], []
        for p in spec.plants[side]:
            s, e = max(math.ceil(p.t_on * fps - 1e-9), 0), min(math.floor(p.t_off * fps + 1e-9), n - 1)
            if s <= e:
                contacts[side].append([s, e])
                th = p.t_off if p.t_heel is None else p.t_heel
                eh = min(math.floor(th * fps + 1e-9), n - 1)
                if s <= eh:
                    heel[side].append([s, eh])
    truth = {
        "category": category, "variant": variant, "seed": seed, "fps": fps, "unit": "m", "up": "y",
        "frames": n, "duration": motion.duration, "gravity": G,
        "actions": actions, "targets": targets, "flight": flights,
        "contacts": contacts, "heel_contacts": heel,
        "start": {"yaw_deg": math.degrees(h0), "position": origin},
        "ik_max_miss_m": ik_miss,
        "params": spec.params,
    }
    return motion, truth


#: categories whose flights are exact parabolas under G (runs only approximate them).
_BALLISTIC = ("jump", "hop", "walk_then_jump")

_GENERATORS: dict[str, Callable[[Rig, int, np.random.Generator, float], ClipSpec]] = {
    "walk": _gen_walk,
    "run": _gen_run,
    "jump": _gen_jump,
    "kick": _gen_kick,
    "punch": _gen_punch,
    "reach": _gen_reach,
    "sit": _gen_sit,
    "hop": _gen_hop,
    "idle": _gen_idle,
}


def generate_clip(category: str, variant: int, seed: int, fps: float = 60.0) -> tuple[Motion, dict[str, Any]]:
    """One synthetic clip of ``category`` and its ground truth; deterministic in (category, variant,
    seed, fps). Targets are in the clip's start heading frame (origin: root at frame 0 on the
    ground, axes turned by the heading at frame 0); ``world`` gives them in the file's frame."""
    if category not in _GENERATORS:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")
    rig = Rig.from_skeleton(humanoid_skeleton())
    rng = _rng(category, variant, seed)
    spec = _GENERATORS[category](rig, variant, rng, fps)
    return _finish(rig, spec, category, variant, seed, fps, rng, f"{category}_{variant:02d}")


# --------------------------------------------------------------------------------------------------
# time warps


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


# --------------------------------------------------------------------------------------------------
# writing


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        v = round(float(x), 6)
        return 0.0 if v == 0 else v
    return x


def truth_json(truth: dict[str, Any]) -> str:
    """Canonical JSON text of a ground-truth dict (sorted keys, floats rounded to 6 decimals)."""
    return json.dumps(_jsonable(truth), sort_keys=True, indent=1) + "\n"


def write_clip(motion: Motion, truth: dict[str, Any], stem: Path) -> Path:
    """Write ``<stem>.bvh`` and ``<stem>.json``; returns the BVH path."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    bvh = stem.with_suffix(".bvh")
    write_bvh(motion, bvh)
    stem.with_suffix(".json").write_text(truth_json(truth))
    return bvh


def write_demo_corpus(out_dir: str | Path, seed: int = 7, variants_per_category: int = 3,
                      fps: float = 60.0) -> list[Path]:
    """Write ``<out_dir>/<category>/<category>_<variant:02d>.bvh`` and ``.json`` ground truth for
    every category; returns the BVH paths. Same inputs give the same bytes."""
    out = Path(out_dir)
    paths = []
    for cat in CATEGORIES:
        for v in range(variants_per_category):
            motion, truth = generate_clip(cat, v, seed, fps)
            paths.append(write_clip(motion, truth, out / cat / f"{cat}_{v:02d}"))
    return paths
