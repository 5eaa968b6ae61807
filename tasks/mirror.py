"""Left/right mirroring of a motion (issue 26; design "Exports").

The mirror plane is the character's sagittal plane in the rest pose, through the world origin:
its normal is the coordinate axis along which paired joints (left hip vs right hip, ...) lie
furthest apart in the rest pose (``MirrorParams.axis`` overrides it), so for the usual skeletons
(CMU ASF, cgspeed BVH and DeepMimic are all X-lateral at rest) it is the plane x = 0. Let M be
that reflection (the lateral coordinate negated) and π the pairing of joints (π(j) = j for an
unpaired joint). The mirrored motion is

* rotations   q'_j = (w, −M v) of q_π(j) = (w, v) — the reflection conjugate M R M of the
  paired joint's rotation: the lateral component of the vector part is kept, the others negate;
* offsets     o'_j = M o_π(j), end sites and per-frame joint translations likewise;
* root        p'_0 = M p_0 (the lateral component of the root's translation negated);

so that, by induction along the hierarchy, every world position is p'_j = M p_π(j) (the world
rotations are M R_π(j) M too). This needs a symmetric topology, parent(π(j)) = π(parent(j)),
checked with an error naming the joints. Joint frames are aligned with the world axes at rest in
every skeleton motionweb reads, so no rest rotation enters.

Asymmetric skeletons: where a captured skeleton's left and right bones differ a little (CMU's do,
by up to ~1 cm), the mirrored skeleton is the mirror image of the performer's: its left leg has
the original right leg's offsets (o'_j = M o_π(j)), so world positions are mirrored exactly and
mirroring twice gives the original skeleton and motion back. :attr:`MirrorResult.asymmetry`
reports the largest |M o_π(j) − o_j| (metres).

Pairs are found from joint names (:func:`mirror_pairs`): ``Left``/``Right`` anywhere in the
name (LeftUpLeg/RightUpLeg, left_hip/right_hip), or a leading or trailing ``l``/``r`` (CMU's
lfemur/rfemur, LHipJoint/RHipJoint, Hand_L/Hand_R), taken only where the partner exists and the
pairing is mutual; ``MirrorParams.pairs`` adds or overrides pairs. O(F·J).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace

import numpy as np
from motionweb.store.kinematics import forward_kinematics, quat_identity
from motionweb.store.motion import Motion, Skeleton
from motionweb.tasks.params.mirror import MirrorParams


@dataclass(frozen=True)
class MirrorResult:
    """A mirrored motion, its joint pairs (left/right names), the plane's normal axis (0, 1, 2)
    and the skeleton's asymmetry: the largest |M o_π(j) − o_j| in metres (file units when the
    unit is unknown)."""

    motion: Motion
    pairs: tuple[tuple[str, str], ...]
    axis: int
    asymmetry: float


_SIDE = re.compile(r"left|right", re.IGNORECASE)
_SWAP = {"l": "r", "r": "l", "L": "R", "R": "L"}


def _swap_word(m: re.Match) -> str:
    w = m.group(0)
    other = "right" if w.lower() == "left" else "left"
    if w.isupper():
        return other.upper()
    return other.capitalize() if w[0].isupper() else other


def _candidates(name: str) -> list[str]:
    out = []
    if _SIDE.search(name):
        out.append(_SIDE.sub(_swap_word, name))
    if len(name) > 1 and name[0] in _SWAP:
        out.append(_SWAP[name[0]] + name[1:])
    if len(name) > 1 and name[-1] in _SWAP:
        out.append(name[:-1] + _SWAP[name[-1]])
    return out


def mirror_pairs(skeleton: Skeleton, overrides: dict[str, str] | None = None) -> np.ndarray:
    """The pairing π (J,) int: π[j] is joint j's left/right partner, j itself when unpaired.

    By name (see the module's docstring), then ``overrides`` ({name: partner}, both ways).
    ValueError naming the joint for an override of an unknown joint, or a pairing that is not
    mutual."""
    names = skeleton.names
    index = {n: j for j, n in enumerate(names)}
    perm = np.arange(len(names))
    for j, n in enumerate(names):
        for c in _candidates(n):
            k = index.get(c)
            if k is not None and k != j:
                perm[j] = k
                break
    for a, b in (overrides or {}).items():
        for n in (a, b):
            if n not in index:
                raise ValueError(f"mirror.pairs: unknown joint {n!r}; joints: {', '.join(names)}")
        ia, ib = index[a], index[b]
        for k in (ia, ib):  # the old partners become unpaired
            if perm[perm[k]] == k:
                perm[perm[k]] = perm[k]
        perm[ia], perm[ib] = ib, ia
    bad = [names[j] for j in range(len(names)) if perm[perm[j]] != j]
    if bad:
        raise ValueError(f"left/right pairs are not mutual for {', '.join(bad)}: set mirror.pairs")
    return perm


def _rest_positions(motion: Motion) -> np.ndarray:
    rest = replace(motion, root_positions=motion.skeleton.offsets[:1], rotations=quat_identity((1, motion.skeleton.n_joints)),
                   translations={})
    return forward_kinematics(rest)[0][0]


def lateral_axis(motion: Motion, perm: np.ndarray) -> int:
    """The axis (0, 1, 2) along which paired joints lie furthest apart in the rest pose.
    ValueError when the skeleton has no pairs."""
    paired = np.flatnonzero(perm != np.arange(len(perm)))
    if not len(paired):
        raise ValueError(f"{motion.name or 'motion'}: no left/right joint pairs found by name "
                         f"({', '.join(motion.skeleton.names)}); set mirror.pairs")
    rest = _rest_positions(motion)
    spread = np.abs(rest[paired] - rest[perm[paired]]).sum(axis=0)
    return int(np.argmax(spread))


def mirror_quat(q: np.ndarray, axis: int) -> np.ndarray:
    """(..., 4) rotations reflected across the plane normal to ``axis``: M R M for the
    reflection M, i.e. (w, x, y, z) with the two non-``axis`` vector components negated."""
    out = -np.asarray(q, np.float64)
    out[..., 0] = q[..., 0]
    out[..., 1 + axis] = q[..., 1 + axis]
    return out


def mirror(motion: Motion, params: MirrorParams | None = None) -> MirrorResult:
    """The motion mirrored left/right (see the module's docstring). ValueError naming the joints
    when the topology is not symmetric under the pairing."""
    params = params or MirrorParams()
    sk = motion.skeleton
    perm = mirror_pairs(sk, params.pairs)
    axis = lateral_axis(motion, perm) if params.axis == "auto" else "xyz".index(params.axis)
    parents = sk.parents
    bad = [sk.names[j] for j in range(sk.n_joints)
           if (parents[perm[j]] if parents[perm[j]] < 0 else perm[parents[perm[j]]]) != parents[j]]
    if bad:
        raise ValueError(f"{motion.name or 'motion'}: the joint pairs do not mirror the hierarchy at "
                         f"{', '.join(bad)} (a joint's partner must hang from its parent's partner); set mirror.pairs")
    flip = np.ones(3)
    flip[axis] = -1.0
    offsets = sk.offsets[perm] * flip
    ends = {j: sk.end_sites[int(perm[j])] * flip for j in range(sk.n_joints) if int(perm[j]) in sk.end_sites}
    channels = tuple(sk.channels[int(perm[j])] for j in range(sk.n_joints))
    skel = replace(sk, offsets=offsets, end_sites=ends, channels=channels)
    trans = {j: motion.translations[int(perm[j])] * flip for j in range(sk.n_joints) if int(perm[j]) in motion.translations}
    out = replace(motion, skeleton=skel, root_positions=motion.root_positions * flip,
                  rotations=mirror_quat(motion.rotations[:, perm], axis), translations=trans,
                  name=f"{motion.name}_mirrored" if motion.name else "mirrored", source=None, content_hash="")
    pairs = tuple((sk.names[j], sk.names[int(perm[j])]) for j in range(sk.n_joints) if perm[j] > j)
    asym = float(np.abs(offsets - sk.offsets).max()) * (motion.scale_to_m or 1.0)
    return MirrorResult(out, pairs, axis, asym)
