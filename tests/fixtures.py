"""Small motions and skeletons shared by the tests (imported by module name: ``from fixtures import ...``)."""

from __future__ import annotations

import numpy as np
from motionweb.store.motion import Motion, Skeleton


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
