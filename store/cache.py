"""A thread-safe least-recently-used map, bounded by entries, by bytes, or both.

The service keeps its webs and packed walk graphs in one (design §5, "The service at scale"):
bounded by bytes, so its memory follows what queries touch, not the size of the library; it also
keeps recent results and motions by count. Cost: O(1) per get and put, plus one eviction per
entry dropped.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable
from typing import Any

import numpy as np


def array_bytes(*arrays: np.ndarray | None) -> int:
    """The bytes held by ``arrays`` (None counts 0)."""
    return sum(int(a.nbytes) for a in arrays if a is not None)


class LRU:
    """Least recently used entries are dropped first once there are more than ``max_items``
    entries or their sizes (``nbytes`` given to :meth:`put`) sum to more than ``max_bytes``
    (None: no bound). The entry just put is never dropped by its own put, so a value larger than
    the bound is kept until the next put (a search always gets the graph it asked for)."""

    def __init__(self, max_items: int | None = None, max_bytes: int | None = None):
        self.max_items, self.max_bytes = max_items, max_bytes
        self._items: OrderedDict[Hashable, tuple[Any, int]] = OrderedDict()
        self._lock = threading.Lock()
        self.nbytes = 0
        self.hits = self.misses = self.evictions = 0

    def get(self, key: Hashable) -> Any:
        """The value of ``key`` (now the most recently used), or None."""
        with self._lock:
            item = self._items.get(key)
            if item is None:
                self.misses += 1
                return None
            self.hits += 1
            self._items.move_to_end(key)
            return item[0]

    def put(self, key: Hashable, value: Any, nbytes: int = 0) -> None:
        """Keep ``value`` under ``key`` (``nbytes``: its size), dropping the least recently used
        entries beyond the bounds."""
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self.nbytes -= old[1]
            self._items[key] = (value, int(nbytes))
            self.nbytes += int(nbytes)
            while len(self._items) > 1 and (
                    (self.max_items is not None and len(self._items) > self.max_items)
                    or (self.max_bytes is not None and self.nbytes > self.max_bytes)):
                _, (_, n) = self._items.popitem(last=False)
                self.nbytes -= n
                self.evictions += 1

    def discard(self, key: Hashable) -> None:
        """Drop ``key``'s entry, if any."""
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self.nbytes -= old[1]

    def oldest_first(self) -> list[Hashable]:
        """The keys, least recently used first (a copy)."""
        with self._lock:
            return list(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key: Hashable) -> bool:
        with self._lock:
            return key in self._items

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self.nbytes = 0

    def stats(self) -> dict[str, Any]:
        """Entries, bytes, the bounds, hits, misses and evictions so far."""
        with self._lock:
            return {"entries": len(self._items), "bytes": self.nbytes, "max_bytes": self.max_bytes,
                    "max_items": self.max_items, "hits": self.hits, "misses": self.misses,
                    "evictions": self.evictions}
