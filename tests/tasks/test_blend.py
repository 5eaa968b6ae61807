"""Blending registered examples (KG04 §4): alignment, quaternion average, reproduction of an
example, identical examples, leg IK, foot plants and skate."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from motionweb.store.demo.corpus import generate_clip
from motionweb.store.demo.perturb import random_warp, time_warp_clip
from motionweb.store.kinematics import forward_kinematics, heading_angle, quat_from_axis_angle, quat_mul
from motionweb.tasks.blend import (
    BlendParams,
    align_frames,
    blend,
    blend_poses,
    check_weights,
    detect_plants,
    ease_offsets,
    foot_skate,
    keytime_registration,
    leg_chains,
    leg_ik,
    metric_skeleton,
    registered_examples,
)
from motionweb.tasks.distance import rigid_align_2d
from naive import numpy_ease_offsets, numpy_hold_plants, numpy_leg_ik, ref_blend_frame, ref_leg_ik

RATE = 30.0


def start_frame(motion) -> np.ndarray:
    """(F, J, 3) joint positions in the motion's start-heading frame (root at frame 0 on the ground)."""
    g, _ = forward_kinematics(motion)
    h = float(heading_angle(motion.rotations[0, 0]))
    c, s = np.cos(-h), np.sin(-h)
    r = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return (g - g[0, 0] * np.array([1.0, 0.0, 1.0])) @ r.T


@pytest.fixture(scope="module")
def warped_pair():
    """walk_00 and a non-linearly time-warped copy, registered exactly (the inverse warp)."""
    a, _ = generate_clip("walk", 0, 7)
    n_b = int(a.n_frames * 1.2)
    warp = random_warp(n_b, a.n_frames, np.random.default_rng(1))
    b = time_warp_clip(a, warp)
    keys_a = np.linspace(0.0, (a.n_frames - 1) / a.fps, 40)
    keys_b = np.interp(keys_a * a.fps, warp, np.arange(n_b)) / b.fps
    reg = keytime_registration([a, b], [keys_a, keys_b], RATE)
    return a, b, reg


@pytest.fixture(scope="module")
def walks():
    """Three demo walks of different speeds and turns, registered by their left touchdowns."""
    clips = [generate_clip("walk", v, 7) for v in (0, 1, 3)]
    n_steps = min(len(t["contacts"]["left"]) for _, t in clips)
    keys = []
    for _, t in clips:
        on = [s / t["fps"] for s, _ in t["contacts"]["left"][1:n_steps]]
        keys.append(np.array(on))
    return [m for m, _ in clips], keytime_registration([m for m, _ in clips], keys, RATE)


def test_align_frames_matches_rigid_align_2d_frame_by_frame() -> None:
    rng = np.random.default_rng(0)
    p = rng.normal(size=(6, 10, 3))
    q = rng.normal(size=(6, 10, 3))
    w = rng.uniform(0.5, 2.0, 10)
    theta, t = align_frames(p, q, w)
    for f in range(6):
        th, tt, _ = rigid_align_2d(p[f], q[f], w)
        assert theta[f] == pytest.approx(th, abs=1e-12)
        np.testing.assert_allclose(t[f], tt, atol=1e-12)


def test_blended_rotations_equal_the_per_joint_quaternion_average(walks) -> None:
    motions, reg = walks
    ex = registered_examples(motions, reg)
    w = np.array([0.5, 0.7, -0.2])
    got = blend_poses(ex, w[None], slice(10, 11))[0, 0]
    ref = ref_blend_frame(ex.local[:, 10], w)
    np.testing.assert_allclose(np.abs(np.sum(got * ref, axis=-1)), 1.0, atol=1e-12)


def test_weight_one_reproduces_each_example(warped_pair) -> None:
    a, b, reg = warped_pair
    ex = registered_examples([a, b], reg)
    for k, m in enumerate((a, b)):
        w = np.eye(2)[k]
        r = blend(ex, w, fps=m.fps, hold_feet=False)
        n = min(m.n_frames, r.motion.n_frames)
        assert abs(r.motion.n_frames - m.n_frames) <= 2  # the example's own timing
        err = np.abs(start_frame(r.motion)[:n] - start_frame(replace(m, skeleton=ex.skeleton))[:n]).max()
        assert err < 0.03, (k, err)  # 30 Hz samples slerped back to 60 fps


def test_identical_examples_blend_to_the_example(warped_pair) -> None:
    a, _, reg = warped_pair
    reg2 = replace(reg, frames=np.repeat(reg.frames[:, :1], 2, axis=1), segments=[reg.segments[0]] * 2)
    ex = registered_examples([a, a], reg2)
    one = blend(ex, np.array([1.0, 0.0]), fps=a.fps)
    for w in ([0.3, 0.7], [1.2, -0.2]):
        r = blend(ex, np.array(w), fps=a.fps)
        assert r.motion.n_frames == one.motion.n_frames
        np.testing.assert_allclose(r.motion.root_positions, one.motion.root_positions, atol=1e-9)
        np.testing.assert_allclose(np.abs(np.sum(r.motion.rotations * one.motion.rotations, -1)), 1.0, atol=1e-9)


