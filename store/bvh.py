"""BVH reader and writer (design §2).

The reader accepts what real files contain: any rotation order per joint, 0, 3 or 6 channels on
any joint (position channels on a non-root joint replace its offset), ``End Site`` in any case,
CRLF, tabs, blank lines and any frame time. The MOTION block is parsed in bulk by numpy; a bad
block is then scanned line by line only to name the faulty line. Every fault raises a
:class:`~store.errors.MotionFormatError` subclass naming the file and line.
"""

from __future__ import annotations

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
from motionweb.store.textfile import decode, number, read_bytes, text_lines
from motionweb.store.numba_cache import njit

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
        value = number(tok)
        if value is None:
            if _is_float(tok):
                raise FrameValueError(self.path, line, f"{what} is {tok}, not a finite number")
            raise SyntaxFormatError(self.path, line, f"expected a number for {what}, found {tok!r}")
        return value


def _parse_hierarchy(tk: _Tokens) -> list[_Joint]:
    """Parse ``ROOT NAME { OFFSET .. CHANNELS .. JOINT .. End Site .. }`` with an explicit stack
    (no recursion: the nesting depth is bounded by the file, not by Python)."""
    joints: list[_Joint] = []
    open_lines: list[int] = []  # line of each joint still open, innermost last
    stack: list[int] = []  # indices of the open joints
    offset_seen: list[bool] = []

    def begin(parent: int) -> None:
        name_line = tk.line()
        name = tk.next("a joint name")
        if name == "{":
            raise SyntaxFormatError(tk.path, name_line, "joint without a name")
        joints.append(_Joint(name=name, parent=parent))
        offset_seen.append(False)
        tk.expect("{")
        stack.append(len(joints) - 1)
        open_lines.append(name_line)

    begin(-1)
    while stack:
        joint = joints[stack[-1]]
        name = joint.name
        line = tk.line()
        tok = tk.next("'}' closing joint " + name)
        low = tok.lower()
        if low == "}":
            if not offset_seen[stack[-1]]:
                raise SyntaxFormatError(tk.path, open_lines[-1], f"joint {name} has no OFFSET")
            stack.pop()
            open_lines.pop()
        elif low == "offset":
            if offset_seen[stack[-1]]:
                raise SyntaxFormatError(tk.path, line, f"joint {name} has a second OFFSET")
            offset_seen[stack[-1]] = True
            joint.offset = np.array([tk.number(f"OFFSET of {name}") for _ in range(3)])
        elif low == "channels":
            if joint.channels:
                raise SyntaxFormatError(tk.path, line, f"joint {name} has a second CHANNELS line")
            count_tok = tk.next(f"CHANNELS count of {name}")
            if not count_tok.isascii() or not count_tok.isdigit() or int(count_tok) > 6:
                raise SyntaxFormatError(tk.path, line, f"bad channel count {count_tok!r} for {name} (0 to 6)")
            chans = []
            for _ in range(int(count_tok)):
                cline = tk.line()
                c = tk.next(f"a channel name of {name}")
                if c.lower() not in _CHANNELS:
                    raise UnknownChannelError(tk.path, cline, f"unknown channel {c!r} on joint {name}")
                if _CHANNELS[c.lower()] in chans:
                    raise SyntaxFormatError(tk.path, cline, f"channel {c} repeated on joint {name}")
                chans.append(_CHANNELS[c.lower()])
            joint.channels = tuple(chans)
        elif low == "joint":
            begin(stack[-1])
        elif low == "end":
            if joint.end_site is not None:
                raise SyntaxFormatError(tk.path, line, f"joint {name} has a second End Site")
            tk.expect("Site")
            tk.expect("{")
            tk.expect("OFFSET")
            joint.end_site = np.array([tk.number(f"End Site OFFSET of {name}") for _ in range(3)])
            tk.expect("}")
        else:
            raise SyntaxFormatError(tk.path, line, f"unexpected {tok!r} in joint {name}")
    return joints


_POW10 = np.array([10.0**k for k in range(23)])
#: kernel status codes
_OK, _BAD_COUNT, _BAD_TOKEN, _TOO_MANY = 0, 1, 2, 3


@njit(cache=True, nogil=True)
def _parse_frames(buf, n_rows, n_cols, out, pow10):  # pragma: no cover - compiled
    """Parse whitespace-separated decimal numbers, one frame per non-blank line, into ``out``.

    Returns (status, line index of the fault within ``buf`` (0-based), rows parsed). Values are
    mantissa / 10^k with an exact integer mantissa, i.e. correctly rounded for up to 15-16
    significant digits, like strtod.

    Bounds: writes ``out[row, col]`` only after checking row < n_rows (else _TOO_MANY) and
    col < n_cols (else _BAD_COUNT), with n_rows × n_cols no larger than ``out`` (checked here);
    ``pow10`` is read at 0..22 only.
    """
    if n_rows > out.shape[0] or n_cols > out.shape[1] or pow10.shape[0] < 23:
        return _TOO_MANY, 0, 0
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
        if c == 32 or c == 9 or c == 11 or c == 12 or c == 13:
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
        if not seen or (i < n and not (buf[i] == 32 or 9 <= buf[i] <= 13)):  # tab, LF, VT, FF, CR
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
    """The value after ``key`` ('Frames:' / 'Frame Time:') on line i (skipping blank lines; any
    white space between the key's words)."""
    while i < len(lines) and not lines[i].strip():
        i += 1
    if i >= len(lines):
        raise TruncatedFileError(path, len(lines), f"file ends before '{key}'")
    s = " ".join(lines[i].split())
    if not s.lower().startswith(key.lower()):
        raise SyntaxFormatError(path, i + 1, f"expected '{key}', found {s[:40]!r}")
    return s[len(key):].strip(), i


