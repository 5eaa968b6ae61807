"""Blending registered examples (KG04 §4, with Kovar & Gleicher 2003's registration curves
simplified; design §6).

The examples are the nodes of a query's :class:`~motionweb.tasks.register.Registration`: for every
query frame u (at the registration's rate) each example i is sampled at its registered frame
s_i(u) (slerp rotations, lerp root), giving N motions on one common timeline of U samples
(:func:`registered_examples`, :class:`Examples`). Per example and sample:

* alignment (KG04 §3.1's 2-D rigid transform): the rotation θ_i(u) about the vertical and the
  horizontal shift that best align the example's joint cloud to the query's (:func:`align_frames`).
  It gives each example a *reference heading* φ_i(u) = h_q(u) − θ_i(u): the query's heading h_q
  seen in the example's own coordinates, so all examples share one notion of "forward";
* the root rotation relative to that heading, Ry(−φ_i)·q_root, the root height, the horizontal
  root step to the next sample in the heading frame (at the mid heading), the heading change and
  the frame duration (s_i(u+1) − s_i(u)) / rate.

A blend with weights w (N,) (may be slightly negative, sum 1; :func:`blend_path` and
:func:`blend_poses` take many weight vectors at once, (S, N)) averages every joint's rotation
(normalised weighted quaternion average, each example's quaternions put on one hemisphere once),
the heading-relative root rotation, root height, steps, heading changes and frame durations, and
integrates the root path from the blended steps: heading Φ(u) = Σ Δφ̄, position
P(u+1) = P(u) + Ry(Φ̄_mid)·step̄. The blend starts at the origin facing +Z (heading 0): it lives
in its own start-heading frame, the frame the parameter functions of ``tasks/parameterize.py``
measure in. Time advances by the blended durations; :func:`blend` resamples to a uniform rate.

Constraint matching (KG03 §5, KG04 §4): foot plants are found in every example
(:func:`detect_plants`: ankle low and slow), carried through the registration (plant_i(u) =
plant at the example's frame nearest s_i(u)), and a foot is planted in the blend where the
examples planted there carry at least half the weight. Each planted run of the blend holds its
ankle at the run's mean position by analytic two-bone leg IK (:func:`leg_ik`), eased in and out
over ``BlendParams.ease_s``; the foot keeps its global orientation. :func:`foot_skate` measures
the mean horizontal ankle speed over planted frames (cm/s).

Units: positions in metres (the examples' file unit times ``scale_to_m``), Y up. Cost of a blend:
O(S·N·U·J) for S weight vectors (only examples with non-zero weight matter, so a sparse blend of
d + 1 examples costs the same whatever N is), plus O(F·J) FK and IK for the output motion.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from motionweb.store.kinematics import (
    forward_kinematics,
    forward_kinematics_of,
    heading_angle,
    quat_from_axis_angle,
    quat_mul,
    quat_normalize,
    quat_rotate,
    sample_motion,
)
from motionweb.store.motion import Motion, Skeleton
from motionweb.tasks.matchgraph import Segment
from motionweb.tasks.params.blend import BlendParams
from motionweb.tasks.register import Registration
from motionweb.store.numba_cache import njit

SIDES = ("left", "right")
_Y = np.array([0.0, 1.0, 0.0])


# ----------------------------------------------------------------------------------- skeleton
_ANKLE = {"left": re.compile(r"^(left_?foot|l_?foot|left_?ankle|l_?ankle)$", re.I),
          "right": re.compile(r"^(right_?foot|r_?foot|right_?ankle|r_?ankle)$", re.I)}


def leg_chains(skeleton: Skeleton, feet: dict[str, str] | None = None) -> dict[str, tuple[int, int, int]]:
    """(hip, knee, ankle) joint indices of each leg: the ankle by name (``feet`` or the usual
    names), the knee its parent, the hip the knee's parent. ValueError naming a missing joint."""
    out = {}
    for side in SIDES:
        if feet and side in feet:
            if feet[side] not in skeleton.names:
                raise ValueError(f"unknown {side} ankle joint {feet[side]!r}; joints: {', '.join(skeleton.names)}")
            ankle = skeleton.index(feet[side])
        else:
            hits = [j for j, n in enumerate(skeleton.names) if _ANKLE[side].match(n)]
            if not hits:
                raise ValueError(f"no {side} ankle joint found by name; set blend.feet.{side} to one of "
                                 f"{', '.join(skeleton.names)}")
            ankle = hits[0]
        knee = int(skeleton.parents[ankle])
        hip = int(skeleton.parents[knee]) if knee >= 0 else -1
        if hip < 0:
            raise ValueError(f"{side} ankle {skeleton.names[ankle]!r} has no knee and hip above it")
        out[side] = (hip, knee, ankle)
    return out


