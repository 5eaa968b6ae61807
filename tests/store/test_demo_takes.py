"""Long demo takes (store/demo/takes.py): durations, continuity across joins, mixed actions,
category = dominant action, deterministic bytes, the plan, BVH round trip."""

from __future__ import annotations

import json
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from motionweb.store.bvh import read_bvh
from motionweb.store.demo.corpus import CATEGORIES
from motionweb.store.demo.takes import (
    MAX_TAKE_S,
    MIN_TAKE_S,
    dominant_action,
    long_take,
    take_plan,
    write_take_corpus,
)
from motionweb.store.kinematics import forward_kinematics

TOTAL = 5000  # frames at 60 Hz: a plan of a few takes


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[Path]]:
    out = tmp_path_factory.mktemp("takes") / "a"
    return out, write_take_corpus(out, TOTAL, seed=3)


def _join_mask(truth: dict, n_steps: int) -> np.ndarray:
    """Per-frame steps (frame i -> i + 1) that enter, cross or leave a blend."""
    mask = np.zeros(n_steps, bool)
    for b in truth["blends"]:
        mask[max(b["start_frame"] - 1, 0):b["end_frame"] + 1] = True
    return mask


@pytest.mark.parametrize("index", [0, 1, 2, 5])
def test_take_is_continuous_and_mixed(index: int) -> None:
    motion, truth = long_take(11, index)
    assert MIN_TAKE_S <= motion.duration <= MAX_TAKE_S
    assert motion.n_frames == truth["frames"]
    actions = [s["action"] for s in truth["segments"]]
    assert len(set(actions)) >= 2
    assert all(a != b for a, b in pairwise(actions))  # no action twice in a row
    # segments and blends tile the take without gaps or overlaps
    spans = sorted([(s["start_frame"], s["end_frame"]) for s in truth["segments"]]
                   + [(b["start_frame"], b["end_frame"]) for b in truth["blends"]])
    assert spans[0][0] == 0 and spans[-1][1] == motion.n_frames - 1
    assert all(b[0] == a[1] + 1 for a, b in pairwise(spans))
    gp, _ = forward_kinematics(motion)
    joint_step = np.linalg.norm(np.diff(gp, axis=0), axis=-1).max(axis=1)
    root_step = np.linalg.norm(np.diff(motion.root_positions, axis=0), axis=-1)
    mask = _join_mask(truth, len(root_step))
    assert mask.any() and (~mask).any()
    # across joins no larger jump than within the segments (runs, kicks): positions are continuous
    assert joint_step[mask].max() <= joint_step[~mask].max()
    assert root_step[mask].max() <= max(root_step[~mask].max(), 0.02)
    assert joint_step[mask].max() < 0.1  # metres per frame at 60 Hz
    assert truth["category"] == dominant_action(truth["segments"])


def test_dominant_action_counts_frames() -> None:
    segs = [{"action": "walk", "start_frame": 0, "end_frame": 99}, {"action": "run", "start_frame": 124, "end_frame": 173},
            {"action": "run", "start_frame": 198, "end_frame": 257}]
    assert dominant_action(segs) == "run"  # 110 frames of runs against 100 of walk
    tie = [{"action": "run", "start_frame": 0, "end_frame": 9}, {"action": "walk", "start_frame": 10, "end_frame": 19}]
    assert dominant_action(tie) == "walk"  # ties: the first in CATEGORIES
    assert CATEGORIES.index("walk") < CATEGORIES.index("run")


def test_take_plan_sums_and_is_deterministic() -> None:
    plan = take_plan(100_000, seed=5)
    assert plan == take_plan(100_000, seed=5)
    assert plan != take_plan(100_000, seed=6)
    total = sum(t.frames for t in plan)
    assert total >= 100_000 and total - plan[-1].frames < 100_000
    assert all(MIN_TAKE_S <= t.duration_s <= MAX_TAKE_S for t in plan)
    assert all(t.frames == round(t.duration_s * 60) + 1 for t in plan)
    assert take_plan(40_000, seed=5) == plan[:len(take_plan(40_000, seed=5))]  # a prefix
    assert take_plan(0) == []


def test_written_takes(written: tuple[Path, list[Path]], tmp_path: Path) -> None:
    out, paths = written
    plan = take_plan(TOTAL, seed=3)
    assert len(paths) == len(plan) >= 2
    assert sum(read_bvh(p).n_frames for p in paths) >= TOTAL
    for p, spec in zip(paths, plan, strict=True):
        truth = json.loads(p.with_suffix(".json").read_text())
        assert p.parent.name == truth["category"] == dominant_action(truth["segments"])
        assert p.name == f"take_{spec.index:05d}.bvh"
        m = read_bvh(p)  # round trip through the BVH reader
        assert m.n_frames == truth["frames"] == spec.frames and m.fps == pytest.approx(60.0)
        motion, _ = long_take(3, spec.index, 60.0, spec.duration_s)
        np.testing.assert_allclose(m.root_positions, motion.root_positions, atol=2e-6)
        gm, _ = forward_kinematics(m)
        gt, _ = forward_kinematics(motion)
        np.testing.assert_allclose(gm, gt, atol=1e-4)
    # same inputs, same bytes
    again = write_take_corpus(tmp_path / "b", TOTAL, seed=3)
    assert [p.relative_to(tmp_path / "b") for p in again] == [p.relative_to(out) for p in paths]
    for a, b in zip(paths, again, strict=True):
        assert a.read_bytes() == b.read_bytes()
        assert a.with_suffix(".json").read_bytes() == b.with_suffix(".json").read_bytes()


def test_take_duration_checked() -> None:
    with pytest.raises(ValueError, match="10-60 s"):
        long_take(1, 0, duration_s=5.0)
