"""Errors the CLI reports itself, in one line: which exceptions those are, and keeping Prefect
from printing their traceback first when they are raised inside a flow run."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager

from motionweb.store.errors import MotionFormatError

#: RuntimeError: e.g. Prefect's local API server not starting in time on a busy machine; OSError:
#: a missing input or an output that cannot be written
ERRORS = (ValueError, KeyError, OSError, MotionFormatError, RuntimeError)


class DropReported(logging.Filter):
    """Drops Prefect's records of an error the CLI reports itself in one line (a ValueError raised
    inside the flow would otherwise print its traceback first): records carrying such an
    exception, and the run's "Finished in state Failed" line that repeats it."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, ERRORS):
            return False
        return not (record.levelno >= logging.ERROR and "Finished in state Failed" in record.getMessage())


@contextmanager
def reported_flow_errors() -> Iterator[None]:
    """While a flow runs for the CLI, Prefect's flow- and task-run loggers drop what
    :class:`DropReported` drops (the failure is still recorded in Prefect's run history)."""
    loggers = [logging.getLogger(name) for name in ("prefect.flow_runs", "prefect.task_runs")]
    drop = DropReported()
    for lg in loggers:
        lg.addFilter(drop)
    try:
        yield
    finally:
        for lg in loggers:
            lg.removeFilter(drop)