def metric_skeleton(motion: Motion) -> Skeleton:
    """The motion's skeleton with offsets in metres."""
    s = motion.metres()
    sk = motion.skeleton
    return replace(sk, offsets=sk.offsets * s, end_sites={k: v * s for k, v in sk.end_sites.items()})


# ----------------------------------------------------------------------------------- alignment
def align_frames(p: np.ndarray, q: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the rotation about +y and horizontal translation taking cloud q onto cloud p
    (KG04 §3.1's optimal 2-D rigid alignment, vectorised over frames).

    p, q: (U, P, 3) clouds; weights (P,). Returns theta (U,) radians and t (U, 2) (x, z), applied
    after the rotation — the same transform as ``tasks.distance.rigid_align_2d`` frame by frame.
    """
    w = np.asarray(weights, np.float64)
    w = w / w.sum()
    cp = np.stack([p[..., 0] @ w, p[..., 2] @ w], -1)
    cq = np.stack([q[..., 0] @ w, q[..., 2] @ w], -1)
    x, z = p[..., 0] - cp[:, :1], p[..., 2] - cp[:, 1:]
    x2, z2 = q[..., 0] - cq[:, :1], q[..., 2] - cq[:, 1:]
    a = (x * x2 + z * z2) @ w
    b = (x * z2 - z * x2) @ w
    theta = np.arctan2(b, a)
    c, s = np.cos(theta), np.sin(theta)
    rq = np.stack([c * cq[:, 0] + s * cq[:, 1], -s * cq[:, 0] + c * cq[:, 1]], -1)
    return theta, cp - rq


def yaw_quat(angle: np.ndarray) -> np.ndarray:
    """Rotations about +y by ``angle`` (...,) radians, (..., 4)."""
    a = np.asarray(angle, np.float64)
    return quat_from_axis_angle(np.broadcast_to(_Y, a.shape + (3,)), a)


def rotate_xz(v: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(..., 2) (x, z) vectors turned about +y by ``angle`` (right-handed: +z toward +x)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1]], -1)


# ----------------------------------------------------------------------------------- plants
def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Inclusive (start, end) index pairs of the True runs of a 1-D mask."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.flatnonzero(np.diff(m.astype(np.int8)))
    return [(int(a), int(b) - 1) for a, b in zip(d[::2], d[1::2], strict=True)]


def detect_plants(ankles: np.ndarray, fps: float, cfg: BlendParams) -> np.ndarray:
    """Foot plants from ankle paths: (F, 2, 3) positions (m, y up) -> (F, 2) bool. A foot is
    planted where its ankle is within ``plant_height`` of its lowest point and its horizontal
    speed (central differences) is below ``plant_speed``; runs shorter than ``plant_min_s`` drop."""
    f = len(ankles)
    if f < 2:
        return np.zeros((f, 2), bool)
    vel = np.gradient(ankles[..., [0, 2]], axis=0) * fps
    speed = np.linalg.norm(vel, axis=-1)
    low = ankles[..., 1] <= ankles[..., 1].min(axis=0) + cfg.plant_height
    mask = low & (speed <= cfg.plant_speed)
    shortest = max(1, math.ceil(cfg.plant_min_s * fps - 1e-9))
    for k in range(2):
        for a, b in runs(mask[:, k]):
            if b - a + 1 < shortest:
                mask[a:b + 1, k] = False
    return mask


def foot_skate(ankles: np.ndarray, plants: np.ndarray, fps: float) -> float:
    """Mean horizontal ankle speed over planted frames, cm/s (0 when nothing is planted).
    ankles (F, 2, 3) in metres, plants (F, 2)."""
    vel = np.gradient(ankles[..., [0, 2]], axis=0) * fps
    speed = np.linalg.norm(vel, axis=-1)
    return float(100.0 * speed[plants].mean()) if plants.any() else 0.0


# ----------------------------------------------------------------------------------- examples
def keytime_registration(motions: Sequence[Motion], keys: Sequence[np.ndarray], rate: float = 30.0) -> Registration:
    """A :class:`Registration` from corresponding key times (seconds; e.g. a demo clip's known
    action times or foot touchdowns): column c maps the query's (clip 0's) keys ``keys[0]`` onto
    ``keys[c]``, linear between keys, at every query frame at ``rate`` — a ground truth to test
    blending against, or a manual registration where the match graph has none."""
    k0 = np.asarray(keys[0], np.float64)
    if len(k0) < 2 or any(len(k) != len(k0) or np.any(np.diff(k) <= 0) for k in keys):
        raise ValueError("key times: the same number (≥ 2) per clip, strictly increasing")
    u = np.arange(round(k0[0] * rate), round(k0[-1] * rate) + 1, dtype=np.float64)
    fr = np.stack([np.interp(u / rate, k0, np.asarray(k, np.float64)) * rate for k in keys], 1)
    fr[:, 0] = u
    segs = [Segment(m.name, int(np.ceil(fr[0, c] - 1e-9)), int(np.floor(fr[-1, c] + 1e-9)))
            for c, m in enumerate(motions)]
    fr = np.clip(fr, [s.start for s in segs], [s.end for s in segs])
    n = len(motions)
    return Registration(rate, list(range(n)), segs, [-1] + [0] * (n - 1), np.zeros(n), fr, [])


@dataclass
class Examples:
    """N examples registered on a common timeline of U samples (KG04 §4.1), ready to blend.

    ``skeleton`` is the query's in metres; ``rate`` the registration rate (samples of u per second
    of the query). Per example i and sample u: ``local`` (N, U, J, 4) joint rotations with the root
    rotation relative to the reference heading, all on one hemisphere per (u, j); ``height``
    (N, U) root height; ``step`` (N, U−1, 2) horizontal root step (x, z) to the next sample in the
    heading frame; ``turn`` (N, U−1) heading change; ``dt`` (N, U−1) seconds between samples;
    ``plants`` (N, U, 2) carried foot plants (left, right). ``names`` label the examples,
    ``scale_to_m`` is the examples' metres per file unit, ``unit`` their unit.
    """

    skeleton: Skeleton
    rate: float
    names: list[str]
    local: np.ndarray
    height: np.ndarray
    step: np.ndarray
    turn: np.ndarray
    dt: np.ndarray
    plants: np.ndarray
    legs: dict[str, tuple[int, int, int]]
    scale_to_m: float = 1.0
    unit: str | None = "m"

    @property
    def n(self) -> int:
        return self.local.shape[0]

    @property
    def n_samples(self) -> int:
        return self.local.shape[1]

    def subset(self, keep: Sequence[int]) -> Examples:
        """The examples ``keep`` only (same timeline)."""
        k = list(keep)
        return replace(self, names=[self.names[i] for i in k], local=self.local[k], height=self.height[k],
                       step=self.step[k], turn=self.turn[k], dt=self.dt[k], plants=self.plants[k])


def registered_examples(motions: Sequence[Motion], reg: Registration, names: Sequence[str] | None = None,
                        cfg: BlendParams | None = None) -> Examples:
    """Sample every registered node at s_i(u) and precompute what a blend needs (see module doc).

    ``motions[c]`` is the clip of ``reg.segments[c]`` (column c; column 0 the query), at its own
    fps; the registration's frames count at ``reg.rate``. All clips must share the query's joint
    names. Plants are detected on each example's segment at its own fps and carried through s_i.
    Cost O(N·U·J) plus the examples' FK over their segments.
    """
    cfg = cfg or BlendParams()
    if len(motions) != len(reg.segments):
        raise ValueError(f"{len(motions)} motions for {len(reg.segments)} registered nodes")
    q = motions[0]
    for c, m in enumerate(motions):
        if m.skeleton.names != q.skeleton.names:
            raise ValueError(f"example {c} ({m.name!r}) has other joints than the query; blends need one skeleton")
    sk = metric_skeleton(q)
    legs = leg_chains(sk, cfg.feet)
    frames = reg.frames  # (U, N) at reg.rate
    u_n, n = frames.shape
    if u_n < 2:
        raise ValueError("a blend needs a registration of at least 2 samples")
    clouds, roots, rots, plants, dts = [], [], [], [], []
    for c, m in enumerate(motions):
        s = m.metres()
        fr = frames[:, c] * m.fps / reg.rate
        smp = sample_motion(m, fr)
        smp = replace(smp, skeleton=sk, root_positions=smp.root_positions * s, unit="m", scale_to_m=1.0,
                      translations={})
        gpos, _ = forward_kinematics(smp)
        clouds.append(gpos)
        roots.append(smp.root_positions)
        rots.append(smp.rotations)
        dts.append(np.diff(frames[:, c]) / reg.rate)
        # plants on the example's own frames over its segment, carried through s_i(u)
        seg = reg.segments[c]
        a = max(0, math.floor(seg.start * m.fps / reg.rate))
        b = min(m.n_frames - 1, math.ceil(seg.end * m.fps / reg.rate))
        own = replace(m, skeleton=sk, root_positions=m.root_positions[a:b + 1] * s, rotations=m.rotations[a:b + 1],
                      translations={})
        gp, _ = forward_kinematics(own)
        ank = gp[:, [legs["left"][2], legs["right"][2]]]
        pl = detect_plants(ank, m.fps, cfg)
        idx = np.clip(np.rint(fr).astype(np.int64) - a, 0, len(pl) - 1)
        plants.append(pl[idx])
    clouds_a = np.stack(clouds)  # (N, U, J, 3)
    w = np.ones(sk.n_joints)
    h_q = np.unwrap(heading_angle(rots[0][:, 0]))
    local = np.stack(rots)  # (N, U, J, 4)
    phi = np.empty((n, u_n))
    for c in range(n):
        theta, _ = align_frames(clouds_a[0], clouds_a[c], w)
        phi[c] = h_q - np.unwrap(theta)
    root = np.stack(roots)  # (N, U, 3)
    local[:, :, 0] = quat_mul(yaw_quat(-phi), local[:, :, 0])
    ref = local[0]
    local = np.where(np.sum(local * ref[None], axis=-1, keepdims=True) < 0, -local, local)
    mid = 0.5 * (phi[:, 1:] + phi[:, :-1])
    step = rotate_xz(np.diff(root[..., [0, 2]], axis=1), -mid)
    return Examples(skeleton=sk, rate=float(reg.rate), names=list(names or [m.name for m in motions]),
                    local=local, height=root[..., 1].copy(), step=step, turn=np.diff(phi, axis=1),
                    dt=np.stack(dts), plants=np.stack(plants), legs=legs,
                    scale_to_m=float(q.metres()), unit=q.unit)


# ----------------------------------------------------------------------------------- blending
def check_weights(weights: np.ndarray, n: int, tol: float = 1e-6) -> np.ndarray:
    """(S, N) float weights, each row summing to 1 (ValueError otherwise)."""
    w = np.atleast_2d(np.asarray(weights, np.float64))
    if w.shape[-1] != n:
        raise ValueError(f"{w.shape[-1]} weights for {n} examples")
    if not np.all(np.isfinite(w)):
        raise ValueError("weights must be finite")
    bad = np.abs(w.sum(axis=-1) - 1.0) > tol
    if bad.any():
        raise ValueError(f"blend weights must sum to 1, got {w[bad][0].sum():.6g}")
    return w


def blend_path(ex: Examples, weights: np.ndarray, upto: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Blended root path of S weight vectors (S, N): positions (S, V, 3) and headings (S, V) for
    the first V = ``upto`` + 1 samples (all by default), from the origin facing +Z. O(S·N·V)."""
    w = check_weights(weights, ex.n)
    v = ex.n_samples if upto is None else int(upto) + 1
    turn = w @ ex.turn[:, :v - 1]  # (S, V-1)
    phi = np.concatenate([np.zeros((len(w), 1)), np.cumsum(turn, axis=1)], axis=1)
    step = np.einsum("sn,nuc->suc", w, ex.step[:, :v - 1])
    mid = 0.5 * (phi[:, 1:] + phi[:, :-1])
    xz = np.concatenate([np.zeros((len(w), 1, 2)), np.cumsum(rotate_xz(step, mid), axis=1)], axis=1)
    pos = np.stack([xz[..., 0], w @ ex.height[:, :v], xz[..., 1]], -1)
    return pos, phi


