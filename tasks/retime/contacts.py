"""Foot contacts and their friction-pyramid force bases (design §8, MPS06 §3.2).

Each foot in contact is a sole rectangle whose 4 corners each carry a 4-edge friction pyramid
inscribed in the Coulomb cone of coefficient μ (MPS06 Fig. 3): 16 basis forces per foot with
magnitudes λ ≥ 0, mapped to generalized forces by the corners' Jacobians, f_q = Jᵀ P λ = N λ
(MPS06 Eqn. 11). A foot with a toe segment has 2 more corners across the ball of the foot (the toe
joint): a foot up on its toes then stands on the forefoot patch from the ball to the toe tips, not on
the line of its tips (24 basis forces). Contacts are detected per foot end (toe, heel) from its height above the clip's
own floor and its speed, with hysteresis and minimum durations (the rule of
:class:`~motionweb.tasks.params.retime.ContactParams`, which holds its defaults); a
"flight" whose centre of mass does not fall at gravity is a stance the rule missed and gets its
lowest slow foot (:func:`missed_stances`); intervals can be given per clip instead.

Cost: one forward kinematics + 4 frame Jacobians per foot per frame, O(F · n_feet · nv).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin
from motionweb.store.motion import Skeleton
from motionweb.tasks.params.retime import ContactParams
from motionweb.tasks.retime.dynamics import BodyModel, centre_of_mass

EDGES_PER_CORNER = 4
#: sole corners: toe tips 0-1, heel 2-3, and (feet with a toe segment) the ball of the foot 4-5
TOE, HEEL, BALL = (0, 1), (2, 3), (4, 5)
#: a flight whose centre of mass falls farther than this (relative) from gravity is not ballistic
BALLISTIC_TOLERANCE = 0.25


@dataclass(frozen=True)
class Foot:
    """A foot: skeleton joint ``joint`` and its sole ``corners`` (K, 3), joint frame, m: toe tips,
    heel and, K = 6, the ball of the foot (:data:`TOE`, :data:`HEEL`, :data:`BALL`)."""

    joint: int
    name: str
    corners: np.ndarray


@dataclass(frozen=True, eq=False)
class Contacts:
    """Contact state and force bases along a clip.

    Attributes:
        feet: the feet considered.
        active: (F, n_feet) bool, foot in contact.
        basis: (F, nv, n_feet * K * 4) generalized force of a unit λ on each basis edge, K corners
            per foot (columns of inactive feet are still filled; use ``active`` to select).
        corner_positions: (F, n_feet, K, 3) world positions of the sole corners, m.
        ground: ground (floor) height, m. friction: μ. detected: False when intervals were given.
        corner_active: (F, n_feet, K) sole corners that may push (toe or heel down), None: all
            corners of an active foot.
        carried: the basis has one more column past the feet's, the clip's own unexplained root
            wrench, active in every frame (:meth:`carrying`).
    """

    feet: tuple[Foot, ...]
    active: np.ndarray
    basis: np.ndarray
    corner_positions: np.ndarray
    ground: float
    friction: float
    detected: bool = True
    corner_active: np.ndarray | None = None
    carried: bool = False

    def carrying(self, wrench: np.ndarray) -> Contacts:
        """These contacts with the wrench (F, 6) appended as a last basis column on the root rows."""
        col = np.zeros(self.basis.shape[:2] + (1,))
        col[:, :wrench.shape[1], 0] = wrench
        return replace(self, basis=np.concatenate([self.basis, col], axis=2), carried=True)

    @property
    def corners(self) -> int:
        """Sole corners per foot, K."""
        return self.corner_positions.shape[2]

    def columns(self, frame: int) -> np.ndarray:
        """Indices of the λ columns of the feet (and sole corners) in contact at ``frame``."""
        per = self.corners * EDGES_PER_CORNER
        feet = np.flatnonzero(self.active[frame])
        cols = (feet[:, None] * per + np.arange(per)[None]).reshape(-1)
        if self.corner_active is not None:
            cols = cols[self.corner_active[frame][feet].repeat(EDGES_PER_CORNER, axis=1).reshape(-1)]
        return np.append(cols, self.basis.shape[2] - 1) if self.carried else cols

    def intervals(self, fps: float) -> dict[str, list[tuple[float, float]]]:
        """Contact intervals in seconds per foot name."""
        out: dict[str, list[tuple[float, float]]] = {}
        for k, foot in enumerate(self.feet):
            out[foot.name] = [(s / fps, (e - 1) / fps) for s, e in runs(self.active[:, k])]
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
    tip, 0.4 × its length wide, flattened to the tip's height; the toe joint between (the ball of
    the foot) adds a corner pair across the sole there (:data:`BALL`). Leaves with no bone get a
    0.2 × 0.1 m square at the joint. All feet of a skeleton get the same number of corners (the
    ball pair only when every foot has a toe joint ahead of the ankle).
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
        ball = rest[leaf] - rest[joint]  # the toe joint (zero when the leaf is the foot joint)
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
            along = float(ball @ fwd)
            if joint != leaf and 0.2 * length < along < 0.95 * length:
                mid = along * fwd + drop
                corners = np.vstack([corners, [mid - w * side, mid + w * side]])
        feet.append(Foot(joint, skeleton.names[joint], corners))
    if len({len(f.corners) for f in feet}) > 1:  # one layout for every foot: drop the ball pairs
        feet = [replace(f, corners=f.corners[:4]) for f in feet]
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
    nf, nc = len(feet), len(feet[0].corners)
    if any(len(ft.corners) != nc for ft in feet):
        raise ValueError(f"every foot needs the same number of sole corners, got {[len(ft.corners) for ft in feet]}")
    basis = np.zeros((f, nv, nf * nc * EDGES_PER_CORNER))
    pos = np.zeros((f, nf, nc, 3))
    lwa = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for i in range(f):
        pin.computeJointJacobians(m, d, q[i])
        pin.updateFramePlacements(m, d)
        for k, fid in enumerate(fids):
            jac = pin.getFrameJacobian(m, d, fid, lwa)[:3]  # (3, nv)
            basis[i, :, k * EDGES_PER_CORNER:(k + 1) * EDGES_PER_CORNER] = jac.T @ edges
            pos[i, k // nc, k % nc] = d.oMf[fid].translation
    return basis, pos


def clip_floor(corner_positions: np.ndarray, up_axis: int = 1, quantile: float = 0.05) -> float:
    """The clip's floor: over the feet, the lowest ``quantile`` of each foot's per-frame lowest sole height.

    Mocap floors are rarely at exactly 0 (marker offsets, skeleton fitting): reading the floor from
    the clip's own feet makes the contact heights relative to where this subject stood. Robust to
    a few frames of a foot sinking (a quantile, not the minimum). O(F · n_feet).
    """
    h = corner_positions[..., up_axis].min(axis=2)  # (F, nf)
    return float(np.quantile(h, quantile, axis=0).min())


def runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index pairs of the runs of True in a 1-D bool array."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], flags.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def hysteresis(low_on: np.ndarray, low_off: np.ndarray) -> np.ndarray:
    """(F,) on where ``low_on`` holds, staying on while ``low_off`` holds (``low_on`` ⊂ ``low_off``)."""
    out = np.zeros(len(low_on), bool)
    state = False
    for i in range(len(low_on)):
        state = bool(low_on[i]) or (state and bool(low_off[i]))
        out[i] = state
    return out


def one_sided_speed(step: np.ndarray, n_frames: int) -> np.ndarray:
    """(F,) the smaller of a point's backward and forward speeds from its steps (F-1, 3) (m/s).

    A foot that lands stops within a frame or two: the central difference at its first frame on
    the ground still averages the approach speed, and at its last frame the lift-off speed. A
    contact frame is one where the point is still on at least one side, so the smaller one-sided
    speed dates touchdown and lift-off to the frame (120 Hz mocap: ±8 ms).
    """
    if n_frames < 2:
        return np.zeros(n_frames)
    v = np.linalg.norm(step, axis=-1)
    return np.minimum(np.concatenate([[np.inf], v]), np.concatenate([v, [np.inf]]))


def detect_contacts(corner_positions: np.ndarray, fps: float, *, up_axis: int = 1, rule: ContactParams,
                    floor: float | None) -> tuple[np.ndarray, np.ndarray, float]:
    """Contact flags per foot (F, n_feet) and per sole corner (F, n_feet, K), and the floor used.

    The rule is :class:`~motionweb.tasks.params.retime.ContactParams`' (MPS06 §3.2 needs contacts;
    the paper does not say how they are read): per foot end (toe: sole corners 0, 1; heel: 2, 3)
    its lower corner's height above ``floor`` (None: the clip's own floor, :func:`clip_floor`) and
    its midpoint's speed. ``corner_positions`` (F, n_feet, K, 3). Speeds: the smaller one-sided
    speed (:func:`one_sided_speed`). The ball corners (K = 6) push with the toe end: a foot whose toe
    tips are down and heel up pivots on its ball, and a flat foot has all three down; a heel alone
    down (heel strike, toes up) pushes with the heel corners. In a frame where a foot is in contact
    by gap closing only, all its corners may push. O(F · n_feet).
    """
    f, nf = corner_positions.shape[:2]
    floor = clip_floor(corner_positions, up_axis) if floor is None else float(floor)
    h = corner_positions[..., up_axis] - floor  # (F, nf, 4)
    step = np.diff(corner_positions, axis=0) * fps  # (F-1, nf, 4, 3): velocity between frames i and i+1
    act = np.zeros((f, nf), bool)
    nc = corner_positions.shape[2]
    corner = np.zeros((f, nf, nc), bool)
    min_gap = int(round(rule.gap_s * fps))
    min_contact = int(round(rule.min_s * fps))
    for k in range(nf):
        ends = []
        for pair in (TOE, HEEL):
            hp = h[:, k, pair].min(axis=1)
            vp = one_sided_speed(step[:, k, pair].mean(axis=1), f)
            ground = hp <= rule.height_ground
            ends.append(hysteresis(((hp <= rule.height_on) & (vp <= rule.speed_on)) | ground,
                                   ((hp <= rule.height_off) & (vp <= rule.speed_off)) | ground))
        a = ends[0] | ends[1]
        for s, e in runs(~a):
            if s > 0 and e < f and e - s < min_gap:
                a[s:e] = True
        for s, e in runs(a):
            if e - s < min_contact:
                a[s:e] = False
        act[:, k] = a
        toe, heel = ends[0] & a, ends[1] & a
        neither = a & ~toe & ~heel
        corner[:, k, list(TOE)] = (toe | neither)[:, None]
        corner[:, k, list(HEEL)] = (heel | neither)[:, None]
        if nc > 4:
            corner[:, k, list(BALL)] = (toe | neither)[:, None]
    return act, corner, floor


def fall_rate(height: np.ndarray, fps: float) -> float:
    """The acceleration (m/s², down positive) ``height`` (n,) samples at ``fps`` fall at: −2 × the
    quadratic coefficient of their least-squares parabola (n ≥ 3)."""
    t = np.arange(len(height)) / fps
    return -2.0 * float(np.polyfit(t - t.mean(), height, 2)[0])


def missed_stances(body: BodyModel, q: np.ndarray, pos: np.ndarray, active: np.ndarray, corner: np.ndarray,
                   floor: float, fps: float, rule: ContactParams) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, int]]]:
    """Stances the rule missed: a "flight" (no foot down, between contacts, at least 4 frames)
    whose centre of mass does not fall at gravity (more than :data:`BALLISTIC_TOLERANCE` off)
    is carried by a foot. The foot that stays lowest is put down for it (all its corners) if it
    stays within ``rule.height_off`` of the floor and slower than ``rule.speed_off`` all along —
    a pivoting foot hovering just above ``height_on`` (CMU 16_29's turn). A real flight falls at
    gravity, or lifts its feet. Returns the new (F, nf) and (F, nf, K) flags and the (start, end,
    foot) runs put down. O(F_flight · B)."""
    active, corner = active.copy(), corner.copy()
    g = float(np.linalg.norm(body.default_gravity()))
    up, f = body.up_axis, active.shape[0]
    mended = []
    for s, e in runs(~active.any(axis=1)):
        if s == 0 or e == f or e - s < 4:
            continue
        if abs(fall_rate(centre_of_mass(body, q[s:e])[:, up], fps) / g - 1.0) <= BALLISTIC_TOLERANCE:
            continue
        low = pos[s:e, ..., up].min(axis=2) - floor  # (n, nf)
        speed = np.linalg.norm(np.gradient(pos[s - 1:e + 1].mean(axis=2), axis=0) * fps, axis=-1)[1:-1]
        ok = (low.max(axis=0) <= rule.height_off) & (speed.max(axis=0) <= rule.speed_off)
        if ok.any():
            k = int(np.argmin(np.where(ok, low.mean(axis=0), np.inf)))
            active[s:e, k] = True
            corner[s:e, k] = True
            mended.append((s, e, k))
    return active, corner, mended


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


def contacts_for(body: BodyModel, q: np.ndarray, fps: float, *, rule: ContactParams, clip: str | None,
                 intervals: dict[str, list[tuple[float, float]]] | None = None,
                 foot_corners: dict[int, np.ndarray] | None = None) -> Contacts:
    """Feet, their contact flags (detected by ``rule`` on clip ``clip``'s floor, or from ``intervals``)
    and force bases with ``rule.friction`` (MPS06 §3.2). ``rule`` is required: ``ContactParams``
    holds its defaults."""
    feet = find_feet(body.skeleton, body.scale, body.up_axis, foot_corners or body.foot_corners or None)
    if not feet:
        raise ValueError("no feet found in the skeleton (no low leaf joints); give foot corners")
    basis, pos = contact_bases(body, q, feet, rule.friction)
    active, corner, floor = detect_contacts(pos, fps, up_axis=body.up_axis, rule=rule, floor=rule.floor_of(clip))
    active, corner, _ = missed_stances(body, q, pos, active, corner, floor, fps, rule)
    if intervals:
        active, corner = intervals_to_active(intervals, feet, q.shape[0], fps), None
    return Contacts(feet=feet, active=active, basis=basis, corner_positions=pos, ground=floor,
                    friction=rule.friction, detected=not intervals, corner_active=corner)
