"""gc_paused: the collector paused for a block, nested and from threads, and running again after."""

from __future__ import annotations

import gc
import threading

import pytest
from motionweb.store.gcpause import gc_paused


def test_the_collector_runs_again_after_the_last_block() -> None:
    assert gc.isenabled()
    with gc_paused():
        assert not gc.isenabled()
        with gc_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()  # the outer block still holds it
    assert gc.isenabled()
    with pytest.raises(RuntimeError), gc_paused():
        raise RuntimeError("in the block")
    assert gc.isenabled()


def test_a_collector_off_before_stays_off() -> None:
    gc.disable()
    try:
        with gc_paused():
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_blocks_in_threads_end_with_the_collector_running() -> None:
    inside = threading.Barrier(4)

    def work() -> None:
        with gc_paused():
            inside.wait()
            assert not gc.isenabled()
            inside.wait()

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert gc.isenabled()


def test_kept_objects_leave_the_collectors_reach() -> None:
    before = gc.get_freeze_count()
    try:
        with gc_paused(keep=True):
            held = [[i] for i in range(1000)]
        assert gc.get_freeze_count() >= before + len(held)
    finally:
        gc.unfreeze()


def test_garbage_made_before_a_kept_block_is_collected_not_frozen() -> None:
    import weakref

    class Node:
        pass

    a, b = Node(), Node()
    a.other, b.other = b, a  # a reference cycle: only the collector frees it
    gone = weakref.ref(a)
    del a, b
    try:
        with gc_paused(keep=True):
            pass
        assert gone() is None
    finally:
        gc.unfreeze()
