"""daemon/heap.py: the start-up heap is collected once, then frozen out of later collections."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import pytest

from daemon.heap import freeze_startup_heap


class _Node:
    def __init__(self) -> None:
        self.other: _Node | None = None


@pytest.fixture
def unfrozen() -> Iterator[None]:
    gc.unfreeze()  # the test process may have frozen nothing yet; start from a known state
    yield
    gc.unfreeze()  # leave the collector to the other tests as it was


@pytest.mark.usefixtures("unfrozen")
def test_cycles_of_start_up_are_collected_and_the_rest_frozen() -> None:
    garbage_a, garbage_b = _Node(), _Node()
    garbage_a.other, garbage_b.other = garbage_b, garbage_a  # unreachable once deleted below
    dead = weakref.ref(garbage_a)
    kept = _Node()
    kept.other = kept
    del garbage_a, garbage_b
    assert gc.get_freeze_count() == 0

    elapsed_s = freeze_startup_heap()

    assert dead() is None  # the cycle was collected, not frozen forever
    assert elapsed_s >= 0.0
    frozen = gc.get_freeze_count()
    assert frozen > 0
    assert not any(o is kept for o in gc.get_objects())  # frozen: in no generation
    gc.collect()
    assert gc.get_freeze_count() == frozen  # a full collection leaves the frozen heap alone


@pytest.mark.usefixtures("unfrozen")
def test_what_comes_after_the_freeze_is_still_collected() -> None:
    freeze_startup_heap()
    later_a, later_b = _Node(), _Node()
    later_a.other, later_b.other = later_b, later_a
    dead = weakref.ref(later_a)
    del later_a, later_b
    gc.collect()
    assert dead() is None
