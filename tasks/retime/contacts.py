"""Foot contacts and their friction-pyramid force bases (design §8, MPS06 §3.2).

Each foot in contact is a rectangle whose 4 corners each carry a 4-edge friction pyramid
inscribed in the Coulomb cone of coefficient μ (MPS06 Fig. 3): 16 basis forces per foot with
magnitudes λ ≥ 0, mapped to generalized forces by the corners' Jacobians, f_q = Jᵀ P λ = N λ
(MPS06 Eqn. 11). Contacts are detected from the height and speed of the foot's lowest corner;
intervals can be given per clip instead.

Cost: one forward kinematics + 4 frame Jacobians per foot per frame, O(F · n_feet · nv).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from motionweb.store.motion import Skeleton
from motionweb.tasks.retime.dynamics import BodyModel

EDGES_PER_CORNER = 4
CORNERS = 4


@dataclass(frozen=True)
class Foot:
    """A foot: skeleton joint ``joint`` and its sole rectangle ``corners`` (4, 3), joint frame, m."""

    joint: int
    name: str
    corners: np.ndarray


@dataclass(frozen=True, eq=False)
class Contacts:
    """Contact state and force bases along a clip.

    Attributes:
        feet: the feet considered.
        active: (F, n_feet) bool, foot in contact.
        basis: (F, nv, n_feet * 16) generalized force of a unit λ on each basis edge
            (columns of inactive feet are still filled; use ``active`` to select).
        corner_positions: (F, n_feet, 4, 3) world positions of the sole corners, m.
        ground: ground height, m. friction: μ. detected: False when intervals were given.
    """

    feet: tuple[Foot, ...]
    active: np.ndarray
    basis: np.ndarray
    corner_positions: np.ndarray
    ground: float
    friction: float
    detected: bool = True

    def columns(self, frame: int) -> np.ndarray:
        """Indices of the λ columns of the feet in contact at ``frame``."""
        per = CORNERS * EDGES_PER_CORNER
        feet = np.flatnonzero(self.active[frame])
        return (feet[:, None] * per + np.arange(per)[None]).reshape(-1)

    def intervals(self, fps: float) -> dict[str, list[tuple[float, float]]]:
        """Contact intervals in seconds per foot name."""
        out: dict[str, list[tuple[float, float]]] = {}
        for k, foot in enumerate(self.feet):
            runs = []
            a = self.active[:, k].astype(np.int8)
            edges = np.flatnonzero(np.diff(np.concatenate([[0], a, [0]])))
            for s, e in zip(edges[::2], edges[1::2], strict=True):
                runs.append((s / fps, (e - 1) / fps))
            out[foot.name] = runs
        return out


def rest_positions(skeleton: Skeleton, scale: float) -> np.ndarray:
    """(J, 3) joint positions of the rest pose (identity rotations), m."""
    pos = np.zeros((skeleton.n_joints, 3))
    for j in range(1, skeleton.n_joints):
        pos[j] = pos[skeleton.parents[j]] + skeleton.offsets[j] * scale
    return pos


def find_feet(skeleton: Skeleton, scale: float, up_axis: int = 1,
              foot_corners: dict[int, np.ndarray] | None = None) -> tuple[Foot, ...]:
    """The feet: the lowest leaf chains of the rest pose (or the joints of ``foot_corners``).

    A leaf in the lowest 20 % of the rest pose is a foot tip; when its parent is also that low
    (ankle → toe) the parent is the foot joint. The sole spans from 25 % behind the joint to the
    tip, 0.4 × its length wide, flattened to the tip's height. Leaves with no bone get a
    0.2 × 0.1 m square at the joint.
    """
    if foot_corners:
        return tuple(Foot(j, skeleton.names[j], np.asarray(c, dtype=float)) for j, c in foot_corners.items())
    rest = rest_positions(skeleton, scale)
    ends = {}
    for j in range(skeleton.n_joints):
        tip = rest[j].copy()
        if j in skeleton.end_sites:
            tip = rest[j] + np.asarray(skeleton.end_sites[j], dtype=float) * scale
        ends[j] = tip
    heights = np.array([ends[j][up_axis] for j in range(skeleton.n_joints)] + list(rest[:, up_axis]))
    lo, hi = heights.min(), heights.max()
    low = lo + 0.2 * (hi - lo)
    up = np.zeros(3)
    up[up_axis] = 1.0
    feet = []
    for leaf in range(skeleton.n_joints):
        if skeleton.children(leaf) or ends[leaf][up_axis] > low or leaf == 0:
            continue
        joint = leaf
        p = int(skeleton.parents[leaf])
        if p > 0 and rest[p][up_axis] <= low and len(skeleton.children(p)) == 1:
            joint = p
        tip = ends[leaf] - rest[joint]
        horiz = tip - (tip @ up) * up
        length = float(np.linalg.norm(horiz))
        if length < 1e-3:
            fwd = np.zeros(3)
            fwd[(up_axis + 2) % 3] = 1.0
            side = np.cross(up, fwd)
            corners = np.array([0.1 * fwd + 0.05 * side, 0.1 * fwd - 0.05 * side,
                                -0.1 * fwd - 0.05 * side, -0.1 * fwd + 0.05 * side])
            corners += tip @ up * up
        else:
            fwd = horiz / length
            side = np.cross(up, fwd)
            w = 0.2 * length
            drop = (tip @ up) * up
            heel = -0.25 * length * fwd + drop
            corners = np.array([tip + w * side, tip - w * side, heel - w * side, heel + w * side])
        feet.append(Foot(joint, skeleton.names[joint], corners))
    return tuple(feet)


def pyramid(normal: np.ndarray, mu: float) -> np.ndarray:
    """(3, 4) unit edges of the 4-sided friction pyramid inscribed in the cone of ``mu``."""
    n = normal / np.linalg.norm(normal)
    t1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 0.0, 1.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    e = np.stack([n + mu * t1, n - mu * t1, n + mu * t2, n - mu * t2], axis=1)
    return e / np.linalg.norm(e, axis=0)


def contact_bases(body: BodyModel, q: np.ndarray, feet: tuple[Foot, ...], mu: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(F, nv, n_feet·16) force bases N = Jᵀ P and (F, n_feet, 4, 3) corner positions.

    Corner Jacobians are Pinocchio frame Jacobians in LOCAL_WORLD_ALIGNED (linear rows).
    """
    m = body.model.copy()
    fids = []
    for foot in feet:
        for k, c in enumerate(foot.corners):
            fids.append(m.addFrame(pin.Frame(f"{foot.name}_corner{k}", foot.joint + 1, 0,
                                             pin.SE3(np.eye(3), np.asarray(c, float)), pin.FrameType.OP_FRAME)))
    d = m.createData()
    up = np.zeros(3)
    up[body.up_axis] = 1.0
    edges = pyramid(up, mu)  # (3, 4)
    f, nv = q.shape[0], m.nv
    nf = len(feet)
    basis = np.zeros((f, nv, nf * CORNERS * EDGES_PER_CORNER))
    pos = np.zeros((f, nf, CORNERS, 3))
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for i in range(f):
        pin.computeJointJacobians(m, d, q[i])
        pin.updateFramePlacements(m, d)
        for k, fid in enumerate(fids):
            jac = pin.getFrameJacobian(m, d, fid, lwa)[:3]  # (3, nv)
            basis[i, :, k * EDGES_PER_CORNER:(k + 1) * EDGES_PER_CORNER] = jac.T @ edges
            pos[i, k // CORNERS, k % CORNERS] = d.oMf[fid].translation
    return basis, pos


def detect_contacts(corner_positions: np.ndarray, fps: float, *, up_axis: int = 1, ground: float = 0.0,
                    height: float = 0.05, speed: float = 0.3, min_frames: int = 2) -> np.ndarray:
    """(F, n_feet) contact flags: lowest corner within ``height`` of the ground and slower than ``speed``.

    Runs shorter than ``min_frames`` are dropped. Speeds by central differences (m/s).
    """
    h = corner_positions[..., up_axis] - ground  # (F, nf, 4)
    vel = np.gradient(corner_positions, 1.0 / fps, axis=0) if corner_positions.shape[0] > 1 else \
        np.zeros_like(corner_positions)
    low = np.argmin(h, axis=2)  # (F, nf)
    hmin = np.take_along_axis(h, low[..., None], axis=2)[..., 0]
    v = np.linalg.norm(np.take_along_axis(vel, low[..., None, None], axis=2)[:, :, 0], axis=-1)
    act = (hmin <= height) & (v <= speed)
    for k in range(act.shape[1]):
        a = act[:, k].astype(np.int8)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], a, [0]])))
        for s, e in zip(edges[::2], edges[1::2], strict=True):
            if e - s < min_frames:
                act[s:e, k] = False
    return act


