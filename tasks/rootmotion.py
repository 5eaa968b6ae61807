"""Root motion: the hips' horizontal travel and heading moved onto a root joint of their own
(issue 26; design "Exports").

Game engines read "root motion" from a root bone above the hips: its translation on the ground
and its turn about the vertical drive the character, while the animation proper plays in place.
With the hips (joint 0) at P(t) (F, 3) and world rotation Q(t) (F, 4):

* the new root joint R (index 0, parent of the old hips, zero offset) is at P with its vertical
  component set to 0 (the ground projection), and turned by the heading H(t) = the twist of Q
  about the vertical axis (swing-twist, :func:`store.kinematics.heading`);
* the hips become joint 1 with per-frame local translation H⁻¹(P − R) (only their height, and the
  sway across and along the heading, remain) and local rotation H⁻¹Q;
* every other joint keeps its offsets and rotations (indices shift by one).

World positions are unchanged: R + H·H⁻¹(P − R) = P, H·H⁻¹Q = Q. :func:`apply_root_motion`
folds the root back into the hips. O(F·J).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from motionweb.store.kinematics import axis_index, heading, quat_inv, quat_mul, quat_normalize, quat_rotate
from motionweb.store.motion import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton
from motionweb.tasks.params.rootmotion import RootMotionParams

ROOT_MOTION_MODES = ("keep", "in-place")


def _unique(name: str, names: tuple[str, ...]) -> str:
    while name in names:
        name += "_motion"
    return name


def extract_root_motion(motion: Motion, up: str = "y", root_name: str = "root") -> Motion:
    """The motion with a root joint carrying the hips' ground travel and heading (see the module's
    docstring): J + 1 joints, the root first, the old hips at index 1 with position channels."""
    sk = motion.skeleton
    k = axis_index(up)
    p = motion.root_positions
    q = motion.rotations[:, 0]
    ground = p.copy()
    ground[:, k] = 0.0
    h = heading(q, up)
    hi = quat_inv(h)
    hips_t = quat_rotate(hi, p - ground)
    hips_q = quat_normalize(quat_mul(hi, q))
    hips_channels = sk.channels[0] if any(c in POSITION_CHANNELS for c in sk.channels[0]) \
        else POSITION_CHANNELS + ("Zrotation", "Xrotation", "Yrotation")
    skel = Skeleton(
        names=(_unique(root_name, sk.names),) + sk.names,
        parents=np.concatenate([[-1], np.where(sk.parents < 0, 0, sk.parents + 1)]),
        offsets=np.concatenate([np.zeros((1, 3)), sk.offsets]),
        channels=(POSITION_CHANNELS + ("Zrotation", "Xrotation", "Yrotation"), hips_channels) + sk.channels[1:],
        end_sites={j + 1: v for j, v in sk.end_sites.items()},
    )
    rot = np.concatenate([h[:, None], hips_q[:, None], motion.rotations[:, 1:]], axis=1)
    trans = {1: hips_t} | {j + 1: t for j, t in motion.translations.items()}
    return replace(motion, skeleton=skel, root_positions=ground, rotations=rot, translations=trans)


def apply_root_motion(motion: Motion) -> Motion:
    """Fold the root joint (index 0) back into its only child, the hips (inverse of
    :func:`extract_root_motion`): the hips' world position and rotation become the root's."""
    sk = motion.skeleton
    kids = sk.children(0)
    if kids != [1] or 1 not in motion.translations:
        raise ValueError(f"{motion.name or 'motion'}: no root-motion joint above the hips (joint 0 needs the "
                         "hips, with per-frame translations, as its only child)")
    h = motion.rotations[:, 0]
    p = motion.root_positions + quat_rotate(h, motion.translations[1])
    q = quat_mul(h, motion.rotations[:, 1])
    channels = sk.channels[1]
    if not any(c in ROTATION_CHANNELS for c in channels):
        channels = POSITION_CHANNELS + ("Zrotation", "Xrotation", "Yrotation")
    skel = Skeleton(names=sk.names[1:], parents=np.where(sk.parents[1:] <= 0, -1, sk.parents[1:] - 1),
                    offsets=sk.offsets[1:], channels=(channels,) + sk.channels[2:],
                    end_sites={j - 1: v for j, v in sk.end_sites.items() if j > 0})
    trans = {j - 1: t for j, t in motion.translations.items() if j > 1}
    return replace(motion, skeleton=skel, root_positions=p, rotations=np.concatenate([q[:, None], motion.rotations[:, 2:]], 1),
                   translations=trans)


def root_motion(motion: Motion, params: RootMotionParams | None = None, up: str = "y") -> Motion:
    """The motion as an export writes it: unchanged for ``keep``, :func:`extract_root_motion`
    for ``in-place``."""
    params = params or RootMotionParams()
    return motion if params.mode == "keep" else extract_root_motion(motion, up, params.root_name)
