"""The shared CMU files: every one loads, and the ASF/AMC and cgspeed BVH forms of one take agree.

``asf_amc/01/01_01.amc`` and ``bvh/01/01_01.bvh`` are the same take. The BVH (B. Hahne's "cgspeed"
conversion) keeps the ASF's length unit and joint order and adds one frame at the start (frame 0,
a rest pose). Measured differences of its skeleton (documented in README "Real data"):

* legs, hips and spine up to the thorax: same offsets, FK within 1e-4 file units;
* the thorax's length (2.065 units, ASF bone ``thorax``) is dropped: ``Neck`` and both
  ``*Shoulder`` joints sit at the thorax joint (offset 0) instead of one thorax length above it,
  so the neck, head, clavicles and arms are 2.065 units lower along the thorax at every frame;
* likewise each wrist's length (ASF ``lwrist`` / ``rwrist``) is dropped below ``*FingerBase``.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from motionweb.store.asfamc import amc_values_by_lines, amc_values_regular, read_asf
from motionweb.store.formats import is_clip, read_motion
from motionweb.store.kinematics import forward_kinematics, quat_rotate

LEGS_SPINE = ("root", "lhipjoint", "lfemur", "ltibia", "lfoot", "ltoes", "rhipjoint", "rfemur", "rtibia",
              "rfoot", "rtoes", "lowerback", "upperback", "thorax")
BELOW_THORAX = ("lowerneck", "upperneck", "head", "lclavicle", "lhumerus", "lradius", "lwrist",
                "rclavicle", "rhumerus", "rradius", "rwrist")


@pytest.fixture(scope="module")
def take_01_01(cmu_dir: Path):
    amc = read_motion(cmu_dir / "asf_amc/01/01_01.amc")
    bvh = read_motion(cmu_dir / "bvh/01/01_01.bvh")
    return amc, bvh


def test_every_cmu_file_loads_and_the_manifest_lists_them(cmu_dir: Path) -> None:
    files = sorted(p for p in cmu_dir.rglob("*") if p.is_file() and is_clip(p))
    with open(cmu_dir / "manifest.csv", newline="") as fh:
        listed = {row["path"] for row in csv.DictReader(fh)}
    assert {p.relative_to(cmu_dir).as_posix() for p in files} == listed
    assert {p.suffix for p in files} == {".amc", ".bvh"}
    for p in files:
        m = read_motion(p)
        pos, _ = forward_kinematics(m)
        assert m.skeleton.n_joints == 31 and m.fps == 120.0 and m.n_frames > 100, p
        assert np.isfinite(pos).all(), p
    for asf in sorted(cmu_dir.rglob("*.asf")):
        assert len(read_asf(asf).bones) == 30, asf


def test_every_cmu_amc_takes_the_bulk_reader_and_reads_as_line_by_line(cmu_dir: Path) -> None:
    for asf_path in sorted(cmu_dir.rglob("*.asf")):
        asf = read_asf(asf_path)
        for amc in sorted(asf_path.parent.glob("*.amc"))[:8]:
            text = amc.read_text()
            bulk = amc_values_regular(text, asf)
            assert bulk is not None, amc
            lines = amc_values_by_lines(text, asf, str(amc))
            assert bulk.n_frames == lines.n_frames and bulk.values.keys() == lines.values.keys(), amc
            assert all(np.array_equal(bulk.values[k], lines.values[k]) for k in bulk.values), amc


def test_bvh_is_the_amc_take_plus_a_first_frame(take_01_01) -> None:
    amc, bvh = take_01_01
    assert bvh.n_frames == amc.n_frames + 1
    pa, _ = forward_kinematics(amc)
    pb, _ = forward_kinematics(bvh)
    # frame 0 of the BVH is none of the take's frames, frame k + 1 is AMC frame k
    legs = [amc.skeleton.index(n) for n in LEGS_SPINE]
    assert np.abs(pb[1:, legs] - pa[:, legs]).max() < 1e-3
    assert np.abs(pb[0, legs] - pa[0, legs]).max() > 1.0


def test_legs_and_spine_agree_to_1e3_file_units(take_01_01) -> None:
    amc, bvh = take_01_01
    assert [n.lower() for n in bvh.skeleton.names][:2] == ["hips", "lhipjoint"]
    pa, _ = forward_kinematics(amc)
    pb, _ = forward_kinematics(bvh)
    for name in LEGS_SPINE:
        j = amc.skeleton.index(name)
        np.testing.assert_allclose(pb[1:, j], pa[:, j], atol=1e-3, rtol=0, err_msg=name)
        np.testing.assert_allclose(bvh.skeleton.offsets[j], amc.skeleton.offsets[j], atol=1e-4, err_msg=name)


def test_bvh_drops_the_thorax_length_below_neck_and_clavicles(cmu_dir: Path, take_01_01) -> None:
    amc, bvh = take_01_01
    thorax = read_asf(cmu_dir / "asf_amc/01/01.asf").bones["thorax"]
    assert thorax.length == pytest.approx(2.065, abs=1e-3)
    pa, ra = forward_kinematics(amc)
    pb, _ = forward_kinematics(bvh)
    t = amc.skeleton.index("thorax")
    for name in ("lowerneck", "lclavicle", "rclavicle"):
        j = amc.skeleton.index(name)
        assert np.allclose(bvh.skeleton.offsets[j], 0.0)  # BVH: at the thorax joint
        np.testing.assert_allclose(amc.skeleton.offsets[j], thorax.length * thorax.direction, atol=1e-4)
    # every joint below the thorax (up to the wrists) is lower by the thorax vector, turned by the
    # thorax's global rotation, at every frame: |difference| = 2.065 units
    shift = quat_rotate(ra[:, t], np.broadcast_to(thorax.length * thorax.direction, (amc.n_frames, 3)))
    for name in BELOW_THORAX:
        j = amc.skeleton.index(name)
        np.testing.assert_allclose(pa[:, j] - pb[1:, j], shift, atol=1e-3, err_msg=name)
        d = np.linalg.norm(pa[:, j] - pb[1:, j], axis=-1)
        assert np.abs(d - 2.065).max() < 2e-3, name
