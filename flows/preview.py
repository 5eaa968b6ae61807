"""Stick-figure previews of a clip, rendered headless with matplotlib (Agg)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.animation import FuncAnimation, PillowWriter
from motionweb.store.kinematics import axis_index, end_site_positions, forward_kinematics
from motionweb.store.motion import Motion


def stick_segments(motion: Motion, up: str = "y") -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Points (F, J+E, 3) in metres with the vertical axis last, and bone index pairs."""
    pos, rot = forward_kinematics(motion)
    ends = end_site_positions(motion, pos, rot)
    pts = np.concatenate([pos, ends], axis=1) * (motion.scale_to_m or 1.0)
    k = axis_index(up)
    pts = pts[..., [i for i in range(3) if i != k] + [k]]
    parents = motion.skeleton.parents
    bones = [(int(parents[j]), j) for j in range(1, motion.skeleton.n_joints)]
    bones += [(j, motion.skeleton.n_joints + e) for e, j in enumerate(sorted(motion.skeleton.end_sites))]
    return pts, bones


def render_gif(motion: Motion, out: str | Path, *, max_frames: int, fps: float, up: str) -> int:
    """Write an animated GIF of the clip; frames are subsampled to at most ``max_frames``
    (the defaults: ``flows/requests.PreviewRequest``).

    Returns the number of frames written.
    """
    pts, bones = stick_segments(motion, up)
    step = max(1, int(np.ceil(motion.n_frames / max_frames)))
    frames = np.arange(0, motion.n_frames, step)
    lo, hi = pts.reshape(-1, 3).min(0), pts.reshape(-1, 3).max(0)
    centre, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-3)
    fig = plt.figure(figsize=(4, 4), dpi=72)
    ax = fig.add_subplot(projection="3d")
    lines = [ax.plot([], [], [], color="tab:blue", lw=2)[0] for _ in bones]
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(max(lo[2], centre[2] - half), max(lo[2], centre[2] - half) + 2 * half)
    ax.set_title(motion.name)

    def draw(f: int) -> list:
        for line, (a, b) in zip(lines, bones, strict=True):
            seg = pts[f, [a, b]]
            line.set_data(seg[:, 0], seg[:, 1])
            line.set_3d_properties(seg[:, 2])
        return lines

    anim = FuncAnimation(fig, draw, frames=frames, blit=False)
    anim.save(str(out), writer=PillowWriter(fps=fps))
    plt.close(fig)
    return len(frames)
