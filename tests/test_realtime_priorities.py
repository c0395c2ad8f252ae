"""Who runs at which priority when real-time scheduling is granted (issue 30): the control
thread at ``scheduler.realtime_priority``, the daemon's other threads real-time below it (the
GIL: a holder preempted by the PC's ordinary processes would hold up a step), and the
background work -- deferred summaries, export processes -- back at normal scheduling and nicer,
never at a real-time priority taking a core from the lab PC for seconds."""

from __future__ import annotations

import asyncio
import os
import threading
from collections.abc import Callable
from typing import TypeVar

import pytest

from daemon.run.control_loop import HOME_REALTIME_PRIORITY, ControlLoop
from daemon.run.workers import EXPORT_NICENESS, SUMMARY_NICENESS, Workers
from drivers import realtime as background

_T = TypeVar("_T")


def _in_a_fifo_thread(work: Callable[[], _T], priority: int = HOME_REALTIME_PRIORITY) -> _T:
    """``work()`` on a thread of its own at SCHED_FIFO ``priority`` (the test's own threads
    are never changed); skipped where the host refuses real-time scheduling, as the daemon
    then asks for niceness instead (tests/test_control_loop.py covers that fallback)."""
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


def test_the_other_threads_run_real_time_below_the_control_thread_and_come_back() -> None:
    async def enter() -> tuple[tuple[int, int, int], tuple[int, int, int], str, str]:
        async with ControlLoop(threaded=True, realtime_priority=10) as control:
            home = _policy()
            on_control = await control.run(_policy)
            said = (control.scheduling, control.home_scheduling)
        return home, on_control, *said

    def work() -> tuple[tuple[int, int, int], tuple[int, int, int], str, str, tuple[int, int, int]]:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))  # as a daemon starts
        return (*asyncio.run(enter()), _policy())

    home, on_control, scheduling, home_scheduling, after = _in_a_fifo_thread(work)
    assert on_control[:2] == (os.SCHED_FIFO, 10), scheduling
    assert home[:2] == (os.SCHED_FIFO, HOME_REALTIME_PRIORITY), home_scheduling
    assert home_scheduling == f"SCHED_FIFO priority {HOME_REALTIME_PRIORITY}"
    assert after[0] == os.SCHED_OTHER  # the thread is given back as it came


def test_the_other_threads_ask_for_niceness_where_real_time_is_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def refuse(*_: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    lowered: list[int] = []
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(os, "setpriority", lambda _which, _who, value: lowered.append(value))
    said = control_home_scheduling()
    assert said.startswith("niceness") and "SCHED_FIFO not permitted" in said
    assert lowered  # the niceness fallback was asked for


def control_home_scheduling() -> str:
    async def enter() -> str:
        async with ControlLoop(threaded=True, realtime_priority=10) as control:
            return control.home_scheduling

    return asyncio.run(enter())


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
    """Started from a real-time thread (as the daemon's API threads are), the deferred
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
