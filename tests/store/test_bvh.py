"""BVH reader/writer: real-file quirks, round trips and one test per kind of bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from motionweb.store.bvh import format_bvh, parse_bvh, read_bvh, write_bvh
from motionweb.store.errors import (
    EmptyMotionError,
    FrameValueError,
    MissingSectionError,
    MotionFormatError,
    TruncatedFileError,
    UnknownChannelError,
)
from motionweb.store.kinematics import forward_kinematics, quat_from_euler

# Mixed rotation orders per joint (as CMU files have), 6 channels on a non-root joint, a joint
# with no channels, "end site" in lower case, tabs, blank lines and a 1/60 s frame time.
QUIRKY = """HIERARCHY
ROOT Hips
{
\tOFFSET 0.0 0.0 0.0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation

\tJOINT Chest
\t{
\t\tOFFSET 0 10 0
\t\tCHANNELS 3 Xrotation Zrotation Yrotation
\t\tJOINT Head
\t\t{
\t\t\tOFFSET 0 5 0
\t\t\tend site
\t\t\t{
\t\t\t\tOFFSET 0 3 0
\t\t\t}
\t\t}
\t}
\tJOINT Tail
\t{
\t\tOFFSET 0 -2 -1
\t\tCHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
\t\tEND SITE
\t\t{
\t\t\tOFFSET 0 0 -4
\t\t}
\t}
}
MOTION
Frames: 3
Frame Time: 0.0166667

1.0 2.0 3.0 10.0 20.0 30.0 5.0 -5.0 15.0 0.0 -2.0 -1.0 0.0 0.0 0.0
\t1.5 2.0 3.0 190.0 -20.0 30.0 5.0 -5.0 15.0 0.1 -2.0 -1.0 0.0 90.0 0.0

