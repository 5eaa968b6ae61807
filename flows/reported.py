"""Errors the CLI reports itself, in one line: which exceptions those are (the on-demand commands
run their work in the CLI's own process, ``flows/lazy_prefect.py``, so no Prefect run logs them first)."""

from __future__ import annotations

from motionweb.store.errors import MotionFormatError

#: RuntimeError: e.g. Prefect's local API server not starting in time on a busy machine; OSError:
#: a missing input or an output that cannot be written
ERRORS = (ValueError, KeyError, OSError, MotionFormatError, RuntimeError)
