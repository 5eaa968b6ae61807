"""GLB export (store/gltf.py, issue 26): joint world positions read back from the file's nodes and
samplers equal motionweb's FK within 1e-4 m at every frame; every written file passes the Khronos
glTF validator with 0 errors; the writer dispatch of store.formats picks GLB by suffix."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from fixtures import jumper_skeleton, wiggle
from gltf_check import accessor, glb_world_positions, validate
from motionweb.store.formats import read_motion, write_motion
from motionweb.store.gltf import up_to_y, write_glb
from motionweb.store.kinematics import forward_kinematics, quat_inv, quat_mul, quat_rotate
from motionweb.store.motion import Motion

TOL_M = 1e-4
#: cgspeed's CMU BVH declares no unit: it keeps the ASF's (inches / 0.45)
CGSPEED_SCALE = 0.0254 / 0.45


def check_round_trip(motion: Motion, path: Path, up: str = "y") -> float:
    """Write ``motion`` as GLB, read the joint world positions back, compare with FK (metres,
    turned to Y up); returns the worst difference (m)."""
    write_glb(motion, path, up=up)
    pos, names, times, doc = glb_world_positions(path)
    assert names == list(motion.skeleton.names)
    np.testing.assert_allclose(times, np.arange(motion.n_frames) / motion.fps, atol=1e-5)
    want = quat_rotate(up_to_y(up), forward_kinematics(motion)[0] * motion.metres())
    err = float(np.abs(pos - want).max())
    assert err < TOL_M, f"{motion.name}: worst joint error {err:.2e} m"
    # the inverse bind matrices undo the rest pose: joint positions with identity rotations
    blob = doc.binary_blob()
    ibm = accessor(doc, blob, doc.skins[0].inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    assert np.allclose(ibm[:, :3, :3], np.eye(3))
    rest = replace(motion, root_positions=motion.skeleton.offsets[:1], rotations=np.tile([1.0, 0, 0, 0], (1, len(names), 1)),
                   translations={})
    bind = quat_rotate(up_to_y(up), forward_kinematics(rest)[0][0] * motion.metres())
    np.testing.assert_allclose(-ibm[:, :3, 3], bind, atol=1e-5)
    # the figure is skinned rigidly: every vertex to one joint with weight 1
    prim = doc.meshes[0].primitives[0]
    w = accessor(doc, blob, prim.attributes.WEIGHTS_0)
    assert np.all(w[:, 0] == 1.0) and np.all(w[:, 1:] == 0.0)
    assert accessor(doc, blob, prim.attributes.JOINTS_0)[:, 0].max() < len(names)
    return err


def assert_valid(paths: list[Path]) -> None:
    for rep in validate(paths):
        assert rep["errors"] == 0, rep


def test_synthetic_round_trip_and_validator(tmp_path: Path) -> None:
    """Always runs: a 9-joint wiggle in centimetres, a jumper with end sites, a one-frame clip."""
    cm = wiggle(90, 30.0, seed=3, unit="cm")
    jump = Motion(jumper_skeleton(), 40.0, np.tile([0.0, 0.95, 0.0], (50, 1)),
                  wiggle(50, 40.0, seed=4).rotations[:, [0, 1, 3, 4, 4, 5, 6, 6]], name="jumper", unit="m")
    one = wiggle(1, 24.0, seed=5)
    paths = []
    for m in (cm, jump, one):
        p = tmp_path / f"{m.name}.glb"
        check_round_trip(m, p)
        paths.append(p)
    assert_valid(paths)


def test_z_up_motion_is_turned_to_y_up(tmp_path: Path) -> None:
    """A Y-up clip turned to Z up (x, y, z) -> (x, -z, y) and exported with up='z' gives the
    Y-up clip's world positions back."""
    m = wiggle(40, 30.0, seed=6)
    r = quat_inv(up_to_y("z"))  # Y up -> Z up
    z = replace(m, root_positions=quat_rotate(r, m.root_positions),
                skeleton=replace(m.skeleton, offsets=quat_rotate(r, m.skeleton.offsets)),
                rotations=quat_mul(quat_mul(r, m.rotations), quat_inv(r)))
    assert np.allclose(forward_kinematics(z)[0][..., 2], forward_kinematics(m)[0][..., 1])
    check_round_trip(z, tmp_path / "z.glb", up="z")
    pos = glb_world_positions(tmp_path / "z.glb")[0]
    np.testing.assert_allclose(pos, forward_kinematics(m)[0], atol=TOL_M)


def test_unknown_unit_is_a_clear_error(tmp_path: Path) -> None:
    m = replace(wiggle(5, 30.0, seed=1), unit=None, scale_to_m=None)
    with pytest.raises(ValueError, match=r"cannot write .*x\.glb: .*length unit"):
        write_glb(m, tmp_path / "x.glb")


def test_write_motion_dispatches_on_suffix_and_format(tmp_path: Path) -> None:
    m = wiggle(20, 30.0, seed=2)
    write_motion(m, tmp_path / "a.glb")
    write_motion(m, tmp_path / "b.bvh")
    write_motion(m, tmp_path / "c.out", fmt="glb")
    assert (tmp_path / "a.glb").read_bytes()[:4] == b"glTF"
    assert (tmp_path / "c.out").read_bytes()[:4] == b"glTF"
    assert (tmp_path / "b.bvh").read_text().startswith("HIERARCHY")
    back = read_motion(tmp_path / "b.bvh", unit="m")
    order = [back.skeleton.index(n) for n in m.skeleton.names]
    np.testing.assert_allclose(forward_kinematics(back)[0][:, order], forward_kinematics(m)[0], atol=1e-4)
    with pytest.raises(ValueError, match=r"x\.obj.*bvh, glb, fbx"):
        write_motion(m, tmp_path / "x.obj")
    with pytest.raises(ValueError, match="unknown motion format 'obj'"):
        write_motion(m, tmp_path / "x.glb", fmt="obj")


@pytest.mark.slow
def test_real_clips_round_trip_and_validate(cmu_dir: Path, deepmimic_dir: Path, tmp_path: Path) -> None:
    """BVH (cgspeed 01_01), ASF/AMC (16_15 walk, 01_01 jumps) and DeepMimic (walk, backflip)."""
    clips = [read_motion(cmu_dir / "bvh" / "01" / "01_01.bvh", scale_to_m=CGSPEED_SCALE),
             read_motion(cmu_dir / "asf_amc" / "16" / "16_15.amc"),
             read_motion(cmu_dir / "asf_amc" / "01" / "01_01.amc"),
             read_motion(deepmimic_dir / "motions" / "humanoid3d_walk.txt"),
             read_motion(deepmimic_dir / "motions" / "humanoid3d_backflip.txt")]
    paths = []
    for k, m in enumerate(clips):
        p = tmp_path / f"{k}_{m.name}.glb"
        check_round_trip(m, p)
        paths.append(p)
    assert_valid(paths)
