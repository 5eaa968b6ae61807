"""DeepMimic reader: a hand-made URDF and clips (always run), then the real clips (skipped when the
data folder is absent): scale, ground contact, free fall in the jump's flight, BVH round trip."""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from fixtures import BASE_MASS, HUMANOID_BODY, ROOT_MASS, deepmimic_frame, handmade_urdf_text
from motionweb.store.bvh import read_bvh, write_bvh
from motionweb.store.deepmimic import (
    FRAME_WIDTH,
    URDF_SCALE,
    centre_of_mass,
    foot_corners,
    read_deepmimic,
    read_humanoid_urdf,
)
from motionweb.store.errors import (
    EmptyMotionError,
    FrameValueError,
    MissingSectionError,
    SyntaxFormatError,
    TruncatedFileError,
)
from motionweb.store.kinematics import end_site_positions, forward_kinematics, quat_from_axis_angle

G = 9.81

# ---- the hand-made humanoid of fixtures.py (own numbers, URDF units = 4 x metres) --------------

@pytest.fixture
def urdf_path(tmp_path: Path) -> Path:
    p = tmp_path / "humanoid.urdf"
    p.write_text(handmade_urdf_text())
    return p


def _clip(tmp_path: Path, frames: list, name: str = "clip.txt", raw: str | None = None) -> Path:
    """One frame per line: frame k is on line 4 + k."""
    folder = tmp_path / "motions"
    folder.mkdir(exist_ok=True)
    p = folder / name
    body = ",\n".join(json.dumps(f) for f in frames)
    p.write_text(raw if raw is not None else '{\n"Loop": "wrap",\n"Frames": [\n' + body + "\n]\n}\n")
    return p


def test_handmade_urdf(urdf_path: Path) -> None:
    model = read_humanoid_urdf(urdf_path)
    sk = model.skeleton
    assert sk.names[:6] == ("root", "chest", "neck", "right_hip", "right_knee", "right_ankle")
    assert "right_wrist" not in sk.names and len(sk.names) == 13
    assert model.joint_types[0] == "free" and model.joint_types[sk.index("right_knee")] == "revolute"
    np.testing.assert_allclose(model.axes[sk.index("left_elbow")], [0, 0, 1])
    np.testing.assert_allclose(model.limits[sk.index("left_knee")], [-3, 0])
    s = URDF_SCALE
    np.testing.assert_allclose(sk.offsets[sk.index("right_knee")], [0, -1.6 * s, 0])
    np.testing.assert_allclose(sk.offsets[sk.index("left_shoulder")], [0, 0.8 * s, -0.8 * s])
    assert model.total_mass == pytest.approx(ROOT_MASS + BASE_MASS + sum(r[4] for r in HUMANOID_BODY))
    assert model.mass is model.masses and model.com is model.coms and model.inertia is model.inertias
    # the wrist is fixed to the elbow: one body, COM between them, the wrist as end site
    e = sk.index("right_elbow")
    assert model.bodies[e] == ("right_elbow", "right_wrist")
    assert model.masses[e] == pytest.approx(1.5)
    np.testing.assert_allclose(model.coms[e], [0, (1.0 * -0.5 + 0.5 * -1.0) / 1.5 * s, 0])
    np.testing.assert_allclose(sk.end_sites[e], [0, -1 * s, 0])
    np.testing.assert_allclose(sk.end_sites[sk.index("neck")], [0, 1.0 * s, 0])  # sphere top
    np.testing.assert_allclose(sk.end_sites[sk.index("left_ankle")], [0.6 * s, -0.2 * s, 0])  # toe on sole
    box = model.foot_boxes["right_ankle"]
    np.testing.assert_allclose(box.size, np.array([0.8, 0.2, 0.4]) * s)
    # solid-shape inertia: a sphere's 2/5 m r^2 about its centre (the COM)
    np.testing.assert_allclose(model.inertias[sk.index("chest")], np.eye(3) * 0.4 * 10 * (0.4 * s) ** 2)
    # a capsule along y: the axial moment is the smallest
    hip = model.inertias[sk.index("right_hip")]
    assert hip[1, 1] < hip[0, 0] and hip[0, 0] == pytest.approx(hip[2, 2])
    assert np.allclose(hip, hip.T)


