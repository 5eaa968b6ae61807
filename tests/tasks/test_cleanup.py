"""Foot-slide cleanup (tasks/cleanup.py, issue 26): planted feet held by blending's leg IK, foot
skate after ≤ 1 cm/s on planted frames, every joint outside the legs unchanged to 1e-9."""

from __future__ import annotations

import csv
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from motionweb.store.demo.corpus import generate_clip
from motionweb.store.formats import read_motion
from motionweb.store.kinematics import forward_kinematics
from motionweb.store.motion import Motion
from motionweb.tasks.blend import BlendParams, ease_offsets
from motionweb.tasks.cleanup import cleanup, close_gaps, reachable_hold, widen

TARGET_CM_S = 1.0
CGSPEED_SCALE = 0.0254 / 0.45


def upper_body(m: Motion, legs: dict) -> list[int]:
    """Joints outside both legs' subtrees (the hips and everything below them)."""
    below = set()
    for hip, _, _ in legs.values():
        below.add(hip)
    for j in range(m.skeleton.n_joints):
        if int(m.skeleton.parents[j]) in below:
            below.add(j)
    return [j for j in range(m.skeleton.n_joints) if j not in below]


def check(m: Motion) -> tuple[float, float]:
    res = cleanup(m)
    assert res.plants[:, 0].any() and res.plants[:, 1].any(), m.name
    assert res.skate_after <= TARGET_CM_S, (m.name, res.skate_before, res.skate_after)
    assert res.skate_after < res.skate_before
    up = upper_body(m, res.legs)
    assert len(up) >= 3
    np.testing.assert_allclose(forward_kinematics(res.motion)[0][:, up], forward_kinematics(m)[0][:, up], atol=1e-9, rtol=0)
    np.testing.assert_array_equal(res.motion.rotations[:, up], m.rotations[:, up])
    return res.skate_before, res.skate_after


def test_sliding_demo_walk_is_cleaned() -> None:
    walk, _ = generate_clip("walk", 0, 7, 60.0)
    t = np.arange(walk.n_frames) / walk.fps
    root = walk.root_positions.copy()
    root[:, 0] += 0.03 * np.sin(2 * np.pi * 1.3 * t)  # the whole body sways: planted feet slide
    sliding = replace(walk, root_positions=root)
    before, _ = check(sliding)
    assert before > 5.0


def test_helpers() -> None:
    p = np.zeros((12, 2), bool)
    p[2:4, 0] = p[6:9, 0] = True
    assert np.flatnonzero(close_gaps(p, 3)[:, 0]).tolist() == list(range(2, 9))
    assert np.flatnonzero(close_gaps(p, 2)[:, 0]).tolist() == [2, 3, 6, 7, 8]
    assert np.flatnonzero(widen(p)[:, 0]).tolist() == [1, 2, 3, 4, 5, 6, 7, 8, 9]
    hips = np.array([[0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
    c = reachable_hold(np.array([[-0.5, 0.0, 0.0], [-0.5, 0.0, 0.0]]), hips, 1.0)
    assert np.all(np.linalg.norm(c - hips, axis=1) <= 1.0 + 1e-9)
    # ease_offsets holds a run at the given point instead of its mean
    ank = np.arange(30.0).reshape(10, 3)
    plants = np.zeros(10, bool)
    plants[3:6] = True
    holds = np.full((10, 3), 7.0)
    off, _ = ease_offsets(10, plants, ank, 2, holds)
    np.testing.assert_allclose(ank[3:6] + off[3:6], 7.0)
    off0, _ = ease_offsets(10, plants, ank, 2)
    np.testing.assert_allclose(ank[3:6] + off0[3:6], np.broadcast_to(ank[3:6].mean(0), (3, 3)))


def test_errors() -> None:
    walk, _ = generate_clip("walk", 0, 7, 30.0)
    with pytest.raises(ValueError, match="Y-up"):
        cleanup(walk, up="z")
    with pytest.raises(ValueError, match="unknown left ankle joint 'nope'"):
        cleanup(walk, BlendParams(feet={"left": "nope"}))


@pytest.mark.slow
def test_every_shared_cmu_walk(cmu_dir: Path) -> None:
    with open(cmu_dir / "manifest.csv") as fh:
        rows = [r for r in csv.DictReader(fh) if r["category"] == "walk"]
    assert len(rows) >= 20
    for r in rows:
        check(read_motion(cmu_dir / r["path"], scale_to_m=CGSPEED_SCALE))
