"""Quaternion algebra, forward kinematics, resampling and the heading frame (design §2).

Quaternions are ``(..., 4)`` arrays ``(w, x, y, z)``; every function broadcasts over leading axes
and is vectorized over frames (the only Python loops run over joints, J ~ 20-60).
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
from motionweb.store.motion import Motion
from motionweb.store.numba_cache import njit
from scipy.spatial.transform import Rotation

AXES = {"x": 0, "y": 1, "z": 2}


def axis_index(axis: str) -> int:
    """0, 1, 2 for 'x', 'y', 'z' (case-insensitive)."""
    try:
        return AXES[axis.lower()]
    except KeyError:
        raise ValueError(f"unknown axis {axis!r}; expected one of x, y, z") from None


def quat_identity(shape: tuple[int, ...] = ()) -> np.ndarray:
    q = np.zeros(shape + (4,))
    q[..., 0] = 1.0
    return q


def quat_normalize(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (apply b first, then a)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bw - ax * bx - ay * by - az * bz
    out[..., 1] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 2] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 3] = aw * bz + ax * by - ay * bx + az * bw
    return out


def quat_inv(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion (its conjugate)."""
    return np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4)."""
    q = np.asarray(q, dtype=np.float64)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation by ``angle`` radians about unit ``axis`` (..., 3)."""
    half = 0.5 * np.asarray(angle, dtype=np.float64)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * np.asarray(axis, dtype=np.float64)], axis=-1)


def quat_from_euler(angles: np.ndarray, order: str, degrees: bool = True) -> np.ndarray:
    """Quaternions from Euler angles (..., len(order)) in an intrinsic order such as ``"ZXY"``.

    BVH semantics: channels ``Zrotation Xrotation Yrotation`` mean ``R = Rz @ Rx @ Ry``.
    """
    angles = np.asarray(angles, dtype=np.float64)
    half = 0.5 * (np.deg2rad(angles) if degrees else angles)
    cos, sin = np.cos(half), np.sin(half)
    q = None
    for k, ax in enumerate(order.lower()):
        step = np.zeros(angles.shape[:-1] + (4,))
        step[..., 0] = cos[..., k]
        step[..., 1 + axis_index(ax)] = sin[..., k]
        q = step if q is None else quat_mul(q, step)
    return quat_identity(angles.shape[:-1]) if q is None else q


def quat_to_euler(q: np.ndarray, order: str, degrees: bool = True) -> np.ndarray:
    """Euler angles (..., 3) in intrinsic ``order`` for quaternions (inverse of quat_from_euler)."""
    q = np.asarray(q, dtype=np.float64)
    flat = q.reshape(-1, 4)
    if len(flat) == 0:
        return np.zeros(q.shape[:-1] + (3,))
    rot = Rotation.from_quat(flat[:, [1, 2, 3, 0]])
    with warnings.catch_warnings():  # at gimbal lock any split of the angles is exact; scipy warns
        warnings.filterwarnings("ignore", "Gimbal lock", UserWarning)
        angles = rot.as_euler(order.upper(), degrees=degrees)
    return angles.reshape(q.shape[:-1] + (3,))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices."""
    w, x, y, z = np.moveaxis(quat_normalize(np.asarray(q, dtype=np.float64)), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def quat_from_matrix(m: np.ndarray) -> np.ndarray:
    """Unit quaternions (w >= 0) from (..., 3, 3) rotation matrices."""
    m = np.asarray(m, dtype=np.float64)
    xyzw = Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat()
    q = xyzw[:, [3, 0, 1, 2]].reshape(m.shape[:-2] + (4,))
    return quat_canonical(q)


def quat_canonical(q: np.ndarray) -> np.ndarray:
    """The representative with w >= 0 (q and -q are the same rotation)."""
    return np.where(q[..., :1] < 0, -q, q)


def quat_log(q: np.ndarray) -> np.ndarray:
    """Quaternion logarithm (..., 3): axis * half-angle, for unit q taken with w >= 0."""
    q = quat_canonical(quat_normalize(np.asarray(q, dtype=np.float64)))
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    half = np.arctan2(s, q[..., :1])
    scale = np.where(s > 1e-12, half / np.where(s > 1e-12, s, 1.0), 1.0)
    return v * scale


def quat_exp(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`quat_log`: unit quaternion from axis * half-angle (..., 3)."""
    v = np.asarray(v, dtype=np.float64)
    half = np.linalg.norm(v, axis=-1, keepdims=True)
    sinc = np.where(half > 1e-12, np.sin(half) / np.where(half > 1e-12, half, 1.0), 1.0)
    return np.concatenate([np.cos(half), v * sinc], axis=-1)