def test_handmade_clip_fk(tmp_path: Path, urdf_path: Path) -> None:
    half = np.sqrt(0.5)
    frames = [deepmimic_frame(root=(1.0, 0.9, 2.0)),
              deepmimic_frame(root=(1.0, 0.9, 2.0), root_q=(half, 0.0, half, 0.0), right_knee=-np.pi / 2),
              deepmimic_frame(0.0)]
    p = _clip(tmp_path, frames)
    m = read_deepmimic(p, urdf_path)
    assert m.fps == 30.0 and m.n_frames == 3 and m.unit == "m" and m.scale_to_m == 1.0
    assert m.content_hash == hashlib.sha256(p.read_bytes()).hexdigest()
    pos, _ = forward_kinematics(m)
    sk = m.skeleton
    s = URDF_SCALE
    k, a = sk.index("right_knee"), sk.index("right_ankle")
    # frame 0: rest pose; frame 1: body turned 90 deg about +Y, knee bent back 90 deg
    np.testing.assert_allclose(pos[0, a], [1.0, 0.9 - 3.2 * s, 2.0 + 0.4 * s], atol=1e-12)
    # Ry(90): x -> -z, z -> x. The hip offset (0, 0, 0.4s) goes to (0.4s, 0, 0); the shank
    # (0, -1.6s, 0) turned by Rz(-90) points to (-1.6s, 0, 0) and then by Ry(90) to (0, 0, 1.6s).
    np.testing.assert_allclose(pos[1, k], [1.0 + 0.4 * s, 0.9 - 1.6 * s, 2.0], atol=1e-12)
    np.testing.assert_allclose(pos[1, a], [1.0 + 0.4 * s, 0.9 - 1.6 * s, 2.0 + 1.6 * s], atol=1e-12)
    np.testing.assert_allclose(m.rotations[1, k], quat_from_axis_angle(np.array([0, 0, 1.0]), -np.pi / 2))
    # default URDF: ../humanoid.urdf beside the motions folder
    assert read_deepmimic(p).skeleton.names == sk.names


def test_unequal_durations_are_resampled(tmp_path: Path, urdf_path: Path) -> None:
    frames = [deepmimic_frame(0.1, root=(0.0, 0.9, 0)), deepmimic_frame(0.2, root=(1.0, 0.9, 0)),
              deepmimic_frame(0.1, root=(2.0, 0.9, 0)), deepmimic_frame(0.0, root=(3.0, 0.9, 0))]
    m = read_deepmimic(_clip(tmp_path, frames), urdf_path)
    assert m.fps == 10.0
    np.testing.assert_allclose(m.root_positions[:, 0], [0.0, 1.0, 1.5, 2.0, 3.0])


def test_bvh_round_trip_handmade(tmp_path: Path, urdf_path: Path) -> None:
    rng = np.random.default_rng(0)
    frames = []
    for _ in range(5):
        f = np.array(deepmimic_frame(right_knee=-1.0, left_elbow=0.7, right_elbow=2.0))
        for c in range(4, FRAME_WIDTH - 3, 4):
            if f[c] == 1.0:
                q = rng.normal(size=4)
                f[c:c + 4] = q / np.linalg.norm(q)
        frames.append(f.round(6).tolist())
    m = read_deepmimic(_clip(tmp_path, frames), urdf_path)
    _assert_bvh_round_trip(m, tmp_path / "rt.bvh")


def _assert_bvh_round_trip(m, out: Path) -> None:
    write_bvh(m, out)
    back = read_bvh(out, unit="m")
    idx = [back.skeleton.index(n) for n in m.skeleton.names]  # the BVH lists joints depth first
    p0, r0 = forward_kinematics(m)
    p1, r1 = forward_kinematics(back)
    np.testing.assert_allclose(p1[:, idx], p0, atol=1e-4)
    e0 = end_site_positions(m, p0, r0)
    e1 = end_site_positions(back, p1, r1)
    order = np.argsort([m.skeleton.names[k] for k in sorted(m.skeleton.end_sites)])
    order_b = np.argsort([back.skeleton.names[k] for k in sorted(back.skeleton.end_sites)])
    np.testing.assert_allclose(e1[:, order_b], e0[:, order], atol=1e-4)
    assert back.fps == pytest.approx(m.fps)


