"""The daemon's worker threads, each pool with one job (issue 15: the loop owns its workers).

- ``step``: the control loop's CPU work (centroid, long model advances, reference frame):
  nobody else submits here, so a burst of API reads can never delay a step's thread job.
- ``db``: the one recorder thread: every write in order, off the event loop (an fsync per
  step), and the end-of-run summary.
- ``reads``: API reads, bounded: at most ``READ_THREADS`` run at once and the rest wait their
  turn in the API, never in front of the control loop.
- ``summaries``: the summaries a shutdown deferred (daemon/run/pending_summaries.py), one at a
  time on a thread of their own, nicer than the daemon: a day at a 20 ms step is 4.32 M steps
  to read back (~87 s), which on the read pool held one of its ``READ_THREADS`` that long.
- ``exports``: processes that encode step exports (daemon/storage/exports.py): CPU-heavy work that
  would hold this process's GIL for seconds, so it runs in processes of its own, started on
  first use; at most ``EXPORT_PROCESSES`` at once.

Drivers keep using the event loop's default executor for their own blocking calls (opening a
port, an OpenCV read), which the API no longer touches.
"""

from __future__ import annotations

import asyncio
import multiprocessing
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from typing import Any, TypeVar

from drivers.realtime import background_priority

_T = TypeVar("_T")

STEP_THREADS = 2
READ_THREADS = 2
#: One: exports then use at most one core of a 2-core lab PC and stream ~19 MB/s, which the
#: event loop forwards with no effect on the steps (benchmarks/bench_control_core.py: six
#: readers moved the p99 lateness by -0.03 and +0.35 ms with one process, +2.1 to +2.9 ms
#: with two).
EXPORT_PROCESSES = 1
#: Export processes run this much nicer than the daemon: on a 2-core lab PC the kernel then
#: gives the control loop the CPU first whenever both want it.
EXPORT_NICENESS = 10
#: The deferred summaries' thread runs at least this nice: on a 2-core lab PC the kernel gives
#: the control loop, the recorder and the API reads the CPU first whenever they want it.
SUMMARY_NICENESS = 10


class Workers:
    """``critical``: run first in each ``step`` and ``db`` thread (the control loop's
    scheduling, daemon/run/control_loop.py): a step waits for both -- its CPU work, and its
    record committed in step order -- so they share the loop's priority."""

    def __init__(self, critical: Callable[[], object] | None = None) -> None:
        self._step = ThreadPoolExecutor(
            STEP_THREADS, thread_name_prefix="step", initializer=critical
        )
        self._db = ThreadPoolExecutor(1, thread_name_prefix="recorder", initializer=critical)
        self._reads = ThreadPoolExecutor(READ_THREADS, thread_name_prefix="api-read")
        self._summaries = ThreadPoolExecutor(
            1,
            thread_name_prefix="deferred-summary",
            initializer=background_priority,
            initargs=(SUMMARY_NICENESS,),
        )
        self._exports: ProcessPoolExecutor | None = None

    def step(self, function: Callable[..., _T], *args: Any) -> asyncio.Future[_T]:
        return asyncio.get_running_loop().run_in_executor(self._step, function, *args)

    def db(self, function: Callable[..., _T], *args: Any) -> asyncio.Future[_T]:
        return asyncio.get_running_loop().run_in_executor(self._db, function, *args)

    def read(self, function: Callable[..., _T], *args: Any) -> asyncio.Future[_T]:
        return asyncio.get_running_loop().run_in_executor(self._reads, function, *args)

    def summary(self, function: Callable[..., _T], *args: Any) -> asyncio.Future[_T]:
        """A deferred summary's computation: its own thread, never an API read's."""
        return asyncio.get_running_loop().run_in_executor(self._summaries, function, *args)

    def export(self, function: Callable[..., _T], *args: Any) -> asyncio.Future[_T]:
        """Run a picklable ``function`` in an export process (started on first use; "spawn":
        a fork of a process with threads and an event loop is not safe)."""
        if self._exports is None:
            context = multiprocessing.get_context("spawn")
            self._exports = ProcessPoolExecutor(
                EXPORT_PROCESSES,
                mp_context=context,
                initializer=background_priority,
                initargs=(EXPORT_NICENESS,),
            )
        return asyncio.get_running_loop().run_in_executor(self._exports, function, *args)

    def shutdown(self) -> None:
        """Wait for the recorder's pending writes (they are the run's record); drop queued
        reads, summaries, exports and step work (their callers are gone; a deferred summary
        in progress was given up by its abandon event and stays pending)."""
        for pool in (self._reads, self._summaries, self._step):
            pool.shutdown(wait=False, cancel_futures=True)
        if self._exports is not None:
            self._exports.shutdown(wait=True, cancel_futures=True)
        self._db.shutdown(wait=True)
