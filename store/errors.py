"""Errors raised for malformed motion files.

Every reader raises a subclass of :class:`MotionFormatError`; its message names the file and,
where there is one, the 1-based line number, so a user can open the file at the fault.
"""

from __future__ import annotations

from pathlib import Path


class MotionFormatError(ValueError):
    """A motion file that cannot be read. ``path`` and ``line`` locate the fault."""

    def __init__(self, path: str | Path | None, line: int | None, message: str):
        self.path = None if path is None else str(path)
        self.line = line
        self.reason = message
        where = self.path or "<text>"
        if line is not None:
            where = f"{where}:{line}"
        super().__init__(f"{where}: {message}")


class TruncatedFileError(MotionFormatError):
    """The file ends before its header or its declared frames are complete."""


class MissingSectionError(MotionFormatError):
    """A required section (HIERARCHY, MOTION, :hierarchy, ...) is absent."""


class FrameValueError(MotionFormatError):
    """A frame line has the wrong number of values, a non-numeric value, NaN or inf."""


class UnknownChannelError(MotionFormatError):
    """A channel name the format does not define."""


class EmptyMotionError(MotionFormatError):
    """A motion with zero frames."""


class UnknownJointError(MotionFormatError):
    """A joint referenced by motion data that the skeleton does not define."""


class SyntaxFormatError(MotionFormatError):
    """Any other violation of the file's grammar."""


class SidecarError(MotionFormatError):
    """The metadata JSON beside a clip is malformed or holds a bad ``unit`` / ``scale_to_m``."""


class ReaderFailure(MotionFormatError):
    """A fault no reader check named (a bug to report: every malformed input should get a
    specific error); raised by ``read_motion`` instead of a foreign exception."""