# ---- malformed clips: file and line of the faulty frame ----------------------------------------

def _expect(exc_type: type, path: Path, line: int | None, call) -> None:
    with pytest.raises(exc_type) as info:
        call()
    assert info.value.path == str(path)
    assert info.value.line == line
    assert path.name in str(info.value)


def test_bad_json(tmp_path: Path, urdf_path: Path) -> None:
    p = _clip(tmp_path, [], raw='{\n"Loop": "wrap",\n"Frames": [\n[0.1, 0 0]\n]\n}\n')
    _expect(SyntaxFormatError, p, 4, lambda: read_deepmimic(p, urdf_path))


def test_truncated_json(tmp_path: Path, urdf_path: Path) -> None:
    good = _clip(tmp_path, [deepmimic_frame(), deepmimic_frame(), deepmimic_frame(0.0)])
    text = good.read_text()
    line5 = sum(len(x) for x in text.splitlines(keepends=True)[:4])
    p = _clip(tmp_path, [], name="cut.txt", raw=text[: line5 + 30])  # ends inside frame 1
    _expect(TruncatedFileError, p, 5, lambda: read_deepmimic(p, urdf_path))


def test_wrong_value_count(tmp_path: Path, urdf_path: Path) -> None:
    frames = [deepmimic_frame(), deepmimic_frame(), deepmimic_frame(0.0)]
    frames[1] = frames[1][:-1]
    p = _clip(tmp_path, frames)
    _expect(FrameValueError, p, 5, lambda: read_deepmimic(p, urdf_path))


@pytest.mark.parametrize("bad", ["NaN", "Infinity", '"x"', "null"])
def test_bad_value(tmp_path: Path, urdf_path: Path, bad: str) -> None:
    frames = [json.dumps(deepmimic_frame()) for _ in range(3)]
    frames[2] = frames[2].replace("0.9", bad, 1)
    p = _clip(tmp_path, [], raw='{\n"Loop": "wrap",\n"Frames": [\n' + ",\n".join(frames) + "\n]\n}\n")
    _expect(FrameValueError, p, 6, lambda: read_deepmimic(p, urdf_path))


def test_zero_frames_and_missing_frames(tmp_path: Path, urdf_path: Path) -> None:
    p = _clip(tmp_path, [])
    _expect(EmptyMotionError, p, 3, lambda: read_deepmimic(p, urdf_path))
    q = _clip(tmp_path, [], name="noframes.txt", raw='{"Loop": "none"}\n')
    _expect(MissingSectionError, q, 1, lambda: read_deepmimic(q, urdf_path))


def test_zero_quaternion(tmp_path: Path, urdf_path: Path) -> None:
    frames = [deepmimic_frame(), deepmimic_frame(root_q=(0.0, 0.0, 0.0, 0.0)), deepmimic_frame(0.0)]
    p = _clip(tmp_path, frames)
    _expect(FrameValueError, p, 5, lambda: read_deepmimic(p, urdf_path))


# ---- the real clips --------------------------------------------------------------------------

@pytest.fixture(scope="module")
def real_model(deepmimic_dir: Path):
    return read_humanoid_urdf(deepmimic_dir / "humanoid.urdf")


def test_every_clip_loads(deepmimic_dir: Path, real_model) -> None:
    paths = sorted((deepmimic_dir / "motions").glob("*.txt"))
    assert len(paths) == 15
    total = 0.0
    for p in paths:
        m = read_deepmimic(p, real_model)
        n_file = len(json.loads(p.read_text())["Frames"])
        assert m.fps in (16.0, 24.0, 30.0, 60.0), p.name
        assert abs(m.n_frames - n_file) <= 1, p.name  # the roll is resampled over its dropped frame
        assert m.unit == "m" and m.content_hash == hashlib.sha256(p.read_bytes()).hexdigest()
        np.testing.assert_allclose(np.linalg.norm(m.rotations, axis=-1), 1.0, atol=1e-12)
        assert 0.05 < m.root_positions[:, 1].max() < 2.0, p.name
        total += m.duration
    assert 30.0 < total < 40.0  # README: ~35 s in all


