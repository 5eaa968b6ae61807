"""Capture glitches in the path the physics sees: one-frame joint turns no body makes (design §8).

Mocap has frames where a joint's solve fails: a marker swap turns a hand 90° for a frame or two
and back (a spike), or a clip starts with an arm frozen in a default pose until the solve locks
on (a step at the clip's start). Differentiated twice, one such frame turns into hundreds of N·m
over the whole derivative window, so every frame near it leaves its feasible polygon at any
timing. :func:`repair_glitches` mends the path the dynamics are computed from — a spike is
bridged by slerp between the good frames on either side, a step within ``edge_s`` of a clip end
is held from the good side — and says what it changed; the retimed output is still sampled from
the clip as captured. A fast turn that is neither stays (the report names it as a likely glitch).

Cost: O(F · J).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from motionweb.store.kinematics import quat_slerp
from motionweb.store.motion import Motion

#: a joint turning faster than this in one frame is a capture glitch, not motion (subject 16's toes
#: and hands peak at ~2,900 °/s; the glitches turn 5,000-21,000 °/s, e.g. 16_28's rhumerus 84°
#: from frame 5 to 6 after five frozen frames, 16_07's lthumb 150° and back over frames 257-259)
GLITCH_DEG_PER_S = 5000.0


@dataclass(frozen=True)
class Glitch:
    """A mended glitch: ``joint`` over frames [start, stop), ``kind`` 'spike' or 'step', and the
    turn (degrees) of its fastest frame."""

    joint: str
    start: int
    stop: int
    kind: str
    degrees: float

    def describe(self) -> str:
        how = "bridged by slerp" if self.kind == "spike" else "held at the nearest good frame"
        at = f"frame {self.start}" if self.stop - self.start == 1 else f"frames {self.start}-{self.stop - 1}"
        return f"{self.joint} {at}: a {self.degrees:.0f}° one-frame {self.kind}, {how}"


def step_degrees(rotations: np.ndarray) -> np.ndarray:
    """(F − 1, ...) angle (degrees) each joint turns from one frame to the next; ``rotations`` (F, ..., 4)."""
    q0, q1 = rotations[:-1], rotations[1:]
    dot = np.abs(np.sum(q0 * q1, axis=-1)) / (np.linalg.norm(q0, axis=-1) * np.linalg.norm(q1, axis=-1))
    return 2.0 * np.degrees(np.arccos(np.clip(dot, 0.0, 1.0)))


def repair_glitches(motion: Motion, edge_s: float = 0.1) -> tuple[Motion, list[Glitch]]:
    """The motion with its capture glitches mended, and the list of what was mended.

    Per joint, a one-frame turn faster than :data:`GLITCH_DEG_PER_S` at step k (frame k → k + 1)
    followed within ``edge_s`` by another at step k2 that comes back (frames k and k2 + 1 closer
    than half the smaller jump) is a spike: frames k + 1 … k2 become the slerp between frames k
    and k2 + 1. A fast step left within ``edge_s`` of the clip's start holds the frames before it
    at the pose after it (the last such step); near the end, the frames after it at the pose
    before it (the first such step). O(F · J).
    """
    rot = motion.rotations.copy()
    span = max(int(round(edge_s * motion.fps)), 1)
    f = motion.n_frames
    steps = step_degrees(rot)  # (F - 1, J)
    fast = steps * motion.fps > GLITCH_DEG_PER_S
    found: list[Glitch] = []
    for j in np.flatnonzero(fast.any(axis=0)).tolist():
        name = motion.skeleton.names[j]
        ks = np.flatnonzero(fast[:, j]).tolist()
        left: list[int] = []
        while ks:
            k = ks.pop(0)
            back = next((k2 for k2 in ks if k2 - k <= span
                         and step_degrees(rot[[k, k2 + 1], j])[0] < 0.5 * min(steps[k, j], steps[k2, j])), None)
            if back is None:
                left.append(k)
                continue
            ks = [k2 for k2 in ks if k2 > back]
            t = (np.arange(k + 1, back + 1) - k) / (back + 1 - k)
            rot[k + 1:back + 1, j] = quat_slerp(rot[k, j][None], rot[back + 1, j][None], t)
            found.append(Glitch(name, k + 1, back + 1, "spike", float(steps[k:back + 1, j].max())))
        head = [k for k in left if k + 1 <= span]
        if head:
            k = head[-1]
            rot[:k + 1, j] = rot[k + 1, j]
            found.append(Glitch(name, 0, k + 1, "step", float(steps[:k + 1, j].max())))
        tail = [k for k in left if k >= f - 1 - span]
        if tail:
            k = tail[0]
            rot[k + 1:, j] = rot[k, j]
            found.append(Glitch(name, k + 1, f, "step", float(steps[k:, j].max())))
    return (replace(motion, rotations=rot) if found else motion), found
