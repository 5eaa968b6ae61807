"""Errors the CLI reports itself, in one line: which exceptions those are (the on-demand commands
run their work in the CLI's own process, ``flows/runtime/lazy_prefect.py``, so no Prefect run logs them first)."""

from __future__ import annotations

from motionweb.store.errors import MotionFormatError

#: RuntimeError: e.g. Prefect's local API server not starting in time on a busy machine; OSError:
#: a missing input or an output that cannot be written
ERRORS = (ValueError, KeyError, OSError, MotionFormatError, RuntimeError)


class CommandError(ValueError):
    """A command's own failure with its exit code (``motionweb verify``: 1 for a damaged store,
    as ``fsck`` and friends do; every other reported error exits 2)."""

    def __init__(self, message: str, exit_code: int = 2):
        super().__init__(message)
        self.exit_code = exit_code