def blend_poses(ex: Examples, weights: np.ndarray, samples: np.ndarray | slice | None = None) -> np.ndarray:
    """(S, V, J, 4) blended local rotations at the samples ``samples`` (all by default): the
    normalised weighted quaternion average; the root's still relative to the heading. O(S·N·V·J)."""
    w = check_weights(weights, ex.n)
    sel = slice(None) if samples is None else samples
    nz = np.flatnonzero(np.any(w != 0.0, axis=0))
    q = np.einsum("sn,nvjc->svjc", w[:, nz], ex.local[nz][:, sel])
    return quat_normalize(q)


def blend_durations(ex: Examples, weights: np.ndarray, cfg: BlendParams | None = None) -> np.ndarray:
    """(S, U−1) blended seconds between samples, floored at ``min_step`` of their mean."""
    cfg = cfg or BlendParams()
    w = check_weights(weights, ex.n)
    dt = w @ ex.dt
    return np.maximum(dt, cfg.min_step * np.mean(ex.dt))


def posed(ex: Examples, root: np.ndarray, heading: np.ndarray, local: np.ndarray, fps: float) -> Motion:
    """A metric motion from blended root positions (F, 3), headings (F,) and local rotations
    (F, J, 4) whose root is relative to the heading."""
    rot = local.copy()
    rot[:, 0] = quat_mul(yaw_quat(heading), local[:, 0])
    return Motion(skeleton=ex.skeleton, fps=float(fps), root_positions=root, rotations=rot, unit="m", scale_to_m=1.0)