def quat_slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation along the shorter arc; ``t`` broadcasts against q[..., 0]."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.sin(theta)
    small = sin_t < 1e-9
    safe = np.where(small, 1.0, sin_t)
    w0 = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    w1 = np.where(small, t, np.sin(t * theta) / safe)
    return quat_normalize(w0 * q0 + w1 * q1)


def quat_average(q: np.ndarray, weights: np.ndarray, axis: int = 0) -> np.ndarray:
    """Normalised weighted average of quaternions along ``axis``.

    Each quaternion is first flipped onto the hemisphere of the one with the largest weight, then
    the weighted sum is normalised. Weights may be slightly negative (KG04 §4.2 near-convex
    weights); they need not sum to one.
    """
    q = np.moveaxis(np.asarray(q, dtype=np.float64), axis, 0)
    w = np.asarray(weights, dtype=np.float64)
    ref = q[int(np.argmax(w))]
    sign = np.where(np.sum(q * ref, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    total = np.tensordot(w, q * sign, axes=(0, 0))
    return quat_normalize(total)


def forward_kinematics(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Global joint positions (F, J, 3) and rotations (F, J, 4), in the file's unit.

    O(F·J), compiled: :func:`forward_kinematics_of` every joint (the operations of :func:`quat_mul`
    and :func:`quat_rotate` in their order, so the same bits as those NumPy formulas, without their
    per-joint temporaries; the index's features call it three times per clip, KG04 §3.1).
    """
    return forward_kinematics_of(motion, np.arange(motion.skeleton.n_joints))


def joint_paths(parents: np.ndarray, joints) -> np.ndarray:
    """Sorted indices of ``joints`` and of every ancestor of theirs (the root-to-joint paths);
    parents precede children, so the order is one FK can follow."""
    par = np.asarray(parents).tolist()
    keep = [False] * len(par)
    for j in np.atleast_1d(np.asarray(joints, np.int64)).tolist():
        while j >= 0 and not keep[j]:
            keep[j] = True
            j = par[j]
    return np.flatnonzero(keep)


def forward_kinematics_of(motion: Motion, joints) -> tuple[np.ndarray, np.ndarray]:
    """Global positions (F, J, 3) and rotations (F, J, 4) of ``joints`` and their ancestors only
    (e.g. the hip-to-foot paths leg IK needs), in the file's unit; every other joint is NaN.

    :func:`forward_kinematics` is this on every joint: O(F·K) for the K joints on the paths, with
    no per-joint Python overhead.
    """
    order = joint_paths(motion.skeleton.parents, joints)
    f, j = motion.n_frames, motion.skeleton.n_joints
    gpos = np.full((f, j, 3), np.nan)
    grot = np.full((f, j, 4), np.nan)
    trans = np.broadcast_to(motion.skeleton.offsets, (f, j, 3))
    moved = [k for k in motion.translations if k in order]
    if moved:
        trans = trans.copy()
        for k in moved:
            trans[:, k] = motion.translations[k]
    _fk_paths(np.ascontiguousarray(motion.rotations, np.float64), np.ascontiguousarray(trans, np.float64),
              np.ascontiguousarray(motion.root_positions, np.float64), motion.skeleton.parents, order, gpos, grot)
    return gpos, grot


@njit(cache=True)
def _fk_paths(local, trans, root, parents, order, gpos, grot):  # pragma: no cover - compiled
    """FK over ``order`` (parents first), frame by frame, with quat_mul's and quat_rotate's
    formulas in their order of operations.

    Bounds: writes frames < F and joints of ``order`` (indices < J, :func:`joint_paths`) of
    ``gpos``/``grot`` (F, J, ·), the caller's arrays of the motion's shape."""
    for f in range(local.shape[0]):
        for j in order:
            if j == 0:
                for c in range(4):
                    grot[f, 0, c] = local[f, 0, c]
                for c in range(3):
                    gpos[f, 0, c] = root[f, c]
                continue
            p = parents[j]
            aw, ax, ay, az = grot[f, p, 0], grot[f, p, 1], grot[f, p, 2], grot[f, p, 3]
            bw, bx, by, bz = local[f, j, 0], local[f, j, 1], local[f, j, 2], local[f, j, 3]
            grot[f, j, 0] = aw * bw - ax * bx - ay * by - az * bz
            grot[f, j, 1] = aw * bx + ax * bw + ay * bz - az * by
            grot[f, j, 2] = aw * by - ax * bz + ay * bw + az * bx
            grot[f, j, 3] = aw * bz + ax * by - ay * bx + az * bw
            vx, vy, vz = trans[f, j, 0], trans[f, j, 1], trans[f, j, 2]
            tx = 2.0 * (ay * vz - az * vy)
            ty = 2.0 * (az * vx - ax * vz)
            tz = 2.0 * (ax * vy - ay * vx)
            gpos[f, j, 0] = gpos[f, p, 0] + (vx + aw * tx + (ay * tz - az * ty))
            gpos[f, j, 1] = gpos[f, p, 1] + (vy + aw * ty + (az * tx - ax * tz))
            gpos[f, j, 2] = gpos[f, p, 2] + (vz + aw * tz + (ax * ty - ay * tx))


def end_site_positions(motion: Motion, global_positions: np.ndarray, global_rotations: np.ndarray) -> np.ndarray:
    """(F, E, 3) global positions of the skeleton's end sites, in ``sorted(end_sites)`` order."""
    keys = sorted(motion.skeleton.end_sites)
    if not keys:
        return np.zeros((motion.n_frames, 0, 3))
    offs = np.stack([motion.skeleton.end_sites[k] for k in keys])
    return global_positions[:, keys] + quat_rotate(global_rotations[:, keys], offs[None])


def sample_motion(motion: Motion, frames: np.ndarray) -> Motion:
    """The motion at fractional frame indices ``frames`` (slerp rotations, lerp translations).

    Indices are clamped to [0, F-1]; the result keeps ``motion.fps``.
    """
    frames = np.clip(np.asarray(frames, dtype=np.float64), 0.0, motion.n_frames - 1)
    i0 = np.floor(frames).astype(np.int64)
    i1 = np.minimum(i0 + 1, motion.n_frames - 1)
    t = frames - i0

    def lerp(a: np.ndarray) -> np.ndarray:
        tt = t.reshape((-1,) + (1,) * (a.ndim - 1))
        return (1.0 - tt) * a[i0] + tt * a[i1]

    rot = quat_slerp(motion.rotations[i0], motion.rotations[i1], t[:, None])
    return replace(
        motion,
        root_positions=lerp(motion.root_positions),
        rotations=rot,
        translations={j: lerp(tr) for j, tr in motion.translations.items()},
    )


def resample(motion: Motion, fps: float) -> Motion:
    """The motion at another frame rate over the same time span (slerp rotations, lerp root)."""
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    n = int(np.floor(motion.duration * fps + 1e-9)) + 1
    frames = np.arange(n) * (motion.fps / fps)
    return replace(sample_motion(motion, frames), fps=float(fps))


def hold_ends(motion: Motion, seconds: float) -> Motion:
    """The motion with its first and last poses held still for ``seconds`` before and after."""
    pad = round(seconds * motion.fps)

    def held(a: np.ndarray) -> np.ndarray:
        return np.concatenate([a[:1].repeat(pad, 0), a, a[-1:].repeat(pad, 0)])

    return replace(motion, root_positions=held(motion.root_positions), rotations=held(motion.rotations),
                   translations={j: held(t) for j, t in motion.translations.items()})


def heading(rotations: np.ndarray, up: str = "y") -> np.ndarray:
    """Rotation about the vertical axis contained in ``rotations`` (..., 4): its twist about ``up``.

    The swing-twist decomposition keeps the part of each root rotation that turns about the
    vertical axis; this is the root heading frame used by features and alignment.
    """
    q = np.asarray(rotations, dtype=np.float64)
    k = axis_index(up)
    twist = np.zeros_like(q)
    twist[..., 0] = q[..., 0]
    twist[..., 1 + k] = q[..., 1 + k]
    norm = np.linalg.norm(twist, axis=-1, keepdims=True)
    identity = quat_identity(q.shape[:-1])
    return np.where(norm > 1e-9, twist / np.where(norm > 1e-9, norm, 1.0), identity)


def heading_angle(rotations: np.ndarray, up: str = "y") -> np.ndarray:
    """Heading angle in radians about ``up`` (right-handed), in (-pi, pi]."""
    h = heading(rotations, up)
    k = axis_index(up)
    return np.angle(np.exp(1j * 2.0 * np.arctan2(h[..., 1 + k], h[..., 0])))


def to_heading_frame(positions: np.ndarray, root_position: np.ndarray, root_rotation: np.ndarray,
                     up: str = "y") -> np.ndarray:
    """Express global positions (F, N, 3) in each frame's root heading frame.

    The origin is the root projected on the ground plane; axes are turned by the inverse heading.
    """
    k = axis_index(up)
    origin = np.array(root_position, dtype=np.float64, copy=True)
    origin[..., k] = 0.0
    inv = quat_inv(heading(root_rotation, up))
    return quat_rotate(inv[:, None, :], positions - origin[:, None, :])


def foot_joints(motion: Motion, up: str = "y", fraction: float = 0.12) -> np.ndarray:
    """Indices of the joints (and, past J, the end sites in ``sorted(end_sites)`` order) that make
    up the feet: those whose height in the rest pose lies within ``fraction`` of the body's height
    above its lowest point. Needs no joint names, so any skeleton works."""
    rest = replace(motion, root_positions=np.zeros((1, 3)), rotations=quat_identity((1, motion.skeleton.n_joints)),
                   translations={})
    gp, gr = forward_kinematics(rest)
    pts = np.concatenate([gp, end_site_positions(rest, gp, gr)], axis=1)[0]
    h = pts[:, axis_index(up)]
    return np.flatnonzero(h <= h.min() + fraction * np.ptp(h))


def airborne_intervals(motion: Motion, margin_m: float = 0.05, min_s: float = 0.1, up: str = "y"
                       ) -> list[tuple[int, int]]:
    """Flight phases (first, last frame) of a clip: runs of at least ``min_s`` seconds in which
    every foot point (:func:`foot_joints`) is more than ``margin_m`` metres above the clip's own
    floor (its lowest foot height). Kinematic only: a quick test for jumps, not a contact model.
    O(F·J)."""
    if motion.scale_to_m is None:
        raise ValueError(f"{motion.name or 'motion'}: unknown length unit (set scale_to_m)")
    gp, gr = forward_kinematics(motion)
    pts = np.concatenate([gp, end_site_positions(motion, gp, gr)], axis=1)[:, foot_joints(motion, up)]
    low = pts[..., axis_index(up)].min(axis=1) * motion.scale_to_m  # (F,)
    air = low > low.min() + margin_m
    edges = np.flatnonzero(np.diff(np.concatenate([[0], air.astype(np.int8), [0]])))
    runs = [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    return [(a, b) for a, b in runs if (b - a + 1) >= max(1, round(min_s * motion.fps))]
