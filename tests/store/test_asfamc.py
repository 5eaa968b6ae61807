"""ASF/AMC reader: hand-made files (not from CMU), FK against hand and matrix computations, BVH
round trip, and one test per malformed input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fixtures import CHAIN_AMC, CHAIN_ASF
from motionweb.store.asfamc import (
    CMU_FPS,
    amc_values_by_lines,
    amc_values_regular,
    read_amc,
    read_asf,
    read_asfamc,
)
from motionweb.store.bvh import read_bvh, write_bvh
from motionweb.store.errors import (
    EmptyMotionError,
    FrameValueError,
    MissingSectionError,
    MotionFormatError,
    TruncatedFileError,
    UnknownJointError,
)
from motionweb.store.kinematics import end_site_positions, forward_kinematics


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_chain_fk_matches_hand_computation(tmp_path: Path) -> None:
    asf = _write(tmp_path, "arm.asf", CHAIN_ASF)
    amc = _write(tmp_path, "arm_01.amc", CHAIN_AMC)
    m = read_asfamc(asf, amc)
    assert m.skeleton.names == ("root", "upper", "lower")
    assert m.skeleton.parents.tolist() == [-1, 0, 1]
    np.testing.assert_allclose(m.skeleton.offsets, [[0, 0, 0], [0, 0, 0], [2, 0, 0]])
    np.testing.assert_allclose(m.skeleton.end_sites[2], [0, 3, 0])
    assert m.skeleton.channels[0][:3] == ("Xposition", "Yposition", "Zposition")
    assert m.skeleton.channels[1] == ("Zrotation", "Yrotation", "Xrotation")
    assert m.n_frames == 2 and m.fps == CMU_FPS
    pos, rot = forward_kinematics(m)
    ends = end_site_positions(m, pos, rot)
    # Frame 1: upper = Rz(90) Rx(90) Rz(-90) = Ry(90) (x -> -z); lower = Rx(90) (y -> z).
    np.testing.assert_allclose(pos[0], [[1, 2, 3], [1, 2, 3], [1, 2, 1]], atol=1e-12)
    np.testing.assert_allclose(ends[0, 0], [4, 2, 1], atol=1e-12)
    # Frame 2: upper = Rz(90) (commutes with C), lower at rest.
    np.testing.assert_allclose(pos[1, 2], [1, 4, 3], atol=1e-12)
    np.testing.assert_allclose(ends[1, 0], [-2, 4, 3], atol=1e-12)


RICH_ASF = """\
:version 1.10
:name rich
:units
  mass 1.0
  length 1.0
  angle deg
:root
  order TX TY TZ RX RY RZ
  axis XYZ
  position 0 0 0
  orientation 0 0 0
:bonedata
  begin
     id 1
     name upper
     direction 1 0 0
     length 2
     axis 0 0 90 XYZ
     dof rx ry rz
  end
  begin
     id 2
     name lower
     direction 0 0.6 0.8
     length 3
     axis 10 20 30 XYZ
     dof rx
     limits (-10 170)
  end
  begin
     id 3
     name side
     direction 0 -1 0
     length 1.5
     axis -30 45 0 ZYX
     dof rz ry
     limits (-90 90) (-45 45)
  end
  begin
     id 4
     name slide
     direction 1 1 0
     length 1
     axis 0 30 0 XYZ
     dof tx ty tz rx
  end
  begin
     id 5
     name stub
     direction 0 0 1
     length 1
     axis 0 0 0 XYZ
     bodymass 1.0
  end
:hierarchy
  begin
    root upper side stub
    upper lower
    side slide
  end
