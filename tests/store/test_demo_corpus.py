"""The synthetic demo corpus: exact flights, planted feet, effector targets, determinism, warps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from motionweb.store.bvh import read_bvh
from motionweb.store.demo.corpus import (
    CATEGORIES,
    generate_clip,
    truth_json,
    walk_then_jump,
    write_demo_corpus,
)
from motionweb.store.demo.perturb import random_warp, time_warp_clip
from motionweb.store.demo.rig import G, humanoid_skeleton
from motionweb.store.kinematics import (
    end_site_positions,
    forward_kinematics,
    heading_angle,
    quat_from_axis_angle,
    quat_rotate,
)

FOOT_JOINTS = ("LeftFoot", "LeftToeBase", "RightFoot", "RightToeBase")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    return write_demo_corpus(tmp_path_factory.mktemp("demo") / "a")


def _lowest_foot_point(motion) -> float:
    gp, gr = forward_kinematics(motion)
    feet = [motion.skeleton.index(n) for n in FOOT_JOINTS]
    return float(min(gp[:, feet, 1].min(), end_site_positions(motion, gp, gr)[:, :, 1].min()))


def test_skeleton_is_a_metre_scale_humanoid() -> None:
    sk = humanoid_skeleton()
    assert 22 <= sk.n_joints <= 26
    assert sk.channels[0][:3] == ("Xposition", "Yposition", "Zposition")
    assert all(sk.rotation_order(j) == "ZXY" for j in range(sk.n_joints))
    assert len(sk.end_sites) == 5  # head, hands, toes
    # chain of offsets from the toe end site to the head end site, standing straight
    head = sk.index("Head")
    up = sk.offsets[[sk.index(n) for n in ("Spine", "Spine1", "Spine2", "Neck", "Head")], 1].sum()
    legs = -sk.offsets[[sk.index(n) for n in ("LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase")], 1].sum()
    assert legs + 0.02 + up + sk.end_sites[head][1] == pytest.approx(1.75, abs=0.01)


@pytest.mark.parametrize("clip", ["jump_0", "jump_1", "jump_2", "hop_1", "walk_then_jump"])
def test_flight_is_exactly_ballistic_and_airborne(clip: str) -> None:
    if clip == "walk_then_jump":
        motion, truth = walk_then_jump(seed=0)
    else:
        cat, v = clip.split("_")
        motion, truth = generate_clip(cat, int(v), seed=7)
    assert truth["flight"] and all(f["ballistic"] for f in truth["flight"])
    gp, _gr = forward_kinematics(motion)
    sk = motion.skeleton
    for fl in truth["flight"]:
        s, e = fl["start_frame"], fl["end_frame"]
        assert e - s >= 8
        root = motion.root_positions[s:e + 1]
        acc = np.diff(root, 2, axis=0) * motion.fps ** 2
        assert np.all(np.abs(acc[:, 1] + G) < 0.01 * G), acc[:, 1]
        assert np.abs(acc[:, [0, 2]]).max() < 1e-6  # constant horizontal velocity
        ankles = gp[s:e + 1, [sk.index("LeftFoot"), sk.index("RightFoot")], 1]
        toes = gp[s:e + 1, [sk.index("LeftToeBase"), sk.index("RightToeBase")], 1]
        planted_ankle = gp[0, sk.index("LeftFoot"), 1]
        assert ankles.min() > planted_ankle + 1e-3 and toes.min() > 0.0
    assert _lowest_foot_point(motion) >= -1e-3


def test_walk_then_jump_has_walk_and_long_flight() -> None:
    motion, truth = walk_then_jump(seed=0)
    walk = next(a for a in truth["actions"] if a["label"] == "walk")
    assert 2.0 <= walk["end_s"] - walk["start_s"] <= 3.0
    (fl,) = truth["flight"]
    assert fl["duration"] >= 0.5 and fl["end_frame"] - fl["start_frame"] >= 29
    assert truth["ik_max_miss_m"] < 1e-9
    m2, t2 = walk_then_jump(seed=0)
    assert np.array_equal(m2.rotations, motion.rotations) and truth_json(t2) == truth_json(truth)


@pytest.mark.parametrize("cat,variant", [("walk", v) for v in range(6)] + [("run", v) for v in range(3)])
def test_planted_feet_do_not_slide(cat: str, variant: int) -> None:
    motion, truth = generate_clip(cat, variant, seed=7)
    gp, _ = forward_kinematics(motion)
    sk = motion.skeleton
    worst = 0.0
    for side, prefix in (("left", "Left"), ("right", "Right")):
        toe, ankle = gp[:, sk.index(prefix + "ToeBase")], gp[:, sk.index(prefix + "Foot")]
        assert len(truth["contacts"][side]) >= 3
        for s, e in truth["contacts"][side]:  # the toe joint holds over the whole stance
            worst = max(worst, float(np.abs(toe[s:e + 1] - toe[s]).max()))
        for s, e in truth["heel_contacts"][side]:  # the ankle until the heel rises
            worst = max(worst, float(np.abs(ankle[s:e + 1] - ankle[s]).max()))
    assert worst < 0.01
    assert _lowest_foot_point(motion) >= -1e-3
    if cat == "run":
        assert truth["flight"] and all(0.03 < f["duration"] < 0.2 for f in truth["flight"])
    else:
        assert truth["flight"] == []


@pytest.mark.parametrize("variant", range(6))
def test_walk_speed_matches_ground_truth(variant: int) -> None:
    motion, truth = generate_clip("walk", variant, seed=3)
    step = np.linalg.norm(np.diff(motion.root_positions[:, [0, 2]], axis=0), axis=1)
    speed = step.sum() / motion.duration
    assert speed == pytest.approx(truth["params"]["speed"], rel=0.05)


@pytest.mark.parametrize("cat", ["kick", "punch", "reach"])
def test_effectors_reach_their_targets_at_the_apex(cat: str) -> None:
    for variant in range(3):
        motion, truth = generate_clip(cat, variant, seed=7)
        gp, _ = forward_kinematics(motion)
        h0 = heading_angle(motion.rotations[0, 0])
        origin = motion.root_positions[0] * np.array([1.0, 0.0, 1.0])
        q0 = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.asarray(h0))
        assert truth["targets"]
        apexes = {a["apex_frame"] for a in truth["actions"] if "apex_frame" in a}
        for tg in truth["targets"]:
            world = quat_rotate(q0, np.asarray(tg["position"])) + origin  # start-heading frame -> world
            assert np.allclose(world, tg["world"], atol=1e-9)
            effector = gp[tg["apex_frame"], motion.skeleton.index(tg["effector"])]
            assert np.linalg.norm(effector - world) < 0.02
            assert tg["apex_frame"] in apexes
            assert world[1] > 0.2


def test_every_clip_is_plausible(corpus: list[Path]) -> None:
    assert len(corpus) == 3 * len(CATEGORIES)
    for path in corpus:
        cat, v = path.stem.rsplit("_", 1)
        motion, truth = generate_clip(cat, int(v), seed=7)
        assert 3.0 <= motion.duration <= 6.5, path.stem
        assert truth["ik_max_miss_m"] < 1e-9, path.stem
        assert _lowest_foot_point(motion) >= -1e-3, path.stem
        # legs rotate smoothly: under 20 degrees between consecutive frames at 60 fps
        legs = [motion.skeleton.index(n) for n in motion.skeleton.names if "Leg" in n or "Foot" in n]
        q = motion.rotations[:, legs]
        dot = np.clip(np.abs(np.sum(q[1:] * q[:-1], axis=-1)), 0.0, 1.0)
        assert np.degrees(2 * np.arccos(dot)).max() < 20.0, path.stem


def test_corpus_is_deterministic_and_round_trips(corpus: list[Path], tmp_path: Path) -> None:
    again = write_demo_corpus(tmp_path / "b")
    assert [p.relative_to(tmp_path / "b") for p in again] == [p.relative_to(corpus[0].parents[1]) for p in corpus]
    for a, b in zip(corpus, again, strict=True):
        assert a.read_bytes() == b.read_bytes()
        assert a.with_suffix(".json").read_bytes() == b.with_suffix(".json").read_bytes()
    for path in corpus:
        cat, v = path.stem.rsplit("_", 1)
        motion, _ = generate_clip(cat, int(v), seed=7)
        back = read_bvh(path)
        assert back.skeleton.names == motion.skeleton.names and back.n_frames == motion.n_frames
        assert back.fps == pytest.approx(60.0)
        p0, _ = forward_kinematics(motion)
        p1, _ = forward_kinematics(back)
        assert np.abs(p0 - p1).max() < 1e-4, path.stem


def test_variants_and_seeds_differ() -> None:
    _a, ta = generate_clip("walk", 0, seed=7)
    _b, tb = generate_clip("walk", 0, seed=8)
    _c, tc = generate_clip("walk", 1, seed=7)
    assert ta["params"] != tb["params"] and ta["params"] != tc["params"]
    with pytest.raises(ValueError, match="unknown category"):
        generate_clip("swim", 0, 0)


@pytest.mark.parametrize("n_out,n_in", [(200, 240), (150, 120), (90, 90)])
def test_random_warp(n_out: int, n_in: int) -> None:
    for seed in range(5):
        w = random_warp(n_out, n_in, np.random.default_rng(seed))
        d = np.diff(w)
        assert w.shape == (n_out,) and w[0] == 0.0 and w[-1] == n_in - 1
        assert np.all(d > 0) and d.min() >= 0.7 and d.max() <= 1.5
        assert d.std() > 0.02  # not linear
        assert np.abs(np.diff(d)).max() < 0.1  # smooth
    with pytest.raises(ValueError):
        random_warp(100, 300, np.random.default_rng(0))


def test_time_warp_clip() -> None:
    motion, _ = generate_clip("walk", 0, seed=7)
    same = time_warp_clip(motion, np.arange(motion.n_frames, dtype=float))
    assert np.allclose(same.root_positions, motion.root_positions)
    w = random_warp(300, motion.n_frames, np.random.default_rng(1))
    warped = time_warp_clip(motion, w)
    assert warped.n_frames == 300 and warped.fps == motion.fps
    assert np.allclose(warped.root_positions[-1], motion.root_positions[-1])
    assert np.allclose(np.linalg.norm(warped.rotations, axis=-1), 1.0)


def test_per_category_variant_counts(tmp_path: Path) -> None:
    files = write_demo_corpus(tmp_path, variants_per_category=1, variants={"reach": 3, "idle": 0})
    names = sorted(p.stem for p in files)
    assert [n for n in names if n.startswith("reach")] == ["reach_00", "reach_01", "reach_02"]
    assert not [n for n in names if n.startswith("idle")] and "walk_00" in names and "walk_01" not in names
    with pytest.raises(ValueError, match="unknown categories swim"):
        write_demo_corpus(tmp_path, variants={"swim": 2})