@dataclass
class BlendResult:
    """A blended motion (metric, uniform ``fps``) with what it was made of: the weights (N,), the
    plants it holds (F, 2), its foot skate before and after IK (cm/s), the worst IK miss (m) and
    the time of every sample u in the output (U,) seconds."""

    motion: Motion
    weights: np.ndarray
    plants: np.ndarray
    skate_raw: float
    skate: float
    ik_miss: float
    times: np.ndarray


def blend(ex: Examples, weights: np.ndarray, fps: float | None = None, cfg: BlendParams | None = None,
          hold_feet: bool = True, measure: bool = True) -> BlendResult:
    """Blend the examples with ``weights`` (N,) (sum 1, may be slightly negative) into one motion
    at ``fps`` (default: the registration rate), with foot plants held by leg IK (KG04 §4).
    ``measure=False`` skips the foot-skate figures (NaN) and the FK they need. Cost O(N'·U·J) for
    the N' examples of non-zero weight plus O(F·J) FK/IK."""
    cfg = cfg or BlendParams()
    w = check_weights(weights, ex.n)[0]
    fps = float(fps or ex.rate)
    pos, phi = blend_path(ex, w[None])
    local = blend_poses(ex, w[None])[0]
    times = np.concatenate([[0.0], np.cumsum(blend_durations(ex, w[None], cfg)[0])])
    on_u = posed(ex, pos[0], phi[0], local, ex.rate)
    n_out = int(math.floor(times[-1] * fps + 1e-9)) + 1
    at = np.interp(np.arange(n_out) / fps, times, np.arange(ex.n_samples, dtype=np.float64))
    motion = replace(sample_motion(on_u, at), fps=fps)
    vote = np.einsum("n,nuk->uk", w, ex.plants.astype(np.float64))
    plants = vote[np.clip(np.rint(at).astype(np.int64), 0, ex.n_samples - 1)] >= 0.5
    feet = [ex.legs["left"][2], ex.legs["right"][2]]
    hold = hold_feet and bool(plants.any())
    if not (hold or measure):
        return BlendResult(motion, w, plants, float("nan"), float("nan"), 0.0, times)
    fk = forward_kinematics_of(motion, feet)
    raw = foot_skate(fk[0][:, feet], plants, fps) if measure else float("nan")
    miss, skate = 0.0, raw
    if hold:
        motion, miss = hold_plants(motion, ex.legs, plants, cfg, fk)
        skate = foot_skate(forward_kinematics_of(motion, feet)[0][:, feet], plants, fps) if measure else float("nan")
    return BlendResult(motion, w, plants, raw, skate, miss, times)


