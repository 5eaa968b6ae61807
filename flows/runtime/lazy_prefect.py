"""Prefect tasks and flows that cost nothing until a flow runs (issue 23).

Importing Prefect takes 2-3 s on a 2-core machine, and a flow run with no server configured
starts Prefect's temporary API server (10-30 s). The on-demand commands (warp, retime, search,
parameterize) run their work in the CLI's process without Prefect: each flow's body is written
once, and each task in it is called through :func:`call`, which runs the task as a Prefect task
inside a flow run and as its plain function (``task.fn``) outside one. So ``some_flow(...)`` is a
Prefect flow run as before, and ``some_flow.fn(...)`` is the same computation, same bytes, with
Prefect never imported.

:func:`task` and :func:`flow` take Prefect's decorator options (``no_cache=True`` for
``cache_policy=NO_CACHE``) and return a :class:`Lazy`: the plain function (``.fn``), made into a
real Prefect task or flow on its first Prefect use (a call, ``.submit``, ``.with_options``, any
other attribute). A lazy flow cannot be served from its module (``Flow.serve`` loads its entrypoint
and expects a ``Flow``): ``index-library`` keeps Prefect's own decorator.
"""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Callable
from typing import Any


class Lazy:
    """A Prefect task or flow (``kind``) of ``fn``, built on first Prefect use; ``.fn`` is ``fn``."""

    def __init__(self, kind: str, fn: Callable[..., Any], options: dict[str, Any]):
        self.fn = fn
        self._kind, self._options, self._obj = kind, options, None
        functools.update_wrapper(self, fn)

    def prefect(self) -> Any:
        """The real ``prefect.Task`` / ``prefect.Flow`` (imports Prefect the first time)."""
        if self._obj is None:
            import prefect

            opts = dict(self._options)
            if opts.pop("no_cache", False):
                from prefect.cache_policies import NO_CACHE

                opts["cache_policy"] = NO_CACHE
            self._obj = getattr(prefect, self._kind)(**opts)(self.fn)
        return self._obj

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self.prefect()(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("_kind", "_options", "_obj", "fn"):
            raise AttributeError(name)
        return getattr(self.prefect(), name)

    def __repr__(self) -> str:
        return f"<lazy Prefect {self._kind} {self.fn.__qualname__}>"


def task(**options: Any) -> Callable[[Callable[..., Any]], Lazy]:
    """``@task(name=..., no_cache=True, retries=...)``: a :class:`Lazy` Prefect task."""
    return lambda fn: Lazy("task", fn, options)


def flow(**options: Any) -> Callable[[Callable[..., Any]], Lazy]:
    """``@flow(name=..., ...)``: a :class:`Lazy` Prefect flow."""
    return lambda fn: Lazy("flow", fn, options)


def in_flow_run() -> bool:
    """Whether this thread runs inside a Prefect flow run (never when Prefect is not imported)."""
    ctx = sys.modules.get("prefect.context")
    return ctx is not None and ctx.FlowRunContext.get() is not None


def call(t: Lazy | Any, *args: Any, **kwargs: Any) -> Any:
    """Run task ``t``: a Prefect task run inside a flow run, its plain function outside one."""
    return t(*args, **kwargs) if in_flow_run() else t.fn(*args, **kwargs)


def run_logger() -> logging.Logger | logging.LoggerAdapter:
    """Prefect's run logger inside a flow run; the ``motionweb.flows`` logger outside one."""
    if in_flow_run():
        from prefect import get_run_logger

        return get_run_logger()
    return logging.getLogger("motionweb.flows")
