"""Quaternion algebra and forward kinematics against closed forms and scipy."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from motionweb.store.demo.corpus import generate_clip
from motionweb.store.kinematics import (
    forward_kinematics,
    forward_kinematics_of,
    heading,
    heading_angle,
    hold_ends,
    joint_paths,
    quat_average,
    quat_exp,
    quat_from_euler,
    quat_from_matrix,
    quat_inv,
    quat_log,
    quat_mul,
    quat_rotate,
    quat_slerp,
    quat_to_euler,
    quat_to_matrix,
    resample,
    sample_motion,
    to_heading_frame,
)
from motionweb.store.motion import Motion, Skeleton
from naive import ref_forward_kinematics
from scipy.spatial.transform import Rotation

RNG = np.random.default_rng(0)


def random_quats(n: int) -> np.ndarray:
    q = RNG.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def same_rotation(a: np.ndarray, b: np.ndarray, tol: float = 1e-9) -> bool:
    return bool(np.all(np.abs(np.abs(np.sum(a * b, axis=-1)) - 1.0) < tol))


@pytest.mark.parametrize("order", ["".join(p) for p in itertools.permutations("XYZ")])
def test_euler_matches_scipy_for_all_orders(order: str) -> None:
    angles = RNG.uniform(-180, 180, size=(50, 3))
    q = quat_from_euler(angles, order)
    ref = Rotation.from_euler(order, angles, degrees=True).as_quat()[:, [3, 0, 1, 2]]
    assert same_rotation(q, ref)
    back = quat_to_euler(q, order)
    assert same_rotation(quat_from_euler(back, order), q)


def test_mul_inverse_rotate_and_matrix() -> None:
    a, b = random_quats(20), random_quats(20)
    v = RNG.normal(size=(20, 3))
    ab = quat_mul(a, b)
    np.testing.assert_allclose(quat_rotate(ab, v), quat_rotate(a, quat_rotate(b, v)), atol=1e-12)
    np.testing.assert_allclose(quat_rotate(quat_mul(quat_inv(a), a), v), v, atol=1e-12)
    m = quat_to_matrix(a)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", m, v), quat_rotate(a, v), atol=1e-12)
    assert same_rotation(quat_from_matrix(m), a)


def test_log_exp_round_trip_and_angle() -> None:
    q = random_quats(30)
    assert same_rotation(quat_exp(quat_log(q)), q)
    # a rotation of 90 degrees about z has log (0, 0, pi/4)
    qz = quat_from_euler(np.array([0.0, 0.0, 90.0]), "XYZ")
    np.testing.assert_allclose(quat_log(qz), [0, 0, np.pi / 4], atol=1e-12)


def test_slerp_closed_form_and_shortest_arc() -> None:
    q0 = quat_from_euler(np.array([0.0, 10.0, 0.0]), "XYZ")
    q1 = quat_from_euler(np.array([0.0, 70.0, 0.0]), "XYZ")
    for t in (0.0, 0.25, 0.5, 1.0):
        expect = quat_from_euler(np.array([0.0, 10.0 + 60.0 * t, 0.0]), "XYZ")
        assert same_rotation(quat_slerp(q0, q1, t), expect)
    # -q1 is the same rotation: slerp must still take the short way
    assert same_rotation(quat_slerp(q0, -q1, 0.5), quat_from_euler(np.array([0.0, 40.0, 0.0]), "XYZ"))


def test_weighted_average_of_rotations_about_one_axis() -> None:
    angles = np.array([10.0, 20.0, 60.0])
    q = quat_from_euler(np.stack([np.zeros(3), angles, np.zeros(3)], axis=1), "XYZ")
    q[1] *= -1  # sign must not matter
    w = np.array([0.5, 0.5, 0.0])
    assert same_rotation(quat_average(q, w), quat_from_euler(np.array([0.0, 15.0, 0.0]), "XYZ"))
    # near-convex weights with a slightly negative one stay a unit quaternion
    avg = quat_average(q, np.array([0.6, 0.5, -0.1]))
    np.testing.assert_allclose(np.linalg.norm(avg), 1.0)


def two_bone(frames: int = 3) -> Motion:
    sk = Skeleton(
        names=("root", "upper", "lower"),
        parents=np.array([-1, 0, 1]),
        offsets=np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2.0, 0.0]]),
        channels=(("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),
                  ("Zrotation", "Xrotation", "Yrotation"), ("Zrotation", "Xrotation", "Yrotation")),
        end_sites={2: np.array([0.0, 3.0, 0.0])},
    )
    rot = np.zeros((frames, 3, 4))
    rot[..., 0] = 1.0
    return Motion(skeleton=sk, fps=30.0, root_positions=np.zeros((frames, 3)), rotations=rot, unit="m")


def test_fk_two_bones_against_hand_computation() -> None:
    m = two_bone(1)
    root = np.array([[1.0, 0.0, 0.0]])
    r = m.rotations.copy()
    r[0, 1] = quat_from_euler(np.array([90.0, 0.0, 0.0]), "ZXY")  # upper turns 90 deg about z
    r[0, 2] = quat_from_euler(np.array([0.0, 90.0, 0.0]), "ZXY")  # lower turns 90 deg about x
    m = Motion(skeleton=m.skeleton, fps=30.0, root_positions=root, rotations=r, unit="m")
    pos, rot = forward_kinematics(m)
    # root at (1,0,0); upper 1 above; lower: offset (0,2,0) rotated by Rz(90) -> (-2,0,0)
    np.testing.assert_allclose(pos[0, 0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(pos[0, 1], [1, 1, 0], atol=1e-12)
    np.testing.assert_allclose(pos[0, 2], [-1, 1, 0], atol=1e-12)
    # end site (0,3,0) under Rz(90) Rx(90): Rx maps y->z, Rz leaves z -> (0,0,3)
    tip = pos[0, 2] + quat_rotate(rot[0, 2], np.array([0.0, 3.0, 0.0]))
    np.testing.assert_allclose(tip, [-1, 1, 3], atol=1e-12)


@pytest.mark.parametrize("frames", [1, 2, 57])
def test_fk_is_the_numpy_formulas_bit_for_bit(frames: int) -> None:
    """The compiled FK gives the same bits as quat_mul/quat_rotate one joint at a time (the index's
    features, hence every web, depend on these bits), translated joints included."""
    m, _ = generate_clip("kick", 2, 7)
    m = m.slice(0, frames)
    m = Motion(skeleton=m.skeleton, fps=m.fps, root_positions=RNG.normal(size=(frames, 3)) * 100,
               rotations=random_quats(frames * m.skeleton.n_joints).reshape(m.rotations.shape), unit=m.unit,
               translations={3: RNG.normal(size=(frames, 3)), 15: RNG.normal(size=(frames, 3))})
    g, r = forward_kinematics(m)
    g0, r0 = ref_forward_kinematics(m)
    assert g.shape == (frames, m.skeleton.n_joints, 3) and r.shape == (frames, m.skeleton.n_joints, 4)
    assert np.array_equal(g, g0) and np.array_equal(r, r0)


def test_fk_of_real_clips_is_the_numpy_formulas_bit_for_bit(cmu_dir) -> None:
    """Same bits on real capture: a CMU BVH (31 joints, 2,752 frames) and an ASF/AMC trial."""
    from motionweb.store.formats import read_motion

    bvh = sorted((cmu_dir / "bvh").rglob("*.bvh"))
    amc = sorted((cmu_dir / "asf_amc").rglob("*.amc"))
    if not bvh or not amc:
        pytest.skip(f"no CMU BVH or AMC trial under {cmu_dir}")
    for path in (bvh[0], amc[0]):
        m = read_motion(path)
        g, r = forward_kinematics(m)
        g0, r0 = ref_forward_kinematics(m)
        assert np.array_equal(g, g0) and np.array_equal(r, r0), path


def test_fk_of_some_joints_equals_the_full_fk_on_their_paths() -> None:
    m, _ = generate_clip("kick", 2, 7)
    m = Motion(skeleton=m.skeleton, fps=m.fps, root_positions=m.root_positions,
               rotations=random_quats(m.n_frames * m.skeleton.n_joints).reshape(m.rotations.shape), unit=m.unit,
               translations={3: RNG.normal(size=(m.n_frames, 3)), 15: RNG.normal(size=(m.n_frames, 3))})
    g, r = forward_kinematics(m)
    names = m.skeleton.names
    for joints in ([names.index("LeftFoot"), names.index("RightFoot")], [names.index("RightHand")], [0]):
        path = joint_paths(m.skeleton.parents, joints)
        want = set()
        for j in joints:
            while j >= 0:
                want.add(j)
                j = int(m.skeleton.parents[j])
        assert path.tolist() == sorted(want)
        g2, r2 = forward_kinematics_of(m, joints)
        np.testing.assert_allclose(g2[:, path], g[:, path], rtol=0, atol=1e-12)  # a translated joint too
        np.testing.assert_allclose(r2[:, path], r[:, path], rtol=0, atol=1e-12)
        rest = np.setdiff1d(np.arange(m.skeleton.n_joints), path)
        assert np.isnan(g2[:, rest]).all() and np.isnan(r2[:, rest]).all()


def test_resample_and_sample_motion() -> None:
    m = two_bone(31)
    t = np.arange(31) / 30.0
    root = np.stack([t, np.zeros(31), 2 * t], axis=1)
    rot = m.rotations.copy()
    rot[:, 1] = quat_from_euler(np.stack([np.zeros(31), 90.0 * t, np.zeros(31)], axis=1), "ZXY")
    m = Motion(skeleton=m.skeleton, fps=30.0, root_positions=root, rotations=rot, unit="m")
    r = resample(m, 120.0)
    assert r.n_frames == 121 and r.fps == 120.0
    tt = np.arange(121) / 120.0
    np.testing.assert_allclose(r.root_positions[:, 2], 2 * tt, atol=1e-12)
    expect = quat_from_euler(np.stack([np.zeros(121), 90.0 * tt, np.zeros(121)], axis=1), "ZXY")
    assert same_rotation(r.rotations[:, 1], expect)
    half = sample_motion(m, np.array([0.5]))
    np.testing.assert_allclose(half.root_positions[0], root[0] * 0.5 + root[1] * 0.5)


def test_heading_extracts_vertical_twist() -> None:
    yaw = np.deg2rad(np.array([-150.0, -30.0, 0.0, 45.0, 170.0]))
    tilt = quat_from_euler(np.array([0.0, 0.0, 20.0]), "XYZ")  # a lean about z after the turn
    q = quat_mul(quat_from_euler(np.stack([np.zeros(5), np.rad2deg(yaw), np.zeros(5)], 1), "XYZ"), tilt)
    np.testing.assert_allclose(heading_angle(q), yaw, atol=1e-9)
    pure = heading(q)
    assert np.allclose(pure[:, [1, 3]], 0.0)
    # a point 1 m in front of a root turned by yaw, expressed in the heading frame, is in front again
    root_pos = np.array([[3.0, 0.9, -2.0]] * 5)
    fwd = quat_rotate(pure, np.array([0.0, 0.0, 1.0]))
    pts = (root_pos + fwd)[:, None, :]
    local = to_heading_frame(pts, root_pos, q)
    np.testing.assert_allclose(local[:, 0], np.tile([0.0, 0.9, 1.0], (5, 1)), atol=1e-9)


def test_hold_ends_repeats_first_and_last_pose() -> None:
    motion = generate_clip("walk", 0, 0, fps=30.0)[0]
    held = hold_ends(motion, 0.5)
    assert held.n_frames == motion.n_frames + 30
    np.testing.assert_array_equal(held.rotations[:16], np.repeat(motion.rotations[:1], 16, 0))
    np.testing.assert_array_equal(held.root_positions[15:-15], motion.root_positions)
    np.testing.assert_array_equal(held.root_positions[-15:], np.repeat(motion.root_positions[-1:], 15, 0))
