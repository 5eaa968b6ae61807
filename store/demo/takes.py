"""Long demo takes: one continuous capture session of 10-60 s holding several actions, as real
capture sessions are (issue 25, part 3: "A million frames").

The demo corpus (`corpus.py`) writes one short clip per action (2-5 s); a real library is mostly
long takes in which a performer walks, stops, jumps, sits... one after another. A take here strings
demo clips of several categories (`clips.py`'s generators, each seeded on its own) into one
:class:`~motionweb.store.motion.Motion`: each next segment is turned about the vertical and moved
on the ground so that its first frame starts where and facing as the previous segment's last frame
ended, and a short blend (the previous last pose eased into the next first pose: root positions
interpolated, joint rotations slerped, cubic ease) joins them, so joint positions are continuous
across joins. A take is labelled by its dominant action (the action with the most frames, ties to
the first in :data:`~motionweb.store.demo.corpus.CATEGORIES`): that is its category, the folder it
is written in, the chunk it is indexed in (KG04 §3: webs are built between clips of one chunk;
design §1 "category chunks").

:func:`long_take` makes one take, :func:`take_plan` decides the takes of a corpus of a given size,
:func:`write_take_corpus` writes them (BVH + JSON truth of the segments). Same inputs, same bytes.
Cost: O(frames · joints) to build and write, linear in the corpus's frames.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from motionweb.store.demo.corpus import CATEGORIES, clip_from_rng, seeded_rng, write_clip
from motionweb.store.demo.rig import UNIT_Y, qaxis, smooth
from motionweb.store.kinematics import heading_angle, quat_mul, quat_rotate, quat_slerp
from motionweb.store.motion import Motion

#: shortest and longest take, seconds.
MIN_TAKE_S, MAX_TAKE_S = 10.0, 60.0
#: seconds of each blend between two segments.
BLEND_S = 0.4
#: styles per category a segment draws from (the generators' ``variant``; a generator grows its
#: speeds with ``variant // 3``, so the style stays in the range the demo uses).
_STYLES = 6


@dataclass(frozen=True)
class TakeSpec:
    """One take of a plan: its index (file ``take_<index:05d>``), duration in seconds and frames."""

    index: int
    duration_s: float
    frames: int


def _frames(duration_s: float, fps: float) -> int:
    return round(duration_s * fps) + 1


def _place_after(prev: Motion, nxt: Motion) -> Motion:
    """``nxt`` turned about the vertical (Y) and moved on the ground so that its first frame has the
    heading and the ground position (x, z) of ``prev``'s last frame; heights are kept."""
    h_prev = float(heading_angle(prev.rotations[-1, 0]))
    h_next = float(heading_angle(nxt.rotations[0, 0]))
    q = qaxis(UNIT_Y, np.array(h_prev - h_next))
    ground = np.array([1.0, 0.0, 1.0])
    root = quat_rotate(q, nxt.root_positions - nxt.root_positions[0] * ground) + prev.root_positions[-1] * ground
    rots = nxt.rotations.copy()
    rots[:, 0] = quat_mul(q, rots[:, 0])
    return replace(nxt, root_positions=root, rotations=rots)


