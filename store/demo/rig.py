"""The procedural demo rig: a 22-joint humanoid, analytic two-bone IK, foot plants and tracks, and
`build_motion`, which turns a plan (root path, foot tracks, upper-body angles, effector targets)
into joint rotations so that the ground truth (planted feet, reached targets) holds by construction.

Units are metres, Y is up, the character faces +Z in its rest pose, quaternions are (w, x, y, z).
The clip generators (`clips.py`) build plans with these pieces.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from motionweb.store.kinematics import (
    forward_kinematics,
    quat_from_axis_angle,
    quat_from_matrix,
    quat_inv,
    quat_mul,
    quat_rotate,
    quat_to_matrix,
)
from motionweb.store.motion import Motion, Skeleton

#: gravity (m/s²) used by every ballistic flight.
G = 9.81
SIDES = ("left", "right")

_ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
_ROT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
UNIT_X = np.array([1.0, 0.0, 0.0])
UNIT_Y = np.array([0.0, 1.0, 0.0])
UNIT_Z = np.array([0.0, 0.0, 1.0])


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


def smooth(u: np.ndarray | float) -> np.ndarray:
    """Cubic ease 3u² - 2u³ on [0, 1] (clamped): C1 with zero end slopes."""
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def hermite(t: np.ndarray, kt: Any, kp: Any, kv: Any = None) -> np.ndarray:
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


def qaxis(axis: np.ndarray, angle: np.ndarray | float) -> np.ndarray:
    angle = np.asarray(angle, dtype=np.float64)
    return quat_from_axis_angle(np.broadcast_to(axis, angle.shape + (3,)), angle)


def qypr(yaw: Any, pitch: Any = 0.0, roll: Any = 0.0) -> np.ndarray:
    """Ry(yaw) · Rx(pitch) · Rz(roll) (radians, broadcast). Positive pitch leans +Y toward +Z."""
    yaw, pitch, roll = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (yaw, pitch, roll)))
    return quat_mul(qaxis(UNIT_Y, yaw), quat_mul(qaxis(UNIT_X, pitch), qaxis(UNIT_Z, roll)))


def rot_y(yaw: Any, v: np.ndarray) -> np.ndarray:
    return quat_rotate(qaxis(UNIT_Y, yaw), v)


def unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-12, n, 1.0)


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
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
    p = unit(pole - np.sum(pole * u, axis=-1, keepdims=True) * u)
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
        return self.ankle + rot_y(self.yaw, rig.toe_offset)

    def pivot_ankle(self, rig: Rig, alpha: np.ndarray) -> np.ndarray:
        """Ankle positions (n, 3) with the heel raised by ``alpha`` about the toe joint."""
        alpha = np.atleast_1d(np.asarray(alpha, dtype=np.float64))
        return self.toe(rig) - quat_rotate(qypr(self.yaw, alpha), rig.toe_offset)

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
            a = p.heel_pitch * smooth((t[m] - th) / (p.t_off - th))
            ankle[m], yaw[m], pitch[m], stance[m] = p.pivot_ankle(rig, a), p.yaw, a, True
        end_ankle, end_pitch = p.end_state(rig)
        if k + 1 < len(plants):
            q = plants[k + 1]
            m = (t > p.t_off) & (t < q.t_on)
            u = (t[m] - p.t_off) / (q.t_on - p.t_off)
            s = smooth(u)[:, None]
            ankle[m] = end_ankle + s * (q.ankle - end_ankle) + (lift * np.sin(np.pi * u) ** 2)[:, None] * UNIT_Y
            pitch[m] = end_pitch * (1.0 - s[:, 0])
            yaw[m] = p.yaw + s[:, 0] * wrap_angle(q.yaw - p.yaw)
        else:
            m = t > p.t_off
            ankle[m], yaw[m], pitch[m] = end_ankle, p.yaw, end_pitch
    return FootTrack(ankle, yaw, pitch, stance)


def override_foot(track: FootTrack, w: np.ndarray, ankle: np.ndarray, pitch: np.ndarray | None = None) -> None:
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
    shoulder = quat_mul(qaxis(UNIT_Z, sign * angles[:, 1]), qaxis(UNIT_X, -angles[:, 0]))
    elbow = qaxis(UNIT_X, -angles[:, 2])
    return shoulder, elbow


def build_motion(rig: Rig, plan: Plan, fps: float, name: str = "") -> tuple[Motion, float]:
    """Joint rotations for a plan (leg and arm IK); returns the motion and the worst IK miss (m)."""
    sk = rig.skeleton
    idx = sk.index
    f = len(plan.t)
    rot = np.zeros((f, sk.n_joints, 4))
    rot[..., 0] = 1.0
    rot[:, 0] = plan.root_rot
    third = qypr(plan.spine[:, 1] / 3, plan.spine[:, 0] / 3, plan.spine[:, 2] / 3)
    for j in ("Spine", "Spine1", "Spine2"):
        rot[:, idx(j)] = third
    half = qypr(plan.head[:, 1] / 2, plan.head[:, 0] / 2, plan.head[:, 2] / 2)
    rot[:, idx("Neck")] = half
    rot[:, idx("Head")] = half
    for side, prefix in zip(SIDES, ("Left", "Right"), strict=True):
        shoulder, elbow = _arm_quats(plan.arms[side], side)
        rot[:, idx(prefix + "Arm")] = shoulder
        rot[:, idx(prefix + "ForeArm")] = elbow
    worst = 0.0
    r_root = quat_to_matrix(plan.root_rot)
    lateral = quat_rotate(plan.root_rot, UNIT_X)
    for side, prefix in zip(SIDES, ("Left", "Right"), strict=True):
        foot = plan.feet[side]
        hip = plan.root_pos + quat_rotate(plan.root_rot, rig.hip_offset[side])
        ankle = _soft_reach(hip, foot.ankle, 0.9 * rig.leg, 0.985 * rig.leg, ~foot.stance)
        u = unit(ankle - hip)
        out = lateral if side == "left" else -lateral
        pole = np.cross(u, lateral) + 0.08 * out
        r1, r2, miss = two_bone_ik(hip, ankle, rig.thigh, rig.shin, pole, -UNIT_Y, UNIT_Z)
        worst = max(worst, float(np.max(miss[foot.stance], initial=0.0)))
        rot[:, idx(prefix + "UpLeg")] = quat_from_matrix(np.swapaxes(r_root, -1, -2) @ r1)
        rot[:, idx(prefix + "Leg")] = quat_from_matrix(np.swapaxes(r1, -1, -2) @ r2)
        q_shin = quat_from_matrix(r2)
        rot[:, idx(prefix + "Foot")] = quat_mul(quat_inv(q_shin), qypr(foot.yaw, foot.pitch))
        # the toes stay level while the heel is up (they bend at the ball of the foot)
        rot[:, idx(prefix + "ToeBase")] = qaxis(UNIT_X, -np.maximum(foot.pitch, 0.0))
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
            lat = quat_rotate(grot[:, idx("Spine2")], UNIT_X)
            out = lat if side == "left" else -lat
            u = unit(goal - shoulder)
            pole = np.cross(lat, u) + 0.6 * out - 0.3 * UNIT_Y
            r1, r2, miss = two_bone_ik(shoulder, goal, rig.upper_arm, rig.forearm, pole, -UNIT_Y, -UNIT_Z)
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


def max_root_heights(rig: Rig, root_xz_pos: np.ndarray, root_rot: np.ndarray, feet: dict[str, FootTrack],
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


def root_height_for(rig: Rig, root_xz: np.ndarray, rot: np.ndarray, ankles: dict[str, np.ndarray],
                     reach: float) -> float:
    """Highest root height at one instant keeping the given ankles within ``reach`` of the hips."""
    best = np.inf
    for side, a in ankles.items():
        off = quat_rotate(rot, rig.hip_offset[side])
        hip = np.array([root_xz[0], 0.0, root_xz[2]]) + off
        dh2 = (hip[0] - a[0]) ** 2 + (hip[2] - a[2]) ** 2
        best = min(best, a[1] + math.sqrt(max(reach * reach - dh2, 0.0)) - off[1])
    return float(best)


def neutral_plan(rig: Rig, t: np.ndarray, feet: dict[str, FootTrack]) -> Plan:
    f = len(t)
    return Plan(t=t, root_pos=np.zeros((f, 3)), root_rot=qypr(np.zeros(f)), feet=feet,
                spine=np.zeros((f, 3)), head=np.zeros((f, 3)),
                arms={s: np.tile([0.0, math.radians(6.0), math.radians(12.0)], (f, 1)) for s in SIDES})


def level_head(plan: Plan, pelvis_pitch: np.ndarray, gain: float = 0.8) -> None:
    plan.head[:, 0] = -gain * (plan.spine[:, 0] + pelvis_pitch)
    plan.head[:, 1] += -0.5 * plan.spine[:, 1]


def frame_times(duration: float, fps: float) -> np.ndarray:
    return np.arange(round(duration * fps) + 1) / fps


def lateral_sign(side: str) -> float:
    return 1.0 if side == "left" else -1.0


