"""The background work leaves the daemon's scheduling (issue 30): deferred summaries and export
processes started from a real-time thread (the control loop's) or a less nice one (the API's)
run at normal scheduling and nicer, never at a real-time priority taking a core from the lab
PC for seconds. (The control loop's own scheduling: tests/test_control_loop.py.)"""

from __future__ import annotations

import asyncio
import os
import threading
from collections.abc import Callable
from typing import TypeVar

import pytest

from daemon.run.workers import EXPORT_NICENESS, SUMMARY_NICENESS, Workers
from drivers import realtime as background

_T = TypeVar("_T")


def _in_a_fifo_thread(work: Callable[[], _T], priority: int = 1) -> _T:
    """``work()`` on a thread of its own at SCHED_FIFO ``priority`` (the test's own threads
    are never changed); skipped where the host refuses real-time scheduling: then nothing
    real-time is there to leave (test_background_priority_never_lowers_a_niceness still runs)."""
    result: list[_T] = []
    errors: list[BaseException] = []

    def run() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except PermissionError as err:
            errors.append(err)
            return
        try:
            result.append(work())
        except BaseException as err:  # handed to the test's thread
            errors.append(err)

    thread = threading.Thread(target=run)
    thread.start()
    thread.join(60)
    if errors and isinstance(errors[0], PermissionError):
        pytest.skip(f"the host refuses SCHED_FIFO ({errors[0]})")
    if errors:
        raise errors[0]
    return result[0]


def _policy() -> tuple[int, int, int]:
    """The calling thread's policy, real-time priority and niceness."""
    thread = threading.get_native_id()
    return (
        os.sched_getscheduler(0),
        os.sched_getparam(0).sched_priority,
        os.getpriority(os.PRIO_PROCESS, thread),
    )


def test_background_priority_leaves_real_time_and_is_nicer() -> None:
    def work() -> tuple[tuple[int, int, int], tuple[int, int, int]]:
        before = _policy()
        background.background_priority(7)
        return before, _policy()

    before, after = _in_a_fifo_thread(work)
    assert before[0] == os.SCHED_FIFO
    assert after[0] == os.SCHED_OTHER and after[2] >= 7


def test_background_priority_never_lowers_a_niceness(monkeypatch: pytest.MonkeyPatch) -> None:
    """A thread already nicer than asked stays as nice (lowering would need a privilege)."""
    set_to: list[int] = []
    monkeypatch.setattr(os, "sched_getscheduler", lambda _pid: os.SCHED_OTHER)
    monkeypatch.setattr(os, "getpriority", lambda _which, _who: 15)
    monkeypatch.setattr(os, "setpriority", lambda _which, _who, value: set_to.append(value))
    background.background_priority(10)
    assert set_to == [15]


def test_deferred_summaries_and_exports_run_outside_real_time() -> None:
    """Started from a real-time thread (as from the control loop's), the deferred
    summaries' thread and the export processes run at normal scheduling, at least as nice as
    their constants."""

    async def submit() -> tuple[tuple[int, int, int], tuple[int, int]]:
        workers = Workers()
        try:
            summary_thread = await workers.summary(_policy)
            export_process = await workers.export(_export_policy)
        finally:
            workers.shutdown()
        return summary_thread, export_process

    summary_thread, export_process = _in_a_fifo_thread(lambda: asyncio.run(submit()))
    assert summary_thread[0] == os.SCHED_OTHER and summary_thread[2] >= SUMMARY_NICENESS
    assert export_process == (os.SCHED_OTHER, EXPORT_NICENESS) or (
        export_process[0] == os.SCHED_OTHER and export_process[1] >= EXPORT_NICENESS
    )


def _export_policy() -> tuple[int, int]:
    """In the export process: its policy and niceness (module level: pickled by name)."""
    return os.sched_getscheduler(0), os.getpriority(os.PRIO_PROCESS, 0)