def test_urdf_masses_and_scale(deepmimic_dir: Path, real_model) -> None:
    text = (deepmimic_dir / "humanoid.urdf").read_text(errors="replace")
    masses = [float(v) for v in re.findall(r'<mass\s+value\s*=\s*"([^"]+)"', text)]
    assert real_model.total_mass == pytest.approx(sum(masses))
    assert real_model.total_mass == pytest.approx(45.0, abs=1e-3)
    chest = re.search(r'name="chest" type="spherical".*?xyz = "([^"]+)"', text, re.DOTALL)
    np.testing.assert_allclose(real_model.skeleton.offsets[1], 0.25 * np.array(chest.group(1).split(), float))
    # the rest pose stands 1.6-1.8 m from the sole of the foot box to the top of the head sphere
    walk = read_deepmimic(deepmimic_dir / "motions" / "humanoid3d_walk.txt", real_model)
    rest = replace(walk, rotations=np.broadcast_to([1.0, 0, 0, 0], walk.rotations.shape).copy())
    pos, rot = forward_kinematics(rest)
    top = end_site_positions(rest, pos, rot)[0, :, 1].max()
    sole = foot_corners(real_model, rest)["right_ankle"][0, :, 1].min()
    assert 1.6 < top - sole < 1.8


def test_walk_feet_touch_the_ground(deepmimic_dir: Path, real_model) -> None:
    m = read_deepmimic(deepmimic_dir / "motions" / "humanoid3d_walk.txt", real_model)
    root_speed = np.linalg.norm(np.diff(m.root_positions[:, [0, 2]], axis=0), axis=1).mean() * m.fps
    assert 0.7 < root_speed < 1.5  # a walk
    for name, corners in foot_corners(real_model, m).items():
        height = corners[..., 1].min(axis=-1)
        assert abs(height.min()) < 0.02, name  # measured -0.005 m
        speed = np.linalg.norm(np.diff(corners.mean(axis=1)[:, [0, 2]], axis=0), axis=1) * m.fps
        stance = height[:-1] < height.min() + 0.02
        assert stance.sum() >= 0.3 * len(stance), name
        assert np.median(speed[stance]) < 0.1 * root_speed, name  # measured 0.012 m/s


def test_jump_flight_is_free_fall(deepmimic_dir: Path, real_model) -> None:
    """Both feet > 5 cm up: the centre of mass accelerates at -g. Measured -9.67 m/s² (root
    -9.84); a 5% tolerance leaves room for capture noise while a wrong scale or a wrong frame
    rate (both change the value by ≥ 25%) fails."""
    m = read_deepmimic(deepmimic_dir / "motions" / "humanoid3d_jump.txt", real_model)
    corners = foot_corners(real_model, m)
    lowest = np.stack([c[..., 1].min(axis=-1) for c in corners.values()]).min(axis=0)
    air = np.flatnonzero(lowest > 0.05)
    assert len(air) >= 15 and np.all(np.diff(air) == 1)  # one flight of ≥ 0.25 s
    inner = air[1:-1]
    com_y = centre_of_mass(real_model, m)[:, 1]
    acc = (com_y[inner + 1] - 2 * com_y[inner] + com_y[inner - 1]) * m.fps ** 2
    assert acc.mean() == pytest.approx(-G, rel=0.05)
    root_y = m.root_positions[:, 1]
    root_acc = (root_y[inner + 1] - 2 * root_y[inner] + root_y[inner - 1]) * m.fps ** 2
    assert root_acc.mean() == pytest.approx(-G, rel=0.05)


def test_real_clip_bvh_round_trip(deepmimic_dir: Path, real_model, tmp_path: Path) -> None:
    for clip in ("humanoid3d_jump.txt", "humanoid3d_backflip.txt"):
        m = read_deepmimic(deepmimic_dir / "motions" / clip, real_model)
        _assert_bvh_round_trip(m, tmp_path / (clip + ".bvh"))
