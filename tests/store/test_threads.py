"""map_in_threads: the answers of a plain loop, in order, whatever the threads; the first error raised."""

from __future__ import annotations

import threading

import pytest
from motionweb.store.threads import map_in_threads


@pytest.mark.parametrize(("threads", "most"), [(1, None), (3, None), (None, 2), (16, 4)])
def test_answers_come_in_item_order_on_at_most_the_threads_asked(threads, most) -> None:
    seen: set[str] = set()

    def square(x: int) -> int:
        seen.add(threading.current_thread().name)
        return x * x

    assert map_in_threads(square, list(range(40)), threads, most) == [x * x for x in range(40)]
    assert len(seen) <= min(threads or 40, most or 40)
    assert map_in_threads(square, [], threads, most) == []


def test_the_first_error_in_item_order_is_raised() -> None:
    def fail_on_odd(x: int) -> int:
        if x % 2:
            raise ValueError(f"item {x}")
        return x

    with pytest.raises(ValueError, match="item 1"):
        map_in_threads(fail_on_odd, list(range(10)), 4)