def to_file_unit(motion: Motion, scale_to_m: float, unit: str | None) -> Motion:
    """A metric motion expressed in a file unit (``scale_to_m`` metres per unit)."""
    s = 1.0 / scale_to_m
    sk = motion.skeleton
    sk = replace(sk, offsets=sk.offsets * s, end_sites={k: v * s for k, v in sk.end_sites.items()})
    return replace(motion, skeleton=sk, root_positions=motion.root_positions * s, unit=unit, scale_to_m=scale_to_m)


# ----------------------------------------------------------------------------------- leg IK
def leg_ik(gpos: np.ndarray, grot: np.ndarray, parents: np.ndarray, chain: tuple[int, int, int],
           target: np.ndarray, fallback_axis: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Analytic two-bone IK of one leg over F frames: new local rotations of hip, knee and ankle
    ((F, 4) each) putting the ankle on ``target`` (F, 3), and the miss (F,) when out of reach.

    The knee bends about its current axis (``fallback_axis`` (F, 3) when the leg is straight) to
    the law-of-cosines angle, then the whole leg turns about the hip by the shortest rotation onto
    the target; the foot keeps its global rotation. ``gpos``/``grot`` (F, J, 3|4) are global FK
    (only the hip's parent, hip, knee and ankle are read, so :func:`forward_kinematics_of` of the
    ankle suffices). Compiled, O(F); ``tests/naive.py`` keeps the same steps in numpy.
    """
    hip, knee, ankle = chain
    f = len(gpos)
    n_j = np.shape(gpos)[1] if np.ndim(gpos) == 3 else 0
    if np.shape(grot)[:2] != (f, n_j) or np.shape(target) != (f, 3) or np.shape(fallback_axis) != (f, 3):
        raise ValueError(f"leg_ik needs gpos (F, J, 3), grot (F, J, 4), target and fallback_axis (F, 3) for F = {f}")
    if not all(0 <= int(k) < n_j for k in chain) or not -1 <= int(parents[hip]) < n_j:
        raise ValueError(f"the leg {chain} is not a chain of joints of a {n_j}-joint skeleton")
    out = np.empty((3, f, 4))
    miss = np.empty(f)
    _leg_ik_kernel(np.ascontiguousarray(gpos, np.float64), np.ascontiguousarray(grot, np.float64),
                   int(parents[hip]), hip, knee, ankle, np.ascontiguousarray(target, np.float64),
                   np.ascontiguousarray(fallback_axis, np.float64), out, miss)
    return out[0], out[1], out[2], miss


@njit(cache=True, inline="always")
def _qmul(aw, ax, ay, az, bw, bx, by, bz):  # pragma: no cover - compiled
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


@njit(cache=True)
def _leg_ik_kernel(gpos, grot, parent, hip, knee, ankle, target, fallback, out, miss):  # pragma: no cover
    """Frame by frame: the bend about the knee axis, the swing about the hip (shortest rotation
    of the bent ankle onto the target; a half turn about any perpendicular axis), the new local
    rotations into ``out`` (3, F, 4) = hip, knee, ankle and the miss (F,).

    Bounds: writes frames f < F of ``out`` and ``miss``; reads joints hip, knee, ankle and parent
    (< J, checked by :func:`leg_ik`)."""
    for f in range(gpos.shape[0]):
        hx, hy, hz = gpos[f, hip, 0], gpos[f, hip, 1], gpos[f, hip, 2]
        kx, ky, kz = gpos[f, knee, 0], gpos[f, knee, 1], gpos[f, knee, 2]
        ax_, ay_, az_ = gpos[f, ankle, 0], gpos[f, ankle, 1], gpos[f, ankle, 2]
        ux, uy, uz = kx - hx, ky - hy, kz - hz  # thigh
        vx, vy, vz = ax_ - kx, ay_ - ky, az_ - kz  # shin
        l1 = math.sqrt(ux * ux + uy * uy + uz * uz)
        l2 = math.sqrt(vx * vx + vy * vy + vz * vz)
        tx, ty, tz = target[f, 0] - hx, target[f, 1] - hy, target[f, 2] - hz
        d_t = math.sqrt(tx * tx + ty * ty + tz * tz)
        dc = min(max(d_t, abs(l1 - l2) + 1e-9), (l1 + l2) * (1.0 - 1e-9))
        wx, wy, wz = ax_ - hx, ay_ - hy, az_ - hz
        d0 = math.sqrt(wx * wx + wy * wy + wz * wz)
        beta0 = math.acos(min(max((l1 ** 2 + l2 ** 2 - d0 ** 2) / (2 * l1 * l2), -1.0), 1.0))
        beta = math.acos(min(max((l1 ** 2 + l2 ** 2 - dc ** 2) / (2 * l1 * l2), -1.0), 1.0))
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        if norm > 1e-9 * max(l1 * l2, 1e-12):
            nx, ny, nz = nx / norm, ny / norm, nz / norm
        else:
            nx, ny, nz = fallback[f, 0], fallback[f, 1], fallback[f, 2]
        half = 0.5 * (beta0 - beta)
        c, s = math.cos(half), math.sin(half)
        bw, bx, by, bz = c, s * nx, s * ny, s * nz
        # bent ankle a1 = k + bend(shin), relative to the hip
        px, py, pz = 2.0 * (by * vz - bz * vy), 2.0 * (bz * vx - bx * vz), 2.0 * (bx * vy - by * vx)
        rx = vx + bw * px + (by * pz - bz * py)
        ry = vy + bw * py + (bz * px - bx * pz)
        rz = vz + bw * pz + (bx * py - by * px)
        ex, ey, ez = ux + rx, uy + ry, uz + rz
        # shortest rotation from e onto t
        ne = math.sqrt(ex * ex + ey * ey + ez * ez)
        nt = d_t
        ex, ey, ez = ex / ne, ey / ne, ez / ne
        gx, gy, gz = tx / nt, ty / nt, tz / nt
        d = ex * gx + ey * gy + ez * gz
        if d < -1.0 + 1e-12:  # opposite: any axis perpendicular to e
            sw, sx, sy, sz = 0.0, 0.0, ez, -ey  # e × (1, 0, 0)
            if math.sqrt(sy * sy + sz * sz) < 1e-6:
                sx, sy, sz = ey, -ex, 0.0  # e × (0, 0, 1)
        else:
            sw, sx, sy, sz = 1.0 + d, ey * gz - ez * gy, ez * gx - ex * gz, ex * gy - ey * gx
        ns = math.sqrt(sw * sw + sx * sx + sy * sy + sz * sz)
        sw, sx, sy, sz = sw / ns, sx / ns, sy / ns, sz / ns
        hw, hx_, hy_, hz_ = _qmul(sw, sx, sy, sz, grot[f, hip, 0], grot[f, hip, 1], grot[f, hip, 2], grot[f, hip, 3])
        k0 = _qmul(bw, bx, by, bz, grot[f, knee, 0], grot[f, knee, 1], grot[f, knee, 2], grot[f, knee, 3])
        kw, kx_, ky_, kz_ = _qmul(sw, sx, sy, sz, k0[0], k0[1], k0[2], k0[3])
        if parent >= 0:
            pw, px_, py_, pz_ = grot[f, parent, 0], -grot[f, parent, 1], -grot[f, parent, 2], -grot[f, parent, 3]
        else:
            pw, px_, py_, pz_ = 1.0, -0.0, -0.0, -0.0
        lh = _qmul(pw, px_, py_, pz_, hw, hx_, hy_, hz_)
        lk = _qmul(hw, -hx_, -hy_, -hz_, kw, kx_, ky_, kz_)
        la = _qmul(kw, -kx_, -ky_, -kz_, grot[f, ankle, 0], grot[f, ankle, 1], grot[f, ankle, 2], grot[f, ankle, 3])
        for c4 in range(4):
            out[0, f, c4] = lh[c4]
            out[1, f, c4] = lk[c4]
            out[2, f, c4] = la[c4]
        miss[f] = abs(d_t - dc)


def ease_offsets(n: int, plants: np.ndarray, ankles: np.ndarray, ramp: int, holds: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Ankle corrections (F, 3) holding every planted run of ``plants`` (F,) at its mean ankle
    position (``ankles`` (F, 3)), eased to zero over ``ramp`` frames on either side (smoothstep;
    overlapping ramps average), and the frames (F,) that need IK. ``holds`` (F, 3), when given,
    is where each run is held instead of its mean (read at the run's first frame; the foot-slide
    cleanup of tasks/cleanup.py passes points the leg reaches). Compiled, O(F·ramp)."""
    if len(plants) != n or np.shape(ankles) != (n, 3) or (holds is not None and np.shape(holds) != (n, 3)):
        raise ValueError(f"ease_offsets needs {n} plant flags and ({n}, 3) ankles (and holds), got {len(plants)} and "
                         f"{np.shape(ankles)}")
    off = np.zeros((n, 3))
    wsum = np.zeros(n)
    ank = np.ascontiguousarray(ankles, np.float64)
    _ease_kernel(np.ascontiguousarray(plants, np.bool_), ank, int(ramp), off, wsum,
                 ank if holds is None else np.ascontiguousarray(holds, np.float64), holds is not None)
    return off, wsum > 0


@njit(cache=True)
def _ease_kernel(plants, ankles, ramp, off, wsum, holds, given):  # pragma: no cover - compiled
    """Bounds: writes frames max(0, a − ramp) .. min(F, b + 1 + ramp) − 1 of ``off``/``wsum`` (F,) for
    each planted run a..b: frames 0..F − 1 only, whatever ``ramp``."""
    n = len(plants)
    i = 0
    while i < n:
        if not plants[i]:
            i += 1
            continue
        a = i
        while i < n and plants[i]:
            i += 1
        b = i - 1
        hold = np.zeros(3)
        if given:
            hold += holds[a]
        else:
            for f in range(a, b + 1):
                hold += ankles[f]
            hold /= b - a + 1
        for f in range(a, b + 1):
            off[f] += hold - ankles[f]
            wsum[f] += 1.0
        for f in range(max(0, a - ramp), min(n, b + 1 + ramp)):
            if a <= f <= b:
                continue
            edge = a if f < a else b
            s = 1.0 - abs(f - edge) / (ramp + 1.0)
            s = s * s * (3.0 - 2.0 * s)
            off[f] += s * (hold - ankles[edge])
            wsum[f] += 1.0
    for f in range(n):
        if wsum[f] > 0:
            off[f] /= max(wsum[f], 1.0)


def hold_plants(motion: Motion, legs: dict[str, tuple[int, int, int]], plants: np.ndarray,
                cfg: BlendParams, fk: tuple[np.ndarray, np.ndarray] | None = None,
                ik: Callable = leg_ik, ease: Callable = ease_offsets,
                holds: dict[str, np.ndarray] | None = None) -> tuple[Motion, float]:
    """Hold each planted foot still (its run's mean ankle position) by leg IK, corrections eased
    over ``cfg.ease_s`` (KG03 constraint matching); ``fk`` = the motion's global (positions,
    rotations) of at least the root-to-ankle paths when already computed. Returns the motion and
    the worst miss (m). O(F) for the two legs (only their FK paths are computed). ``ik`` and
    ``ease`` are the two steps (the compiled ones; tests run the numpy references through the
    same loop). ``holds`` ({side: (F, 3)}, file units) replaces the runs' mean ankle positions
    as the points held (see :func:`ease_offsets`)."""
    feet = [legs[side][2] for side in SIDES]
    gpos, grot = fk if fk is not None else forward_kinematics_of(motion, feet)
    rot = motion.rotations.copy()
    ramp = max(1, round(cfg.ease_s * motion.fps))
    lateral = quat_rotate(grot[:, 0], np.array([1.0, 0.0, 0.0]))
    worst = 0.0
    for k, side in enumerate(SIDES):
        hip, knee, ankle = legs[side]
        if holds is None:
            off, mask = ease(motion.n_frames, plants[:, k], gpos[:, ankle], ramp)
        else:
            off, mask = ease(motion.n_frames, plants[:, k], gpos[:, ankle], ramp, holds=holds[side])
        if not mask.any():
            continue
        lh, lk, la, miss = ik(gpos[mask], grot[mask], motion.skeleton.parents, legs[side],
                              gpos[mask, ankle] + off[mask], lateral[mask])
        rot[mask, hip], rot[mask, knee], rot[mask, ankle] = lh, lk, la
        worst = max(worst, float(miss.max(initial=0.0)))
    return replace(motion, rotations=rot), worst
