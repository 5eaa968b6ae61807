"""Point-cloud frame features for the frame distance (design §3, KG04 §3.1).

KG04 §3.1 uses "the metric of Kovar et al. 2002": each frame becomes the cloud of global joint
positions over a short window of frames centred on it, each point with a weight, and two frames
are compared after the best rigid 2-D alignment (rotation about the vertical axis plus horizontal
translation). This module builds the clouds; ``tasks.distance`` compares them.

Layout: ``clip_features`` returns ``(F, P, 3)`` with ``P = window * J`` points per frame, ordered
window offset major, joint minor (point ``w * J + j`` is joint ``j`` at frame ``f + w - window//2``).
Coordinates are in metres and in the canonical y-up layout: column 1 is always the vertical axis
(for ``up="z"`` the axes are turned by a proper rotation so that z lands in column 1), so the
distance code never needs to know the file's up axis. Cost: O(F·J) forward kinematics plus
O(F·P) copies.
"""

from __future__ import annotations

import numpy as np
from motionweb.store.kinematics import axis_index, forward_kinematics, resample
from motionweb.store.motion import Motion, Skeleton
from motionweb.tasks.params.features import FeatureParams

#: proper rotations taking each up axis to column 1 (y): rows are the new x, y, z axes.
_TO_Y_UP: dict[int, np.ndarray] = {
    0: np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),  # x up
    1: np.eye(3),
    2: np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),  # z up
}


def window_offsets(window: int) -> np.ndarray:
    """Frame offsets of a centred window of ``window`` frames (odd sizes are symmetric)."""
    if window < 1:
        raise ValueError(f"feature window must be at least 1 frame, got {window}")
    return np.arange(window) - window // 2


def joint_positions_m(motion: Motion, up: str = "y") -> np.ndarray:
    """Global joint positions (F, J, 3) in metres, vertical axis in column 1."""
    gpos, _ = forward_kinematics(motion)
    rot = _TO_Y_UP[axis_index(up)]
    return (gpos @ rot.T) * motion.metres()


def clip_features(motion: Motion, rate: float, cfg: FeatureParams, up: str = "y") -> np.ndarray:
    """(F_rate, P, 3) windowed point clouds of ``motion`` resampled to ``rate`` Hz (KG04 §3.1).

    The clip is resampled first (slerp), then each frame's cloud holds the joints of the
    ``cfg.window`` frames centred on it, with edge frames clamped (the first frame repeats).
    Returned in ``cfg.dtype``, metres, vertical axis in column 1.
    """
    m = motion if abs(motion.fps - rate) < 1e-9 else resample(motion, rate)
    pos = joint_positions_m(m, up)  # (F, J, 3)
    f = pos.shape[0]
    idx = np.clip(np.arange(f)[:, None] + window_offsets(cfg.window)[None, :], 0, f - 1)  # (F, W)
    clouds = pos[idx].reshape(f, -1, 3)  # (F, W*J, 3), window major
    return np.ascontiguousarray(clouds, dtype=np.dtype(cfg.dtype))


def point_weights(skeleton: Skeleton, cfg: FeatureParams) -> np.ndarray:
    """(P,) point weights summing to 1, matching ``clip_features``' point order.

    Joint weights come from ``cfg.joint_weights`` by joint name (1 for joints not named; unknown
    names are an error so a typo cannot silently change the metric); every window frame gets
    the same weights (uniform over time, as in KG04's default).
    """
    w = np.ones(skeleton.n_joints)
    for name, value in cfg.joint_weights.items():
        if value < 0:
            raise ValueError(f"joint weight for {name!r} must be >= 0, got {value}")
        w[skeleton.index(name)] = value
    total = w.sum() * cfg.window
    if not total > 0:
        raise ValueError("joint weights are all zero")
    return np.tile(w, cfg.window) / total


def feature_set(motion: Motion, cfg: FeatureParams, up: str = "y") -> tuple[dict[float, np.ndarray], np.ndarray]:
    """A clip's features at every rate of ``cfg`` ({rate: (F_r, P, 3)}) and its point weights
    (P,): what the index stores per clip (``flows/workers.compute_features_batch``) and what a
    query clip from outside the index is compared with (``tasks/query_clip.py``). O(F·P) per rate."""
    return ({float(r): clip_features(motion, float(r), cfg, up=up) for r in cfg.rates},
            point_weights(motion.skeleton, cfg))