def intervals_to_active(intervals: dict[str, list[tuple[float, float]]], feet: tuple[Foot, ...],
                        n_frames: int, fps: float) -> np.ndarray:
    """(F, n_feet) flags from ``{foot joint name: [(start_s, end_s), ...]}`` (others: no contact)."""
    names = [f.name for f in feet]
    act = np.zeros((n_frames, len(feet)), bool)
    for name, runs in intervals.items():
        if name not in names:
            raise ValueError(f"contact override names {name!r}, not a foot; the feet are {', '.join(names)}")
        k = names.index(name)
        for s, e in runs:
            i0 = max(int(np.ceil(s * fps - 1e-9)), 0)
            i1 = min(int(np.floor(e * fps + 1e-9)), n_frames - 1)
            act[i0:i1 + 1, k] = True
    return act


def contacts_for(body: BodyModel, q: np.ndarray, fps: float, *, mu: float = 0.5, height: float = 0.05,
                 speed: float = 0.3, ground: float = 0.0,
                 intervals: dict[str, list[tuple[float, float]]] | None = None,
                 foot_corners: dict[int, np.ndarray] | None = None) -> Contacts:
    """Feet, their contact flags (detected, or from ``intervals``) and force bases (MPS06 §3.2)."""
    feet = find_feet(body.skeleton, body.scale, body.up_axis, foot_corners or body.foot_corners or None)
    if not feet:
        raise ValueError("no feet found in the skeleton (no low leaf joints); give foot corners")
    basis, pos = contact_bases(body, q, feet, mu)
    if intervals:
        active = intervals_to_active(intervals, feet, q.shape[0], fps)
    else:
        active = detect_contacts(pos, fps, up_axis=body.up_axis, ground=ground, height=height, speed=speed)
    return Contacts(feet=feet, active=active, basis=basis, corner_positions=pos, ground=ground,
                    friction=mu, detected=not intervals)