def test_weights_must_sum_to_one(warped_pair) -> None:
    with pytest.raises(ValueError, match="sum to 1"):
        check_weights(np.array([0.5, 0.6]), 2)
    with pytest.raises(ValueError, match="3 weights for 2 examples"):
        check_weights(np.array([0.5, 0.25, 0.25]), 2)


def test_leg_ik_reaches_targets_and_keeps_the_foot_orientation() -> None:
    m, _ = generate_clip("kick", 0, 7)
    sk = metric_skeleton(m)
    m = replace(m, skeleton=sk)
    legs = leg_chains(sk)
    hip, knee, ankle = legs["left"]
    gpos, grot = forward_kinematics(m)
    rng = np.random.default_rng(2)
    frames = np.arange(0, m.n_frames, 7)
    target = gpos[frames, ankle] + rng.normal(0.0, 0.08, (len(frames), 3))
    lh, lk, la, miss = leg_ik(gpos[frames], grot[frames], sk.parents, legs["left"], target,
                              np.tile([1.0, 0.0, 0.0], (len(frames), 1)))
    rot = m.rotations[frames].copy()
    rot[:, hip], rot[:, knee], rot[:, ankle] = lh, lk, la
    out = replace(m, root_positions=m.root_positions[frames], rotations=rot)
    g2, r2 = forward_kinematics(out)
    reach = miss < 1e-12
    assert 0.5 < reach.mean() < 1.0
    np.testing.assert_allclose(g2[reach, ankle], target[reach], atol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(r2[:, ankle] * grot[frames, ankle], -1)), 1.0, atol=1e-9)
    others = [j for j in range(sk.n_joints) if j not in (hip, knee, ankle)]
    np.testing.assert_array_equal(out.rotations[:, others], m.rotations[frames][:, others])
    for i in np.flatnonzero(~reach)[:2]:  # out of reach: as close as any hip/knee rotation gets
        assert np.linalg.norm(g2[i, ankle] - target[i]) == pytest.approx(
            ref_leg_ik(m, legs["left"], int(frames[i]), target[i]), abs=2e-4)


def test_compiled_leg_ik_equals_the_numpy_steps() -> None:
    m, _ = generate_clip("kick", 1, 7)
    sk = metric_skeleton(m)
    m = replace(m, skeleton=sk, root_positions=m.root_positions * m.metres())
    legs = leg_chains(sk)
    gpos, grot = forward_kinematics(m)
    rng = np.random.default_rng(5)
    for side in ("left", "right"):
        hip, knee, ankle = legs[side]
        target = gpos[:, ankle] + rng.normal(0.0, 0.15, (m.n_frames, 3))  # some out of reach
        target[::9] = gpos[::9, hip] - (gpos[::9, ankle] - gpos[::9, hip])  # straight through the hip: opposite
        fallback = rng.normal(size=(m.n_frames, 3))
        fallback /= np.linalg.norm(fallback, axis=1, keepdims=True)
        g = gpos.copy()
        g[::5, knee] = 0.5 * (g[::5, hip] + g[::5, ankle])  # a straight leg: the knee axis falls back
        fast = leg_ik(g, grot, sk.parents, legs[side], target, fallback)
        slow = numpy_leg_ik(g, grot, sk.parents, legs[side], target, fallback)
        for a, b in zip(fast, slow, strict=True):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-10)


def test_compiled_ease_offsets_equal_the_numpy_runs() -> None:
    rng = np.random.default_rng(3)
    for n, ramp in ((5, 3), (40, 1), (120, 9), (120, 40)):
        ankles = rng.normal(size=(n, 3))
        for density in (0.0, 0.2, 0.7, 1.0):
            plants = rng.random(n) < density
            head = n // 2  # longer runs there: ramps of neighbouring runs overlap and average
            plants[:head] = np.convolve(plants, np.ones(4), "same")[:head] > 0
            fast, slow = ease_offsets(n, plants, ankles, ramp), numpy_ease_offsets(n, plants, ankles, ramp)
            np.testing.assert_array_equal(fast[1], slow[1])
            np.testing.assert_allclose(fast[0], slow[0], rtol=0, atol=1e-12)