2.0 2.0 3.0 10.0 20.0 170.0 5.0 -5.0 15.0 0.2 -2.0 -1.0 45.0 0.0 0.0
"""


def test_quirky_file_parses(tmp_path: Path) -> None:
    path = tmp_path / "quirky.bvh"
    path.write_bytes(QUIRKY.replace("\n", "\r\n").encode())
    m = read_bvh(path, unit="cm")
    assert m.skeleton.names == ("Hips", "Chest", "Head", "Tail")
    assert [m.skeleton.rotation_order(j) for j in range(4)] == ["ZYX", "XZY", "", "YXZ"]
    assert m.skeleton.channels[2] == ()
    assert set(m.skeleton.end_sites) == {2, 3}
    assert m.fps == pytest.approx(60.0, rel=1e-4)
    assert m.n_frames == 3 and m.scale_to_m == 0.01
    np.testing.assert_allclose(m.root_positions[:, 0], [1.0, 1.5, 2.0])
    np.testing.assert_allclose(m.translations[3][:, 0], [0.0, 0.1, 0.2])
    # the chest rotation is Rx(5) Rz(-5) Ry(15) in that intrinsic order
    expect = quat_from_euler(np.array([5.0, -5.0, 15.0]), "XZY")
    assert abs(abs(np.dot(m.rotations[0, 1], expect)) - 1) < 1e-12
    assert len(m.content_hash) == 64


def test_own_files_round_trip_exactly(tmp_path: Path) -> None:
    m = parse_bvh(QUIRKY)
    first = format_bvh(m)
    again = parse_bvh(first)
    assert format_bvh(again) == first
    write_bvh(again, tmp_path / "a.bvh")
    assert (tmp_path / "a.bvh").read_text() == first


def test_round_trip_preserves_positions_of_wrapped_angles() -> None:
    m = parse_bvh(QUIRKY)
    m2 = parse_bvh(format_bvh(m))
    p1, _ = forward_kinematics(m)
    p2, _ = forward_kinematics(m2)
    np.testing.assert_allclose(p1, p2, atol=1e-4)
    assert np.all(np.abs(np.abs(np.sum(m.rotations * m2.rotations, -1)) - 1) < 1e-9)


def test_fk_of_quirky_file_by_hand() -> None:
    m = parse_bvh(QUIRKY)
    pos, _ = forward_kinematics(m)
    # frame 2: root at (1.5,2,3) with root rotation Rz(190) Ry(-20) Rx(30); the tail's own
    # position channels (0.1,-2,-1) replace its offset
    from scipy.spatial.transform import Rotation

    r = Rotation.from_euler("ZYX", [190.0, -20.0, 30.0], degrees=True)
    np.testing.assert_allclose(pos[1, 3], np.array([1.5, 2.0, 3.0]) + r.apply([0.1, -2.0, -1.0]), atol=1e-9)


def _bad(text: str, tmp_path: Path) -> MotionFormatError:
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(MotionFormatError) as info:
        read_bvh(path)
    assert "bad.bvh" in str(info.value)
    return info.value


def _line_of(text: str, needle: str) -> int:
    return next(i + 1 for i, line in enumerate(text.splitlines()) if needle in line)


def test_truncated_frames(tmp_path: Path) -> None:
    text = QUIRKY.rsplit("\n", 2)[0] + "\n"
    err = _bad(text, tmp_path)
    assert isinstance(err, TruncatedFileError) and "2 of the 3" in str(err)


def test_truncated_header(tmp_path: Path) -> None:
    text = QUIRKY[: QUIRKY.index("JOINT Tail")]
    err = _bad(text, tmp_path)
    assert isinstance(err, MissingSectionError | TruncatedFileError)


def test_wrong_value_count_names_the_line(tmp_path: Path) -> None:
    text = QUIRKY.replace("2.0 2.0 3.0 10.0 20.0 170.0", "2.0 2.0 10.0 20.0 170.0")
    err = _bad(text, tmp_path)
    assert isinstance(err, FrameValueError)
    assert err.line == _line_of(text, "2.0 2.0 10.0 20.0 170.0")
    assert "14 values, expected 15" in str(err)


@pytest.mark.parametrize("value", ["abc", "nan", "inf", "-Infinity"])
def test_non_numeric_or_non_finite_value(tmp_path: Path, value: str) -> None:
    text = QUIRKY.replace("190.0", value)
    err = _bad(text, tmp_path)
    assert isinstance(err, FrameValueError)
    assert err.line == _line_of(text, f"1.5 2.0 3.0 {value}")


def test_missing_sections(tmp_path: Path) -> None:
    assert isinstance(_bad(QUIRKY.replace("MOTION", "MOTIONS"), tmp_path), MissingSectionError)
    err = _bad(QUIRKY.replace("HIERARCHY", ""), tmp_path)
    assert isinstance(err, MissingSectionError) and "HIERARCHY" in str(err)


def test_zero_frames(tmp_path: Path) -> None:
    text = QUIRKY.split("Frames:")[0] + "Frames: 0\nFrame Time: 0.0166667\n"
    assert isinstance(_bad(text, tmp_path), EmptyMotionError)


def test_unknown_channel_names_its_line(tmp_path: Path) -> None:
    text = QUIRKY.replace("Xrotation Zrotation Yrotation", "Xrotation Zrotation Wrotation")
    err = _bad(text, tmp_path)
    assert isinstance(err, UnknownChannelError)
    assert err.line == _line_of(text, "Wrotation") and "Wrotation" in str(err)


def test_more_frames_than_declared(tmp_path: Path) -> None:
    err = _bad(QUIRKY.replace("Frames: 3", "Frames: 2"), tmp_path)
    assert isinstance(err, FrameValueError) and "more frame lines" in str(err)


def test_compiled_frame_parser_matches_python_float() -> None:
    """The numba MOTION parser against Python's float() (the slow, obviously correct reference)."""
    from motionweb.store.bvh import _POW10, _parse_frames

    rng = np.random.default_rng(3)
    values = np.concatenate([
        rng.normal(scale=100.0, size=300),
        rng.normal(scale=1e-3, size=100),
        np.array([0.0, -0.0, 1e-30, 123456789012345678.0, 5e20, -7.25e-7, 1.0, 1e22, 1e23]),
    ])
    tokens = [f"{v:.6f}" for v in values[:200]] + [repr(float(v)) for v in values[200:]]
    tokens += ["+3", ".5", "-.25", "7.", "1E3", "2.5e-3"]
    n_cols = 4
    tokens += ["0"] * (-len(tokens) % n_cols)
    text = "\n".join("\t ".join(tokens[i:i + n_cols]) for i in range(0, len(tokens), n_cols)) + "\r\n"
    rows = len(tokens) // n_cols
    out = np.empty((rows, n_cols))
    status, _, parsed = _parse_frames(np.frombuffer(text.encode(), np.uint8), rows, n_cols, out, _POW10)
    assert (status, parsed) == (0, rows)
    expect = np.array([float(t) for t in tokens]).reshape(rows, n_cols)
    # correctly rounded (bit-identical to strtod) up to 15 significant digits, as printed BVH has
    short = np.array([len(t.lstrip("+-").replace(".", "").lstrip("0")) <= 15 and "e" not in t.lower()
                      for t in tokens]).reshape(rows, n_cols)
    assert short.sum() > 200
    np.testing.assert_array_equal(out[short], expect[short])
    np.testing.assert_allclose(out, expect, rtol=4e-16)