def _blend(a: Motion, b: Motion, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` frames easing ``a``'s last pose into ``b``'s first (both excluded): root positions
    (n, 3) linear, rotations (n, J, 4) slerped, weights smooth(k / (n + 1))."""
    w = smooth(np.arange(1, n + 1) / (n + 1))
    root = a.root_positions[-1] * (1.0 - w[:, None]) + b.root_positions[0] * w[:, None]
    rots = quat_slerp(a.rotations[-1][None], b.rotations[0][None], np.broadcast_to(w[:, None], (n, a.rotations.shape[1])))
    return root, rots


def dominant_action(segments: list[dict[str, Any]]) -> str:
    """The action with the most frames over ``segments`` (ties: the first in CATEGORIES order)."""
    count: dict[str, int] = {}
    for s in segments:
        count[s["action"]] = count.get(s["action"], 0) + s["end_frame"] - s["start_frame"] + 1
    return max(count, key=lambda a: (count[a], -CATEGORIES.index(a)))


def long_take(seed: int, index: int, fps: float = 60.0, duration_s: float | None = None
              ) -> tuple[Motion, dict[str, Any]]:
    """One continuous take of ``duration_s`` seconds (None: drawn in [10, 60] s) made of demo
    actions in a seeded random order (no action twice in a row, at least two actions), and its
    truth: ``segments`` (action, start/end frame, inclusive), ``blends`` (start/end frame),
    ``category`` (the dominant action), frames, fps.

    Motion: root positions (F, 3) in metres, rotations (F, J, 4), F = round(duration_s · fps) + 1;
    the last segment is cut to fit. Deterministic in (seed, index, fps, duration_s).
    Cost O(F · J): the segments' generators and one pass of concatenation."""
    rng = seeded_rng("take", index, seed)
    if duration_s is None:
        duration_s = float(rng.uniform(MIN_TAKE_S, MAX_TAKE_S))
    if not MIN_TAKE_S <= duration_s <= MAX_TAKE_S:
        raise ValueError(f"a take lasts {MIN_TAKE_S:g}-{MAX_TAKE_S:g} s, not {duration_s:g}")
    n_total = _frames(duration_s, fps)
    n_blend = max(1, round(BLEND_S * fps))
    roots: list[np.ndarray] = []
    rots: list[np.ndarray] = []
    segments: list[dict[str, Any]] = []
    blends: list[dict[str, Any]] = []
    prev: Motion | None = None
    n = 0
    k = 0
    while n < n_total or len({s["action"] for s in segments}) < 2:
        choices = [c for c in CATEGORIES if not segments or c != segments[-1]["action"]]
        action = choices[int(rng.integers(len(choices)))]
        style = int(rng.integers(_STYLES))
        clip, _ = clip_from_rng(action, style, seeded_rng(f"take/{action}", index * 1024 + k, seed), seed, fps)
        k += 1
        if prev is not None:
            clip = _place_after(prev, clip)
            b_root, b_rots = _blend(prev, clip, n_blend)
            roots.append(b_root)
            rots.append(b_rots)
            blends.append({"start_frame": n, "end_frame": n + n_blend - 1})
            n += n_blend
        roots.append(clip.root_positions)
        rots.append(clip.rotations)
        segments.append({"action": action, "style": style, "start_frame": n, "end_frame": n + clip.n_frames - 1})
        n += clip.n_frames
        prev = clip
    root = np.concatenate(roots)[:n_total]
    rot = np.concatenate(rots)[:n_total]
    # cut to the take's frames: segments and blends past the end go, the last is shortened
    segments = [{**s, "end_frame": min(s["end_frame"], n_total - 1)} for s in segments if s["start_frame"] < n_total]
    blends = [{**b, "end_frame": min(b["end_frame"], n_total - 1)} for b in blends if b["start_frame"] < n_total]
    name = f"take_{index:05d}"
    motion = replace(prev, root_positions=root, rotations=rot, name=name, source=None, content_hash="")
    category = dominant_action(segments)
    truth = {"category": category, "take": index, "seed": seed, "fps": fps, "unit": "m", "up": "y",
             "frames": n_total, "duration": motion.duration, "blend_frames": n_blend,
             "segments": segments, "blends": blends}
    return motion, truth


def take_plan(total_frames: int, seed: int = 7, fps: float = 60.0) -> list[TakeSpec]:
    """Takes of durations drawn uniformly in [10, 60] s from a generator seeded by ``seed`` until
    their frames sum to at least ``total_frames``. A plan for fewer frames is a prefix of the plan
    for more. O(takes)."""
    if total_frames < 0:
        raise ValueError(f"total_frames must be ≥ 0, got {total_frames}")
    rng = seeded_rng("take-plan", 0, seed)
    plan: list[TakeSpec] = []
    n = 0
    while n < total_frames:
        d = round(float(rng.uniform(MIN_TAKE_S, MAX_TAKE_S)), 3)
        plan.append(TakeSpec(len(plan), d, _frames(d, fps)))
        n += plan[-1].frames
    return plan


def write_take_corpus(out_dir: str | Path, total_frames: int, seed: int = 7, fps: float = 60.0) -> list[Path]:
    """Write the takes of :func:`take_plan` as ``<out_dir>/<category>/take_<i:05d>.bvh`` with their
    truth ``.json`` beside (segments: action, start/end frame); returns the BVH paths in take
    order. Same inputs give the same bytes. Cost O(total_frames · J) time, one take in memory."""
    out = Path(out_dir)
    paths = []
    for spec in take_plan(total_frames, seed, fps):
        motion, truth = long_take(seed, spec.index, fps, spec.duration_s)
        paths.append(write_clip(motion, truth, out / truth["category"] / motion.name))
    return paths


__all__ = ["BLEND_S", "MAX_TAKE_S", "MIN_TAKE_S", "TakeSpec", "dominant_action", "long_take", "take_plan",
           "write_take_corpus"]
