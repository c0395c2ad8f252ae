"""daemon/heap.py: the start-up heap is collected once, then frozen out of later collections;
the memory locked where the host permits it, one line saying why not where it does not."""

from __future__ import annotations

import ctypes
import errno
import gc
import os
import subprocess
import sys
import weakref
from collections.abc import Iterator

import pytest

from daemon import heap
from daemon.heap import freeze_startup_heap, lock_memory
from tests.helpers import REPO_ROOT


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


# --- locked memory ----------------------------------------------------------------------


def test_a_finite_locking_limit_locks_nothing_and_says_what_to_grant(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def never(*_: object) -> None:
        raise AssertionError("mlockall must not be called under a finite limit")

    monkeypatch.setattr(heap.resource, "getrlimit", lambda _: (8 << 20, 8 << 20))
    monkeypatch.setattr(heap, "_has_capability", lambda _: False)
    monkeypatch.setattr(heap.ctypes, "CDLL", never)
    said = lock_memory()
    assert said.startswith("memory not locked") and "8192 KiB" in said
    assert "LimitMEMLOCK=infinity" in said and "\n" not in said


def test_a_refused_mlockall_is_one_line_with_its_reason(monkeypatch: pytest.MonkeyPatch) -> None:
    class Libc:
        def mlockall(self, flags: int) -> int:
            assert flags == heap.MCL_CURRENT | heap.MCL_FUTURE | heap.MCL_ONFAULT
            ctypes.set_errno(errno.EPERM)
            return -1

    monkeypatch.setattr(heap.resource, "getrlimit", lambda _: (heap.resource.RLIM_INFINITY,) * 2)
    monkeypatch.setattr(heap.ctypes, "CDLL", lambda *_, **__: Libc())
    said = lock_memory()
    assert said == f"memory not locked: mlockall failed ({os.strerror(errno.EPERM)})"


def test_memory_is_locked_where_the_host_permits_it() -> None:
    """In a process of its own (a lock stays until the process ends): locked pages show in
    VmLck when the host permits it; otherwise the one line says so and nothing is locked."""
    code = (
        "from daemon.heap import lock_memory; said = lock_memory(); "
        "status = open('/proc/self/status').read(); "
        "print(said); print(status.split('VmLck:')[1].split()[0])"
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    )
    said, locked_kib = done.stdout.splitlines()
    if said.startswith("memory locked"):
        assert int(locked_kib) > 1024  # the interpreter's pages at least
    else:
        assert said.startswith("memory not locked") and int(locked_kib) == 0
