"""Work on many independent items in a few threads, answers in the items' order: for stages
whose per-item work releases the GIL (file reads, Blosc, SHA-256, nogil compiled kernels)."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")

#: threads of a pass over a store's files or a corpus: more add little on a disk
IO_THREADS = 8


def map_in_threads(fn: Callable[[T], R], items: Sequence[T], threads: int | None = None,
                   most: int | None = None, name: str = "work") -> list[R]:
    """``[fn(x) for x in items]``, in that order, on ``threads`` threads (default: one per core),
    at most ``most`` and one per item; in this thread when that comes to one. An exception of
    ``fn`` is raised here, the first in item order."""
    n = min(threads or os.cpu_count() or 1, len(items), most or len(items) or 1)
    if n <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(n, thread_name_prefix=name) as pool:
        return list(pool.map(fn, items))
