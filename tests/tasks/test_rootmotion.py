"""Root motion (tasks/rootmotion.py, issue 26): the hips' ground travel and heading move onto a
root joint; world positions are unchanged and applying the root motion back gives the original."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fixtures import wiggle
from motionweb.store.formats import read_motion, write_motion
from motionweb.store.kinematics import forward_kinematics, heading_angle
from motionweb.tasks.rootmotion import RootMotionParams, apply_root_motion, extract_root_motion, root_motion


def same_rotations(a: np.ndarray, b: np.ndarray, tol: float) -> None:
    d = np.minimum(np.abs(a - b).max(-1), np.abs(a + b).max(-1))
    assert d.max() < tol, d.max()


def test_extract_then_apply_is_the_original() -> None:
    m = wiggle(120, 30.0, seed=8)
    rm = extract_root_motion(m)
    assert rm.skeleton.names == ("root",) + m.skeleton.names
    assert np.all(rm.root_positions[:, 1] == 0.0)
    np.testing.assert_allclose(rm.root_positions[:, [0, 2]], m.root_positions[:, [0, 2]])
    # in place: the hips keep their height, no heading left in their rotation
    np.testing.assert_allclose(rm.translations[1][:, 1], m.root_positions[:, 1], atol=1e-12)
    np.testing.assert_allclose(heading_angle(rm.rotations[:, 1]), 0.0, atol=1e-9)
    np.testing.assert_allclose(forward_kinematics(rm)[0][:, 1:], forward_kinematics(m)[0], atol=1e-9)
    back = apply_root_motion(rm)
    assert back.skeleton.names == m.skeleton.names
    assert np.array_equal(back.skeleton.parents, m.skeleton.parents)
    np.testing.assert_allclose(back.root_positions, m.root_positions, atol=1e-9)
    np.testing.assert_allclose(back.skeleton.offsets, m.skeleton.offsets, atol=0)
    same_rotations(back.rotations, m.rotations, 1e-9)
    assert back.translations == {}
    assert root_motion(m, RootMotionParams()) is m
    with pytest.raises(ValueError, match="no root-motion joint"):
        apply_root_motion(m)


def test_z_up_and_bvh_round_trip(tmp_path: Path) -> None:
    m = wiggle(30, 30.0, seed=9, unit="cm")
    z = extract_root_motion(m, up="z")
    assert np.all(z.root_positions[:, 2] == 0.0)
    np.testing.assert_allclose(forward_kinematics(z)[0][:, 1:], forward_kinematics(m)[0], atol=1e-9)
    rm = extract_root_motion(m)
    write_motion(rm, tmp_path / "rm.bvh")
    back = read_motion(tmp_path / "rm.bvh", unit="cm")
    order = [back.skeleton.index(n) for n in rm.skeleton.names]
    np.testing.assert_allclose(forward_kinematics(back)[0][:, order], forward_kinematics(rm)[0], atol=1e-3)


@pytest.mark.slow
def test_cmu_root_is_renamed(cmu16: Path) -> None:
    m = read_motion(cmu16 / "16_15.amc")
    rm = extract_root_motion(m)
    assert rm.skeleton.names[:2] == ("root_motion", "root")
    back = apply_root_motion(rm)
    np.testing.assert_allclose(back.root_positions, m.root_positions, atol=1e-9)
    same_rotations(back.rotations, m.rotations, 1e-9)