#: accepted frame times (s): 100 kHz to one frame per 10 s
FRAME_TIME_RANGE = (1e-5, 10.0)


def _is_float(token: str) -> bool:
    """Whether Python reads the token as a float at all (to tell 'inf' or '1e999' from 'abc')."""
    try:
        float(token)
    except ValueError:
        return False
    return "_" not in token


def parse_bvh(text: str, path: str | None = None, *, unit: str | None = None,
              scale_to_m: float | None = None, name: str | None = None, content_hash: str = "") -> Motion:
    """Parse BVH text into a :class:`Motion`.

    ``unit``/``scale_to_m`` come from the caller (BVH declares no unit). The declared frame count
    is checked against the bytes left in the file before the frame array is allocated. Cost:
    O(file size).
    """
    lines = text_lines(text.removeprefix("\ufeff"))
    h = _find(lines, "HIERARCHY")
    if h < 0:
        raise MissingSectionError(path, 1, "no HIERARCHY section")
    m = _find(lines, "MOTION", h + 1)
    if m < 0:
        raise MissingSectionError(path, len(lines), "no MOTION section")
    tk = _Tokens(lines[: m], path)
    tk.pos = sum(len(line.split()) for line in lines[: h + 1])
    root_line = tk.line()
    if (tok := tk.next("ROOT")).upper() != "ROOT":
        raise SyntaxFormatError(path, root_line, f"expected ROOT, found {tok!r}")
    joints = _parse_hierarchy(tk)
    if tk.peek() is not None:
        raise SyntaxFormatError(path, tk.line(), f"unexpected {tk.peek()!r} after the hierarchy")

    frames_text, i = _header_value(lines, m + 1, "Frames:", path)
    if not (frames_text.isascii() and frames_text.isdigit()):
        raise SyntaxFormatError(path, i + 1, f"bad frame count {frames_text!r}")
    n_frames = int(frames_text)
    ft_text, i = _header_value(lines, i + 1, "Frame Time:", path)
    frame_time = number(ft_text)
    if frame_time is None:
        raise SyntaxFormatError(path, i + 1, f"bad frame time {ft_text!r}")
    lo, hi = FRAME_TIME_RANGE
    if not lo <= frame_time <= hi:
        raise FrameValueError(path, i + 1, f"frame time {ft_text} s is outside {lo:g}..{hi:g} s")
    if n_frames <= 0:
        raise EmptyMotionError(path, i, f"the file declares {n_frames} frames")

    first = i + 1  # 0-based index of the first frame line
    n_cols = sum(len(j.channels) for j in joints)
    if n_cols == 0:
        raise SyntaxFormatError(path, h + 1, "the hierarchy declares no channels")
    block = "\n".join(lines[first:]).encode("ascii", errors="replace")
    if n_frames * n_cols * 2 - 1 > len(block):  # each value takes a digit and a separator at least
        raise TruncatedFileError(path, len(lines), f"the file declares {n_frames} frames of {n_cols} values, "
                                 f"more than its {len(block)} bytes of frame lines can hold")
    data = np.empty((n_frames, n_cols))
    status, fault, rows = _parse_frames(np.frombuffer(block, dtype=np.uint8), n_frames, n_cols, data, _POW10)
    line_no = first + 1 + int(fault)
    if status == _BAD_COUNT:
        count = len(lines[line_no - 1].split())
        raise FrameValueError(path, line_no, f"frame line has {count} values, expected {n_cols}")
    if status == _BAD_TOKEN:
        bad = next((t for t in lines[line_no - 1].split() if number(t) is None), "?")
        what = "a value that is not finite" if _is_float(bad) else "non-numeric value"
        raise FrameValueError(path, line_no, f"{what} {bad!r}")
    if status == _TOO_MANY:
        raise FrameValueError(path, line_no, f"more frame lines than the {n_frames} declared")
    if rows < n_frames:
        raise TruncatedFileError(path, len(lines), f"file ends after {rows} of the {n_frames} declared frames")
    finite = np.isfinite(data).all(axis=1)
    if not finite.all():
        row = int(np.flatnonzero(~finite)[0])
        line_no = first + 1 + _nth_frame_line(lines[first:], row)
        bad = next((t for t in lines[line_no - 1].split() if number(t) is None), "?")
        raise FrameValueError(path, line_no, f"a value that is not finite {bad!r}")
    return _to_motion(joints, data, frame_rate(frame_time), path, unit, scale_to_m, name, content_hash)


def _nth_frame_line(lines: list[str], row: int) -> int:
    """0-based index among ``lines`` of the ``row``-th non-blank line."""
    seen = -1
    for k, line in enumerate(lines):
        if line.strip():
            seen += 1
            if seen == row:
                return k
    return len(lines) - 1


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
    """Read a BVH file (any newline convention, UTF-8 or Latin-1). See :func:`parse_bvh`."""
    raw, digest = read_bytes(path)
    return parse_bvh(decode(raw), str(path), unit=unit, scale_to_m=scale_to_m, content_hash=digest)


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

