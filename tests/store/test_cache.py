"""The LRU bounded by entries and bytes (store.cache) that the service keeps its webs in."""

from __future__ import annotations

import numpy as np
from motionweb.store.cache import LRU, array_bytes
from motionweb.store.web import MatchWeb


def test_bytes_bound_drops_the_least_recently_used() -> None:
    c = LRU(max_bytes=100)
    c.put("a", 1, 40)
    c.put("b", 2, 40)
    assert c.get("a") == 1  # a is now the most recent
    c.put("c", 3, 40)  # 120 > 100: b goes
    assert "b" not in c and c.get("a") == 1 and c.get("c") == 3 and c.nbytes == 80
    c.put("a", 4, 10)  # replacing an entry counts its new size only
    assert c.nbytes == 50 and c.get("a") == 4
    assert c.stats()["evictions"] == 1 and c.stats()["entries"] == 2


def test_an_entry_larger_than_the_bound_is_kept_until_the_next_put() -> None:
    c = LRU(max_bytes=10)
    c.put("big", "x", 100)
    assert c.get("big") == "x" and len(c) == 1
    c.put("small", "y", 5)
    assert "big" not in c and c.get("small") == "y" and c.nbytes == 5


def test_items_bound_and_no_bound() -> None:
    c = LRU(max_items=2)
    for k in range(5):
        c.put(k, k)
    assert sorted(k for k in range(5) if k in c) == [3, 4] and c.get(0) is None
    u = LRU()
    for k in range(1000):
        u.put(k, k, 1 << 20)
    assert len(u) == 1000 and u.nbytes == 1000 << 20


def test_web_bytes_count_its_arrays() -> None:
    web = MatchWeb(30.0, (5, 5), paths_cells=np.array([[0, 0], [1, 1]]), paths_values=np.array([0.1, 0.2]),
                   paths_offsets=np.array([0, 2]))
    assert web.nbytes == array_bytes(web.paths_cells, web.paths_values, web.paths_offsets, web.bridges,
                                     web.bridges_cells, web.bridges_values, web.bridges_offsets)
    assert web.nbytes == 2 * 2 * 4 + 2 * 4 + 2 * 8 + 0 + 0 + 0 + 8


def test_discard_drops_an_entry_and_its_bytes_and_oldest_first_lists_the_keys() -> None:
    c = LRU(max_bytes=100)
    for k, n in (("a", 10), ("b", 20), ("c", 30)):
        c.put(k, k.upper(), n)
    c.get("a")
    assert c.oldest_first() == ["b", "c", "a"]
    c.discard("c")
    c.discard("nope")
    assert c.oldest_first() == ["b", "a"] and c.nbytes == 30 and c.get("c") is None and len(c) == 2