def test_held_plants_equal_the_full_fk_reference(walks) -> None:
    motions, reg = walks
    cfg = BlendParams()
    ex = registered_examples(motions, reg, cfg=cfg)
    for w in ([0.2, 0.5, 0.3], [1.1, -0.1, 0.0]):
        raw = blend(ex, np.array(w), fps=60.0, cfg=cfg, hold_feet=False, measure=False)
        fast = blend(ex, np.array(w), fps=60.0, cfg=cfg)
        slow, miss = numpy_hold_plants(raw.motion, ex.legs, raw.plants, cfg)
        assert raw.plants.any()
        np.testing.assert_array_equal(fast.plants, raw.plants)
        np.testing.assert_allclose(fast.motion.rotations, slow.rotations, rtol=0, atol=1e-10)
        assert fast.ik_miss == pytest.approx(miss, abs=1e-10)
        g, _ = forward_kinematics(slow)
        feet = [ex.legs["left"][2], ex.legs["right"][2]]
        assert fast.skate == pytest.approx(foot_skate(g[:, feet], raw.plants, 60.0), abs=1e-8)


def test_detected_plants_agree_with_the_demo_truth() -> None:
    m, truth = generate_clip("walk", 1, 7)
    sk = metric_skeleton(m)
    legs = leg_chains(sk)
    g, _ = forward_kinematics(replace(m, skeleton=sk))
    pl = detect_plants(g[:, [legs["left"][2], legs["right"][2]]], m.fps, BlendParams())
    for k, side in enumerate(("left", "right")):
        true = np.zeros(m.n_frames, bool)
        for a, b in truth["heel_contacts"][side]:
            true[a:b + 1] = True
        contact = np.zeros(m.n_frames, bool)  # flat foot or heel rising about the toe
        for a, b in truth["contacts"][side]:
            contact[a:b + 1] = True
        assert np.mean(pl[:, k] == true) > 0.85, side
        assert pl[:, k][~contact].mean() < 0.05  # no plant while the truth says the foot swings


def test_blend_holds_plants_and_skates_no_more_than_the_examples(walks) -> None:
    motions, reg = walks
    cfg = BlendParams()
    ex = registered_examples(motions, reg, cfg=cfg)
    skates = []
    for m in motions:
        g, _ = forward_kinematics(replace(m, skeleton=ex.skeleton))
        ank = g[:, [ex.legs["left"][2], ex.legs["right"][2]]]
        skates.append(foot_skate(ank, detect_plants(ank, m.fps, cfg), m.fps))
    for w in ([1 / 3, 1 / 3, 1 / 3], [0.6, -0.1, 0.5]):
        r = blend(ex, np.array(w), fps=60.0, cfg=cfg)
        assert r.plants.mean() > 0.3  # both feet planted in stance
        assert r.skate <= 1.5 * np.mean(skates), (w, r.skate, skates)
        assert r.skate < r.skate_raw


def test_blend_of_turned_examples_turns_between_them(walks) -> None:
    motions, reg = walks
    ex = registered_examples(motions, reg)
    def final_heading(w):
        r = blend(ex, np.array(w), hold_feet=False)
        h = np.unwrap(heading_angle(r.motion.rotations[:, 0]))
        return h[-10:].mean() - h[:10].mean()
    h0, h1, mid = final_heading([1, 0, 0]), final_heading([0, 1, 0]), final_heading([0.5, 0.5, 0])
    assert min(h0, h1) < mid < max(h0, h1)
    assert abs(h1 - h0) > 0.2


def test_leg_chains_errors_name_the_joint() -> None:
    m, _ = generate_clip("walk", 0, 7)
    with pytest.raises(ValueError, match="unknown left ankle joint 'Nope'"):
        leg_chains(m.skeleton, {"left": "Nope"})


def test_quaternion_sign_flips_do_not_change_a_blend(warped_pair) -> None:
    a, b, reg = warped_pair
    flipped = replace(b, rotations=-b.rotations)
    e1 = registered_examples([a, b], reg)
    e2 = registered_examples([a, flipped], reg)
    w = np.array([0.4, 0.6])
    r1, r2 = blend(e1, w, hold_feet=False), blend(e2, w, hold_feet=False)
    np.testing.assert_allclose(np.abs(np.sum(r1.motion.rotations * r2.motion.rotations, -1)), 1.0, atol=1e-9)
    # a 180° turn of one example (world frame) changes nothing either: blends are in the start frame
    q = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.array(np.pi))
    turned = replace(b, rotations=np.concatenate([quat_mul(q, b.rotations[:, :1]), b.rotations[:, 1:]], 1),
                     root_positions=b.root_positions * np.array([-1.0, 1.0, -1.0]))
    r3 = blend(registered_examples([a, turned], reg), w, hold_feet=False)
    np.testing.assert_allclose(start_frame(r3.motion), start_frame(r1.motion), atol=1e-6)


def test_unmeasured_blend_is_the_same_motion(walks) -> None:
    motions, reg = walks
    ex = registered_examples(motions, reg)
    w = np.array([0.2, 0.5, 0.3])
    a, b = blend(ex, w, fps=60.0), blend(ex, w, fps=60.0, measure=False)
    np.testing.assert_array_equal(a.motion.rotations, b.motion.rotations)
    assert np.isnan(b.skate) and np.isfinite(a.skate)
