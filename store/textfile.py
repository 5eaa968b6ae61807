"""Reading motion text files the same way in every reader: bytes, decoding, lines, numbers.

Lines end at ``\\n``, ``\\r\\n`` or ``\\r`` only: form feeds, vertical tabs and U+2028 are white
space inside a line, so line numbers match what an editor shows (``str.splitlines`` would count
them as line breaks). A UTF-8 byte-order mark is dropped. Numbers are plain decimals (``1``,
``-2.5``, ``1e-3``): Python's ``float`` also takes ``1_000``, ``nan`` and ``inf``, which no motion
format writes.
"""

from __future__ import annotations

import hashlib
import math
import re
from pathlib import Path

from motionweb.store.errors import MissingSectionError

_LINE_BREAK = re.compile(r"\r\n|\r|\n")
_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


def read_bytes(path: str | Path) -> tuple[bytes, str]:
    """A file's bytes and their SHA-256 (hex); an unreadable file is a format error naming it."""
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise MissingSectionError(str(path), None, f"cannot read file: {exc.strerror or exc}") from None
    return raw, hashlib.sha256(raw).hexdigest()


def decode(raw: bytes) -> str:
    """UTF-8 text without a byte-order mark; bytes that are not UTF-8 are read as Latin-1."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return text.removeprefix("\ufeff")


def text_lines(text: str) -> list[str]:
    """The lines of ``text`` split at \\n, \\r\\n or \\r only (no empty last line after a final break)."""
    lines = _LINE_BREAK.split(text)
    if lines and lines[-1] == "":
        lines.pop()
    return lines


def line_of(text: str, pos: int) -> int:
    """1-based line number of character offset ``pos`` (same line breaks as :func:`text_lines`)."""
    head = text[:pos]
    return len(_LINE_BREAK.findall(head)) + 1 - (1 if head.endswith("\r") and text[pos:pos + 1] == "\n" else 0)


def number(token: str) -> float | None:
    """The finite value of a plain decimal token, None when it is anything else (or overflows)."""
    if not _NUMBER.fullmatch(token):
        return None
    value = float(token)
    return value if math.isfinite(value) else None
