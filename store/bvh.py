"""BVH reader and writer (design §2).

The reader accepts what real files contain: any rotation order per joint, 0, 3 or 6 channels on
any joint (position channels on a non-root joint replace its offset), ``End Site`` in any case,
CRLF, tabs, blank lines and any frame time. The MOTION block is parsed in bulk by numpy; a bad
block is then scanned line by line only to name the faulty line. Every fault raises a
:class:`~store.errors.MotionFormatError` subclass naming the file and line.
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from motionweb.store.errors import (
    EmptyMotionError,
    FrameValueError,
    MissingSectionError,
    SyntaxFormatError,
    TruncatedFileError,
    UnknownChannelError,
)
from motionweb.store.kinematics import quat_from_euler, quat_identity, quat_to_euler
from motionweb.store.motion import POSITION_CHANNELS, ROTATION_CHANNELS, Motion, Skeleton
from numba import njit

_CHANNELS = {c.lower(): c for c in POSITION_CHANNELS + ROTATION_CHANNELS}


@dataclass
class _Joint:
    name: str
    parent: int
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))
    channels: tuple[str, ...] = ()
    end_site: np.ndarray | None = None


class _Tokens:
    """Header tokens with their 1-based line numbers."""

    def __init__(self, lines: list[str], path: str | None):
        self.items = [(tok, i + 1) for i, line in enumerate(lines) for tok in line.split()]
        self.pos = 0
        self.path = path
        self.last_line = len(lines)

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None

    def line(self) -> int:
        return self.items[self.pos][1] if self.pos < len(self.items) else self.last_line

    def next(self, what: str) -> str:
        if self.pos >= len(self.items):
            raise TruncatedFileError(self.path, self.last_line, f"file ends inside the HIERARCHY; expected {what}")
        tok = self.items[self.pos][0]
        self.pos += 1
        return tok

    def expect(self, word: str) -> None:
        line = self.line()
        tok = self.next(repr(word))
        if tok.lower() != word.lower():
            raise SyntaxFormatError(self.path, line, f"expected {word!r}, found {tok!r}")

    def number(self, what: str) -> float:
        line = self.line()
        tok = self.next(what)
        try:
            value = float(tok)
        except ValueError:
            raise SyntaxFormatError(self.path, line, f"expected a number for {what}, found {tok!r}") from None
        if not np.isfinite(value):
            raise FrameValueError(self.path, line, f"{what} is {tok}")
        return value


def _parse_joint(tk: _Tokens, joints: list[_Joint], parent: int) -> None:
    """Parse ``NAME { OFFSET .. CHANNELS .. children }`` after ROOT/JOINT."""
    name_line = tk.line()
    name = tk.next("a joint name")
    if name == "{":
        raise SyntaxFormatError(tk.path, name_line, "joint without a name")
    index = len(joints)
    joint = _Joint(name=name, parent=parent)
    joints.append(joint)
    tk.expect("{")
    while True:
        line = tk.line()
        tok = tk.next("'}' closing joint " + name)
        low = tok.lower()
        if low == "}":
            return
        if low == "offset":
            joint.offset = np.array([tk.number(f"OFFSET of {name}") for _ in range(3)])
        elif low == "channels":
            count = tk.number(f"CHANNELS count of {name}")
            if count != int(count) or count < 0:
                raise SyntaxFormatError(tk.path, line, f"bad channel count {count} for {name}")
            chans = []
            for _ in range(int(count)):
                cline = tk.line()
                c = tk.next(f"a channel name of {name}")
                if c.lower() not in _CHANNELS:
                    raise UnknownChannelError(tk.path, cline, f"unknown channel {c!r} on joint {name}")
                chans.append(_CHANNELS[c.lower()])
            joint.channels = tuple(chans)
        elif low == "joint":
            _parse_joint(tk, joints, index)
        elif low == "end":
            tk.expect("Site")
            tk.expect("{")
            tk.expect("OFFSET")
            joint.end_site = np.array([tk.number(f"End Site OFFSET of {name}") for _ in range(3)])
            tk.expect("}")
        else:
            raise SyntaxFormatError(tk.path, line, f"unexpected {tok!r} in joint {name}")


_POW10 = np.array([10.0**k for k in range(23)])
#: kernel status codes
_OK, _BAD_COUNT, _BAD_TOKEN, _TOO_MANY = 0, 1, 2, 3


@njit(cache=True, nogil=True)
def _parse_frames(buf, n_rows, n_cols, out, pow10):  # pragma: no cover - compiled
    """Parse whitespace-separated decimal numbers, one frame per non-blank line, into ``out``.

    Returns (status, line index of the fault within ``buf`` (0-based), rows parsed). Values are
    mantissa / 10^k with an exact integer mantissa, i.e. correctly rounded for up to 15-16
    significant digits, like strtod.
    """
    n = buf.shape[0]
    i = 0
    line = 0
    row = 0
    col = 0
    while i < n:
        c = buf[i]
        if c == 10:  # newline ends a frame line
            if col != 0:
                if col != n_cols:
                    return _BAD_COUNT, line, row
                row += 1
                col = 0
            line += 1
            i += 1
            continue
        if c == 32 or c == 9 or c == 13:
            i += 1
            continue
        if row >= n_rows:
            return _TOO_MANY, line, row
        if col >= n_cols:
            return _BAD_COUNT, line, row
        neg = False
        if c == 45 or c == 43:
            neg = c == 45
            i += 1
        mant = 0
        exp = 0
        digits = 0
        seen = False
        while i < n and 48 <= buf[i] <= 57:
            if digits < 18:
                mant = mant * 10 + (buf[i] - 48)
                if mant:
                    digits += 1
            else:
                exp += 1
            seen = True
            i += 1
        if i < n and buf[i] == 46:
            i += 1
            while i < n and 48 <= buf[i] <= 57:
                if digits < 18:
                    mant = mant * 10 + (buf[i] - 48)
                    exp -= 1
                    if mant:
                        digits += 1
                seen = True
                i += 1
        if seen and i < n and (buf[i] == 101 or buf[i] == 69):
            i += 1
            eneg = False
            if i < n and (buf[i] == 45 or buf[i] == 43):
                eneg = buf[i] == 45
                i += 1
            e = 0
            eseen = False
            while i < n and 48 <= buf[i] <= 57:
                e = min(e * 10 + (buf[i] - 48), 100000)
                eseen = True
                i += 1
            if not eseen:
                return _BAD_TOKEN, line, row
            exp += -e if eneg else e
        if not seen or (i < n and not (buf[i] == 32 or buf[i] == 9 or buf[i] == 13 or buf[i] == 10)):
            return _BAD_TOKEN, line, row
        v = float(mant)
        if 0 <= exp <= 22:
            v = v * pow10[exp]
        elif -22 <= exp < 0:
            v = v / pow10[-exp]
        else:
            v = v * 10.0**exp
        out[row, col] = -v if neg else v
        col += 1
    if col != 0:
        if col != n_cols:
            return _BAD_COUNT, line, row
        row += 1
    return _OK, line, row


def _find(lines: list[str], word: str, start: int = 0) -> int:
    for i in range(start, len(lines)):
        s = lines[i].strip()
        if s.split(None, 1)[:1] == [word] or s.upper() == word:
            return i
    return -1


def _header_value(lines: list[str], i: int, key: str, path: str | None) -> tuple[str, int]:
    """The value after ``key`` ('Frames:' / 'Frame Time:') on line i (skipping blank lines)."""
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines):
        raise TruncatedFileError(path, len(lines), f"file ends before '{key}'")
    s = lines[i].strip()
    if not s.lower().startswith(key.lower()):
        raise SyntaxFormatError(path, i + 1, f"expected '{key}', found {s[:40]!r}")
    return s[len(key):].strip(), i


_NON_FINITE = ("nan", "inf", "infinity")


def _is_number(token: str) -> bool:
    try:
        return bool(np.isfinite(float(token)))
    except ValueError:
        return False


def parse_bvh(text: str, path: str | None = None, *, unit: str | None = None,
              scale_to_m: float | None = None, name: str | None = None, content_hash: str = "") -> Motion:
    """Parse BVH text into a :class:`Motion`.

    ``unit``/``scale_to_m`` come from the caller (BVH declares no unit). Cost: O(file size).
    """
    lines = text.splitlines()
    h = _find(lines, "HIERARCHY")
    if h < 0:
        raise MissingSectionError(path, 1, "no HIERARCHY section")
    m = _find(lines, "MOTION", h + 1)
    if m < 0:
        raise MissingSectionError(path, len(lines), "no MOTION section")
    tk = _Tokens(lines[: m], path)
    tk.pos = sum(len(line.split()) for line in lines[: h + 1])
    joints: list[_Joint] = []
    root_line = tk.line()
    if (tok := tk.next("ROOT")).upper() != "ROOT":
        raise SyntaxFormatError(path, root_line, f"expected ROOT, found {tok!r}")
    _parse_joint(tk, joints, -1)
    if tk.peek() is not None:
        raise SyntaxFormatError(path, tk.line(), f"unexpected {tk.peek()!r} after the hierarchy")

    frames_text, i = _header_value(lines, m + 1, "Frames:", path)
    try:
        n_frames = int(frames_text)
    except ValueError:
        raise SyntaxFormatError(path, i + 1, f"bad frame count {frames_text!r}") from None
    ft_text, i = _header_value(lines, i + 1, "Frame Time:", path)
    try:
        frame_time = float(ft_text)
    except ValueError:
        raise SyntaxFormatError(path, i + 1, f"bad frame time {ft_text!r}") from None
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise FrameValueError(path, i + 1, f"frame time must be positive, got {ft_text}")
    if n_frames <= 0:
        raise EmptyMotionError(path, i, f"the file declares {n_frames} frames")

    first = i + 1  # 0-based index of the first frame line
    n_cols = sum(len(j.channels) for j in joints)
    if n_cols == 0:
        raise SyntaxFormatError(path, h + 1, "the hierarchy declares no channels")
    block = "\n".join(lines[first:]).encode("ascii", errors="replace")
    data = np.empty((n_frames, n_cols))
    status, fault, rows = _parse_frames(np.frombuffer(block, dtype=np.uint8), n_frames, n_cols, data, _POW10)
    line_no = first + 1 + int(fault)
    if status == _BAD_COUNT:
        count = len(lines[line_no - 1].split())
        raise FrameValueError(path, line_no, f"frame line has {count} values, expected {n_cols}")
    if status == _BAD_TOKEN:
        bad = next((t for t in lines[line_no - 1].split() if not _is_number(t)), "?")
        what = "a value that is not finite" if bad.lower().lstrip("+-") in _NON_FINITE else "non-numeric value"
        raise FrameValueError(path, line_no, f"{what} {bad!r}")
    if status == _TOO_MANY:
        raise FrameValueError(path, line_no, f"more frame lines than the {n_frames} declared")
    if rows < n_frames:
        raise TruncatedFileError(path, len(lines), f"file ends after {rows} of the {n_frames} declared frames")
    return _to_motion(joints, data, frame_rate(frame_time), path, unit, scale_to_m, name, content_hash)


def frame_rate(frame_time: float) -> float:
    """Frames per second for a printed frame time; snapped to the nearest integer rate when the
    frame time is that rate printed to a few digits (CMU's 0.008333 s means 120 fps)."""
    fps = 1.0 / frame_time
    return float(round(fps)) if abs(fps - round(fps)) < 1e-4 * fps else fps


def _to_motion(joints: list[_Joint], data: np.ndarray, fps: float, path: str | None, unit: str | None,
               scale_to_m: float | None, name: str | None, content_hash: str) -> Motion:
    skeleton = Skeleton(
        names=tuple(j.name for j in joints),
        parents=np.array([j.parent for j in joints]),
        offsets=np.stack([j.offset for j in joints]),
        channels=tuple(j.channels for j in joints),
        end_sites={k: j.end_site for k, j in enumerate(joints) if j.end_site is not None},
    )
    n_frames = data.shape[0]
    rotations = quat_identity((n_frames, len(joints)))
    root = np.broadcast_to(joints[0].offset, (n_frames, 3)).copy()
    translations: dict[int, np.ndarray] = {}
    by_order: dict[str, list[tuple[int, list[int]]]] = {}
    col = 0
    for k, j in enumerate(joints):
        cols = {c: col + n for n, c in enumerate(j.channels)}
        col += len(j.channels)
        pos = [c for c in j.channels if c in POSITION_CHANNELS]
        if pos:
            t = root if k == 0 else np.broadcast_to(j.offset, (n_frames, 3)).copy()
            for c in pos:
                t[:, "XYZ".index(c[0])] = data[:, cols[c]]
            if k:
                translations[k] = t
        rot = [c for c in j.channels if c in ROTATION_CHANNELS]
        if rot:
            by_order.setdefault("".join(c[0] for c in rot), []).append((k, [cols[c] for c in rot]))
    for order, members in by_order.items():
        idx = [k for k, _ in members]
        angles = data[:, np.array([c for _, c in members])]  # (F, G, len(order))
        rotations[:, idx] = quat_from_euler(angles, order)
    return Motion(
        skeleton=skeleton,
        fps=fps,
        root_positions=root,
        rotations=rotations,
        name=name if name is not None else (Path(path).stem if path else "motion"),
        source=path,
        content_hash=content_hash,
        unit=unit,
        scale_to_m=scale_to_m,
        translations=translations,
    )


def read_bvh(path: str | Path, *, unit: str | None = None, scale_to_m: float | None = None) -> Motion:
    """Read a BVH file (any newline convention). See :func:`parse_bvh`."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise MissingSectionError(str(path), None, f"cannot read file: {exc.strerror}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return parse_bvh(text, str(path), unit=unit, scale_to_m=scale_to_m,
                     content_hash=hashlib.sha256(raw).hexdigest())


def _channel_values(motion: Motion, order: list[int] | None = None) -> np.ndarray:
    """(F, C) channel values of every joint in file order (``order``: the joints as the hierarchy
    is written, depth first; the skeleton's index order need not be depth first)."""
    sk = motion.skeleton
    f = motion.n_frames
    cols: list[np.ndarray] = []
    for k in (range(sk.n_joints) if order is None else order):
        chans = sk.channels[k]
        if not chans:
            continue
        values = {}
        if sk.has_position(k):
            t = motion.root_positions if k == 0 else motion.translations.get(k, np.broadcast_to(sk.offsets[k], (f, 3)))
            for a, c in enumerate(POSITION_CHANNELS):
                values[c] = t[:, a]
        order = sk.rotation_order(k)
        if order:
            q = motion.rotations[:, k]
            if len(order) == 3:
                angles = quat_to_euler(q, order)
            elif len(order) == 1:
                a = "XYZ".index(order)
                angles = np.rad2deg(2.0 * np.arctan2(q[:, 1 + a], q[:, 0]))[:, None]
            else:
                raise ValueError(f"cannot write joint {sk.names[k]} with rotation channels {order}")
            for a, axis in enumerate(order):
                values[axis + "rotation"] = angles[:, a]
        cols.extend(values[c] for c in chans)
    return np.stack(cols, axis=1)


def format_bvh(motion: Motion, decimals: int = 6) -> str:
    """BVH text for a motion: the hierarchy with tab indentation, then one line per frame."""
    sk = motion.skeleton
    out: list[str] = ["HIERARCHY"]
    num = f"{{:.{decimals}f}}"

    def vec(v: np.ndarray) -> str:
        return " ".join(num.format(x) for x in v)

    written: list[int] = []

    def joint(k: int, depth: int) -> None:
        written.append(k)
        ind = "\t" * depth
        out.append(f"{ind}{'ROOT' if k == 0 else 'JOINT'} {sk.names[k]}")
        out.append(ind + "{")
        out.append(f"{ind}\tOFFSET {vec(sk.offsets[k])}")
        if sk.channels[k]:
            out.append(f"{ind}\tCHANNELS {len(sk.channels[k])} {' '.join(sk.channels[k])}")
        for c in sk.children(k):
            joint(c, depth + 1)
        if k in sk.end_sites:
            out.append(f"{ind}\tEnd Site")
            out.append(ind + "\t{")
            out.append(f"{ind}\t\tOFFSET {vec(sk.end_sites[k])}")
            out.append(ind + "\t}")
        out.append(ind + "}")

    joint(0, 0)
    out.append("MOTION")
    out.append(f"Frames: {motion.n_frames}")
    out.append(f"Frame Time: {1.0 / motion.fps:.10g}")
    buf = io.StringIO()
    np.savetxt(buf, _channel_values(motion, written), fmt=f"%.{decimals}f", delimiter=" ")
    # "-0.000000" and "0.000000" are the same value; print one spelling so round trips are exact.
    body = buf.getvalue().replace("-" + num.format(0.0), num.format(0.0))
    return "\n".join(out) + "\n" + body


def write_bvh(motion: Motion, path: str | Path, decimals: int = 6) -> None:
    """Write a motion as BVH (LF newlines)."""
    Path(path).write_text(format_bvh(motion, decimals))

