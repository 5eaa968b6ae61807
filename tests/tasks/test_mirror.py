"""Mirroring (tasks/mirror.py, issue 26): twice is the identity, world positions are reflected
onto the partner joints, a mirrored walk's left-foot plants are the original's right-foot plants,
and the CMU (ASF and cgspeed BVH) and DeepMimic skeletons all mirror."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fixtures import tiny_motion, wiggle
from motionweb.store.demo.corpus import generate_clip
from motionweb.store.formats import read_motion
from motionweb.store.kinematics import forward_kinematics
from motionweb.store.motion import Motion
from motionweb.tasks.blend import BlendParams, detect_plants, leg_chains
from motionweb.tasks.mirror import MirrorParams, mirror, mirror_pairs
from motionweb.tasks.rootmotion import extract_root_motion

CGSPEED_SCALE = 0.0254 / 0.45


def assert_same(a: Motion, b: Motion, tol: float = 1e-9) -> None:
    assert a.skeleton.names == b.skeleton.names
    np.testing.assert_allclose(a.rotations, b.rotations, atol=tol)
    np.testing.assert_allclose(a.root_positions, b.root_positions, atol=tol)
    np.testing.assert_allclose(a.skeleton.offsets, b.skeleton.offsets, atol=tol)
    assert a.translations.keys() == b.translations.keys()
    for j in a.translations:
        np.testing.assert_allclose(a.translations[j], b.translations[j], atol=tol)
    assert sorted(a.skeleton.end_sites) == sorted(b.skeleton.end_sites)


def check_mirror(m: Motion, n_pairs: int) -> None:
    """Twice = original (1e-9); world positions of joint j = M (positions of its partner)."""
    res = mirror(m)
    assert len(res.pairs) == n_pairs, res.pairs
    assert_same(mirror(res.motion).motion, m)
    perm = mirror_pairs(m.skeleton)
    flip = np.ones(3)
    flip[res.axis] = -1.0
    scale = np.abs(forward_kinematics(m)[0]).max()
    np.testing.assert_allclose(forward_kinematics(res.motion)[0], forward_kinematics(m)[0][:, perm] * flip,
                               atol=1e-9 * max(1.0, scale))


def plants(m: Motion) -> np.ndarray:
    legs = leg_chains(m.skeleton)
    gp = forward_kinematics(m)[0] * m.metres()
    return detect_plants(gp[:, [legs["left"][2], legs["right"][2]]], m.fps, BlendParams())


def test_synthetic_mirror_twice_and_reflected_positions() -> None:
    m = wiggle(80, 30.0, seed=2)
    check_mirror(m, 3)  # lleg/rleg, lknee/rknee, larm/rarm
    assert mirror(m).axis == 0
    # a skeleton with position channels below the root and a root-motion joint mirrors too
    check_mirror(extract_root_motion(m), 3)


def test_demo_walk_plants_swap_sides() -> None:
    walk, _ = generate_clip("walk", 0, 7, 60.0)
    check_mirror(walk, 8)
    before, after = plants(walk), plants(mirror(walk).motion)
    assert before[:, 0].any() and before[:, 1].any()
    assert np.array_equal(after[:, 0], before[:, 1]) and np.array_equal(after[:, 1], before[:, 0])


def test_pairs_override_and_errors() -> None:
    m = wiggle(10, 30.0, seed=1)
    with pytest.raises(ValueError, match="no left/right joint pairs"):
        mirror(tiny_motion(5, 30.0))
    with pytest.raises(ValueError, match="unknown joint 'nose'"):
        mirror(m, MirrorParams(pairs={"nose": "larm"}))
    with pytest.raises(ValueError, match="do not mirror the hierarchy"):
        mirror(m, MirrorParams(pairs={"larm": "rleg"}))
    # the override pairs joints the names do not: hips/spine stay unpaired, arms swapped explicitly
    perm = mirror_pairs(m.skeleton, {"larm": "rarm"})
    assert m.skeleton.names[perm[m.skeleton.index("larm")]] == "rarm"
    assert mirror(m, MirrorParams(axis="x")).axis == 0


@pytest.mark.slow
def test_real_skeletons_mirror(cmu_dir: Path, deepmimic_dir: Path) -> None:
    amc = read_motion(cmu_dir / "asf_amc" / "16" / "16_15.amc")
    check_mirror(amc, 12)
    assert mirror(amc).asymmetry < 0.02  # CMU's left and right bones differ by ~1.5 cm at most
    bvh = [read_motion(cmu_dir / "bvh" / p, scale_to_m=CGSPEED_SCALE) for p in ("01/01_01.bvh", "131/131_02.bvh")]
    for m in bvh:
        check_mirror(m, 12)
    dm = read_motion(deepmimic_dir / "motions" / "humanoid3d_walk.txt")
    check_mirror(dm, 5)
    assert mirror(dm).axis == 2  # DeepMimic's humanoid faces +x: z is lateral
    for walk in (amc, bvh[1], dm):  # 131_02: cgspeed's "start, walk, stop"
        before, after = plants(walk), plants(mirror(walk).motion)
        assert before[:, 0].any() and before[:, 1].any(), walk.name
        assert np.array_equal(after, before[:, ::-1]), walk.name