"""


def _rich_amc(n: int = 6) -> tuple[str, np.ndarray]:
    rng = np.random.default_rng(3)
    vals = rng.uniform(-80, 80, (n, 13))
    vals[:, :3] = rng.uniform(-5, 5, (n, 3))
    vals[:, 10:13] = rng.uniform(-0.5, 0.5, (n, 3))
    lines = [":FULLY-SPECIFIED", ":DEGREES"]
    for f in range(n):
        v = vals[f]
        lines += [str(f + 1), "root " + " ".join(f"{x:.6f}" for x in v[:6]),
                  "upper " + " ".join(f"{x:.6f}" for x in v[6:9]), f"lower {v[9]:.6f}",
                  f"side {v[3]:.6f} {v[4]:.6f}", "slide " + " ".join(f"{x:.6f}" for x in v[10:13]) + f" {v[5]:.6f}"]
    return "\n".join(lines) + "\n", np.round(vals, 6)


def test_rich_skeleton_fk_matches_matrix_reference(tmp_path: Path) -> None:
    """Independent check with rotation matrices: global = parent · C M C⁻¹, M = R_last … R_first."""
    text, vals = _rich_amc()
    m = read_asfamc(_write(tmp_path, "rich.asf", RICH_ASF), _write(tmp_path, "rich_01.amc", text))
    pos, _ = forward_kinematics(m)
    d = np.deg2rad
    r = {"x": _rx, "y": _ry, "z": _rz}
    c_upper = _rz(d(90))
    c_lower = _rz(d(30)) @ _ry(d(20)) @ _rx(d(10))
    c_side = _rx(d(-30)) @ _ry(d(45)) @ _rz(d(0))  # order ZYX: Z first, then Y, then X
    c_slide = _ry(d(30))
    lower_dir = np.array([0, 0.6, 0.8])
    for f in range(len(vals)):
        v = vals[f]
        root_r = r["z"](d(v[5])) @ r["y"](d(v[4])) @ r["x"](d(v[3]))
        g_upper = root_r @ c_upper @ (_rz(d(v[8])) @ _ry(d(v[7])) @ _rx(d(v[6]))) @ c_upper.T
        p_lower = v[:3] + g_upper @ np.array([2.0, 0, 0])
        g_side = root_r @ c_side @ (_ry(d(v[4])) @ _rz(d(v[3]))) @ c_side.T
        p_slide = v[:3] + g_side @ (np.array([0, -1.5, 0]) + c_slide @ v[10:13])
        np.testing.assert_allclose(pos[f, m.skeleton.index("lower")], p_lower, atol=1e-9)
        np.testing.assert_allclose(pos[f, m.skeleton.index("slide")], p_slide, atol=1e-9)
        g_lower = g_upper @ c_lower @ _rx(d(v[9])) @ c_lower.T
        ends = end_site_positions(m, *forward_kinematics(m))
        keys = sorted(m.skeleton.end_sites)
        np.testing.assert_allclose(ends[f, keys.index(m.skeleton.index("lower"))],
                                   p_lower + g_lower @ (3 * lower_dir), atol=1e-9)


def test_asf_metadata(tmp_path: Path) -> None:
    asf = read_asf(_write(tmp_path, "rich.asf", RICH_ASF))
    assert asf.name == "rich" and asf.version == "1.10" and asf.angle_unit == "deg"
    side = asf.bones["side"]
    assert side.dof == ("rz", "ry") and side.axis_order == "ZYX" and side.id == 3
    np.testing.assert_allclose(side.limits, np.deg2rad([[-90, 90], [-45, 45]]))
    np.testing.assert_allclose(asf.bones["lower"].direction, [0, 0.6, 0.8])
    assert np.all(np.isinf(asf.bones["upper"].limits))  # no limits given
    assert asf.hierarchy["root"] == ("upper", "side", "stub")
    sk = asf.skeleton
    assert sk.names == ("root", "upper", "lower", "side", "slide", "stub")
    assert sk.channels[sk.index("stub")] == ()  # no dof: not listed in the AMC either
    np.testing.assert_allclose(sk.end_sites[sk.index("stub")], [0, 0, 1])
    assert sk.channels[sk.index("side")] == ("Yrotation", "Zrotation", "Xrotation")
    assert sk.channels[sk.index("slide")] == ("Xposition", "Yposition", "Zposition",
                                              "Xrotation", "Yrotation", "Zrotation")
    np.testing.assert_allclose(sk.offsets[sk.index("slide")], [0, -1.5, 0])
    np.testing.assert_allclose(sk.end_sites[sk.index("slide")], np.array([1, 1, 0]) / np.sqrt(2))
    assert asf.documentation == ""


def test_units_scale(tmp_path: Path) -> None:
    sk = read_asf(_write(tmp_path, "arm.asf", CHAIN_ASF))
    assert sk.documentation.startswith("upper points along +X")
    assert sk.length_multiplier == 0.5
    assert sk.scale_to_m == pytest.approx(0.0254 / 0.5)
    m = read_asfamc(tmp_path / "arm.asf", _write(tmp_path, "arm_01.amc", CHAIN_AMC), fps=60)
    assert m.unit == "in/0.5" and m.scale_to_m == pytest.approx(0.0508) and m.fps == 60
    assert m.metres() == pytest.approx(0.0508)
    # the CMU convention: length 0.45 -> (1 / 0.45) inches per unit
    cmu = read_asf(_write(tmp_path, "cmu.asf", CHAIN_ASF.replace("length 0.5", "length 0.45")))
    assert cmu.scale_to_m == pytest.approx((1 / 0.45) * 0.0254)
    metric = read_asf(tmp_path / "arm.asf", length_unit="cm")
    assert metric.scale_to_m == pytest.approx(0.02)
    # radians in the ASF: limits converted, AMC stays in degrees when it says so
    rad = read_asf(_write(tmp_path, "rad.asf", CHAIN_ASF.replace("angle deg", "angle rad")
                          .replace("axis 0 0 90 XYZ", f"axis 0 0 {np.pi / 2!r} XYZ")))
    np.testing.assert_allclose(rad.rest_axes[1], read_asf(tmp_path / "arm.asf").rest_axes[1], atol=1e-12)
    m_rad = read_amc(tmp_path / "arm_01.amc", rad)
    np.testing.assert_allclose(forward_kinematics(m_rad)[0], forward_kinematics(m)[0], atol=1e-12)
    assert m.content_hash and len(m.content_hash) == 64


def test_amc_to_bvh_round_trip(tmp_path: Path) -> None:
    text, _ = _rich_amc()
    m = read_asfamc(_write(tmp_path, "rich.asf", RICH_ASF), _write(tmp_path, "rich_01.amc", text))
    out = tmp_path / "rich.bvh"
    write_bvh(m, out)
    back = read_bvh(out, scale_to_m=m.scale_to_m)
    assert back.skeleton.names == m.skeleton.names
    p0, r0 = forward_kinematics(m)
    p1, r1 = forward_kinematics(back)
    np.testing.assert_allclose(p1, p0, atol=1e-4)
    np.testing.assert_allclose(end_site_positions(back, p1, r1), end_site_positions(m, p0, r0), atol=1e-4)
    assert back.fps == pytest.approx(m.fps)
    # with a zero axis the BVH channel values are the AMC values (reverse dof order)
    chain = read_asfamc(_write(tmp_path, "arm.asf", CHAIN_ASF), _write(tmp_path, "arm_01.amc", CHAIN_AMC))
    write_bvh(chain, tmp_path / "arm.bvh")
    first = (tmp_path / "arm.bvh").read_text().splitlines()[-2].split()
    assert chain.skeleton.channels[2] == ("Xrotation", "Yrotation", "Zrotation")
    assert [float(x) for x in first[:3]] == pytest.approx([1.0, 2.0, 3.0])
    assert [float(x) for x in first[-3:]] == pytest.approx([90.0, 0.0, 0.0])


# ---- malformed input: each names the file and the faulty line -----------------------------------

def _expect(exc_type: type, path: Path, line: int, call) -> None:
    with pytest.raises(exc_type) as info:
        call()
    assert info.value.path == str(path)
    assert info.value.line == line
    assert f"{path.name}:{line}" in str(info.value)


def test_truncated_asf(tmp_path: Path) -> None:
    lines = CHAIN_ASF.splitlines()
    cut = lines.index("    length 3")  # inside the second bone block
    p = _write(tmp_path, "cut.asf", "\n".join(lines[: cut + 1]) + "\n")
    _expect(TruncatedFileError, p, cut + 1, lambda: read_asf(p))


def test_missing_hierarchy(tmp_path: Path) -> None:
    text = CHAIN_ASF[: CHAIN_ASF.index(":hierarchy")]
    p = _write(tmp_path, "nohier.asf", text)
    _expect(MissingSectionError, p, len(text.splitlines()), lambda: read_asf(p))


def test_missing_bonedata(tmp_path: Path) -> None:
    a, b = CHAIN_ASF.index(":bonedata"), CHAIN_ASF.index(":hierarchy")
    text = CHAIN_ASF[:a] + CHAIN_ASF[b:]
    p = _write(tmp_path, "nobones.asf", text)
    _expect(MissingSectionError, p, len(text.splitlines()), lambda: read_asf(p))


def test_hierarchy_names_unknown_bone(tmp_path: Path) -> None:
    p = _write(tmp_path, "badhier.asf", CHAIN_ASF.replace("upper lower", "upper lower hand"))
    line = CHAIN_ASF.splitlines().index("    upper lower") + 1
    _expect(UnknownJointError, p, line, lambda: read_asf(p))


@pytest.fixture
def arm(tmp_path: Path):
    return read_asf(_write(tmp_path, "arm.asf", CHAIN_ASF))


def _amc_with(tmp_path: Path, old: str, new: str) -> tuple[Path, int]:
    """CHAIN_AMC with the first occurrence of line ``old`` replaced; returns (path, line number)."""
    lines = CHAIN_AMC.splitlines()
    k = lines.index(old)
    lines[k] = new
    return _write(tmp_path, "bad.amc", "\n".join(lines) + "\n"), k + 1


def test_amc_unknown_bone(tmp_path: Path, arm) -> None:
    p, line = _amc_with(tmp_path, "lower 0", "hand 0")
    _expect(UnknownJointError, p, line, lambda: read_amc(p, arm))


def test_amc_wrong_value_count(tmp_path: Path, arm) -> None:
    p, line = _amc_with(tmp_path, "upper 90 0 0", "upper 90 0")
    _expect(FrameValueError, p, line, lambda: read_amc(p, arm))


@pytest.mark.parametrize("bad", ["abc", "nan", "inf", "-inf"])
def test_amc_bad_number(tmp_path: Path, arm, bad: str) -> None:
    p, line = _amc_with(tmp_path, "upper 0 0 90", f"upper 0 {bad} 90")
    _expect(FrameValueError, p, line, lambda: read_amc(p, arm))


def test_amc_zero_frames(tmp_path: Path, arm) -> None:
    p = _write(tmp_path, "empty.amc", ":FULLY-SPECIFIED\n:DEGREES\n")
    _expect(EmptyMotionError, p, 2, lambda: read_amc(p, arm))


def test_amc_truncated(tmp_path: Path, arm) -> None:
    lines = CHAIN_AMC.splitlines()
    p = _write(tmp_path, "cut.amc", "\n".join(lines[:-1]) + "\n")  # last frame lacks 'lower'
    _expect(TruncatedFileError, p, len(lines) - 1, lambda: read_amc(p, arm))
    p2 = _write(tmp_path, "cut2.amc", "\n".join(lines[:-2] + ["upper 0 0"]))  # cut inside a line
    _expect(TruncatedFileError, p2, len(lines) - 1, lambda: read_amc(p2, arm))


def test_amc_frame_missing_a_bone(tmp_path: Path, arm) -> None:
    # a middle frame without a bone the first frame has: the frame-number line is reported
    lines = CHAIN_AMC.splitlines() + ["3", "root 0 0 0 0 0 0", "upper 0 0 0", "lower 0"]
    del lines[lines.index("upper 0 0 90")]
    p = _write(tmp_path, "gap.amc", "\n".join(lines) + "\n")
    _expect(FrameValueError, p, lines.index("2") + 1, lambda: read_amc(p, arm))
    # a bone listed twice in one frame
    lines = CHAIN_AMC.splitlines()
    k = lines.index("lower 90")
    lines.insert(k + 1, "lower 5")
    p = _write(tmp_path, "twice.amc", "\n".join(lines) + "\n")
    _expect(FrameValueError, p, k + 2, lambda: read_amc(p, arm))


def _same_values(a, b) -> None:
    assert a.n_frames == b.n_frames and a.degrees == b.degrees and a.values.keys() == b.values.keys()
    for k in a.values:
        assert np.array_equal(a.values[k], b.values[k]), k


# what exporters vary and the bulk reader must read exactly as the line reader does
REGULAR_VARIANTS = {
    "as written": CHAIN_AMC,
    "CRLF": CHAIN_AMC.replace("\n", "\r\n"),
    "no final newline": CHAIN_AMC.rstrip("\n"),
    "tabs and blank lines": CHAIN_AMC.replace("root 1 2", "\troot\t1  2").replace("\n2\n", "\n\n 2 \n\n"),
    "radians": CHAIN_AMC.replace(":DEGREES", ":RADIANS"),
    "byte-order mark": "\ufeff" + CHAIN_AMC,
    "exponents": CHAIN_AMC.replace("upper 90 0 0", "upper 9e1 -0.0 +0E-3"),
}


@pytest.mark.parametrize("variant", REGULAR_VARIANTS)
def test_bulk_amc_reader_equals_line_reader(arm, variant: str) -> None:
    text = REGULAR_VARIANTS[variant]
    bulk = amc_values_regular(text, arm)
    assert bulk is not None, "a regular file must take the bulk path"
    _same_values(bulk, amc_values_by_lines(text, arm))


IRREGULAR_VARIANTS = {
    "bones in another order": CHAIN_AMC.replace("root 1 2 3 0 0 0\nupper 0 0 90", "upper 0 0 90\nroot 1 2 3 0 0 0"),
    "a comment after a value": CHAIN_AMC.replace("lower 90", "lower 90 # knee"),
    "a value on the next line": CHAIN_AMC.replace("upper 90 0 0", "upper 90 0\n0"),
    "two bones on a line": CHAIN_AMC.replace("upper 0 0 90\nlower 0", "upper 0 0 90 lower 0"),
    "a form feed": CHAIN_AMC.replace("lower 0", "lower\f0"),
}


@pytest.mark.parametrize("variant", IRREGULAR_VARIANTS)
def test_bulk_amc_reader_leaves_irregular_files_to_the_line_reader(arm, variant: str) -> None:
    text = IRREGULAR_VARIANTS[variant]
    assert amc_values_regular(text, arm) is None
    try:  # whatever the line reader makes of it (a motion or a located error) is parse_amc's answer
        amc_values_by_lines(text, arm)
    except MotionFormatError as exc:
        assert exc.line is not None


@pytest.mark.parametrize("bad", ["abc", "nan", "1e999", "1_0", "1e", "1.2.3", "0x10"])
def test_bulk_amc_reader_refuses_what_the_line_reader_refuses(arm, bad: str) -> None:
    text = CHAIN_AMC.replace("upper 0 0 90", f"upper 0 {bad} 90")
    assert amc_values_regular(text, arm) is None
    with pytest.raises(FrameValueError):
        amc_values_by_lines(text, arm)


def test_bulk_amc_reader_refuses_frame_numbers_out_of_order(arm) -> None:
    assert amc_values_regular(CHAIN_AMC.replace("\n2\n", "\n3\n"), arm) is None
