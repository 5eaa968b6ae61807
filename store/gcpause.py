"""Python's cyclic garbage collector paused while a large JSON text becomes Python objects.

Parsing a web shard's header (4.5 MB, ~9 M objects across the 72 headers of the 381k-frame
store) or a manifest builds containers that all live on; each full collection the allocations
trigger walks every one of them, so the parse cost grows as the square of what is already held.
Measured on those 72 headers: orjson 4.3 s with the collector running, 0.9 s paused (json: 8.1
and 1.3 s). JSON values hold no reference cycles, so pausing loses nothing: reference counting
frees them.

Once parsed they are still the collector's to walk: with a writer's ~9 M objects of those headers
held, the next 2 M allocations of anything took 5.2 s instead of 0.3 s. ``keep=True`` moves every
object alive at the end of the block out of its reach (``gc.freeze``); they are still freed by
reference counting when dropped, only a reference cycle alive at that moment would never be
collected: the collector runs once when such a block starts (cost: the objects not frozen yet),
so only cycles made inside it (none is expected) are kept, and a long-lived process (the app's
readers) does not ask for it."""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator
from contextlib import contextmanager

_lock = threading.Lock()
_depth = 0
_was_enabled = False


@contextmanager
def gc_paused(keep: bool = False) -> Iterator[None]:
    """Pause the collector for the block (nested and concurrent blocks too: it runs again, if it
    ran before the first, when the last one ends); ``keep``: then freeze what is alive (see above)."""
    global _depth, _was_enabled
    if keep:
        gc.collect()  # the garbage so far, before what is alive at the end is frozen
    with _lock:
        if _depth == 0:
            _was_enabled = gc.isenabled()
            gc.disable()
        _depth += 1
    try:
        yield
        if keep:
            gc.freeze()
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and _was_enabled:
                gc.enable()
