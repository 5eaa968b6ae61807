"""Capture glitches mended in the path the dynamics see: synthetic spikes and steps, real fast
motion left alone, and CMU 16_28 (its frozen start) inside its polygons at the original timing."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from fixtures import wiggle
from motionweb.store.formats import read_motion
from motionweb.store.kinematics import quat_from_axis_angle, quat_mul
from motionweb.tasks.retime import RetimeParams, prepare
from motionweb.tasks.retime.glitches import GLITCH_DEG_PER_S, repair_glitches, step_degrees
from motionweb.tasks.retime.report import original_feasibility


def turned(rot: np.ndarray, degrees: float) -> np.ndarray:
    """``rot`` (..., 4) turned ``degrees`` about x."""
    q = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(degrees))
    return quat_mul(np.broadcast_to(q, rot.shape), rot)


def angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return step_degrees(np.stack([a, b]))[0]


def test_a_spike_is_bridged_and_a_frozen_start_held() -> None:
    m = wiggle(240, 120.0, seed=3)  # smooth turns, at most a few hundred °/s
    assert (step_degrees(m.rotations) * m.fps).max() < GLITCH_DEG_PER_S
    rot = m.rotations.copy()
    rot[100:102, 7] = turned(rot[100:102, 7], 120.0)  # larm: a 2-frame marker swap
    rot[:6, 8] = turned(rot[6, 8], 80.0)  # rarm: frozen 80° off for 6 frames, then the solve locks on
    bad = replace(m, rotations=rot)
    fixed, found = repair_glitches(bad)
    kinds = {(g.joint, g.kind, g.start, g.stop) for g in found}
    assert kinds == {("larm", "spike", 100, 102), ("rarm", "step", 0, 6)}
    assert angle(fixed.rotations[100:102, 7], m.rotations[100:102, 7]).max() < 1.0  # slerp ≈ the smooth path
    np.testing.assert_allclose(fixed.rotations[:6, 8], np.broadcast_to(rot[6, 8], (6, 4)))
    untouched = np.ones(m.skeleton.n_joints, bool)
    untouched[[7, 8]] = False
    np.testing.assert_array_equal(fixed.rotations[:, untouched], bad.rotations[:, untouched])
    assert (step_degrees(fixed.rotations) * m.fps).max() < GLITCH_DEG_PER_S


def test_fast_motion_and_a_lasting_jump_mid_clip_stay() -> None:
    """A turn below the threshold is motion; a mid-clip jump that does not come back is not mended
    (the report names it instead)."""
    m = wiggle(240, 120.0, seed=4)
    rot = m.rotations.copy()
    rot[120:, 7] = turned(rot[120:, 7], 60.0)  # 7,200 °/s, and it stays
    rot[60:63, 8] = turned(rot[60:63, 8], 12.0)  # 1,440 °/s spike: fast, not a glitch
    out, found = repair_glitches(replace(m, rotations=rot))
    assert found == []
    assert out.rotations is rot or np.array_equal(out.rotations, rot)


def test_cmu_16_28_frozen_arm_start(cmu16: Path) -> None:
    """16_28 starts with its right arm frozen for 6 frames, then turns it 84° in one frame: mended,
    its original timing is inside its polygons (94.1 % without the repair, the frames by the glitch)."""
    motion = read_motion(cmu16 / "16_28.amc")
    plan = prepare(motion, RetimeParams())
    assert [(g.joint, g.kind, g.start, g.stop) for g in plan.glitches] == [("rhumerus", "step", 0, 6)]
    assert plan.motion is motion  # the output is sampled from the clip as captured
    assert original_feasibility(plan)["inside_fraction"] >= 0.99
    raw = prepare(motion, RetimeParams(repair_glitches=False))
    assert raw.glitches == [] and original_feasibility(raw)["inside_fraction"] < 0.95
