"""The daemon's worker threads, each pool with one job (issue 15: the loop owns its workers).

- ``step``: the control loop's CPU work (centroid, long model advances, reference frame):
  nobody else submits here, so a burst of API reads can never delay a step's thread job.
- ``db``: the one recorder thread: every write in order, off the event loop (an fsync per
  step), and the end-of-run summary.
- ``reads``: API reads and exports, bounded: at most ``READ_THREADS`` run at once and the rest
  wait their turn in the API, never in front of the control loop.

Drivers keep using the event loop's default executor for their own blocking calls (opening a
port, an OpenCV read), which the API no longer touches.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

_T = TypeVar("_T")

STEP_THREADS = 2
READ_THREADS = 2


class Workers:
    def __init__(self) -> None:
        self._step = ThreadPoolExecutor(STEP_THREADS, thread_name_prefix="step")
        self._db = ThreadPoolExecutor(1, thread_name_prefix="recorder")
        self._reads = ThreadPoolExecutor(READ_THREADS, thread_name_prefix="api-read")

    def step(self, function: Callable[..., _T], *args: Any) -> asyncio.Future[_T]:
        return asyncio.get_running_loop().run_in_executor(self._step, function, *args)

    def db(self, function: Callable[..., _T], *args: Any) -> asyncio.Future[_T]:
        return asyncio.get_running_loop().run_in_executor(self._db, function, *args)

    def read(self, function: Callable[..., _T], *args: Any) -> asyncio.Future[_T]:
        return asyncio.get_running_loop().run_in_executor(self._reads, function, *args)

    def shutdown(self) -> None:
        """Wait for the recorder's pending writes (they are the run's record); drop queued
        reads and step work (their callers are gone)."""
        for pool in (self._reads, self._step):
            pool.shutdown(wait=False, cancel_futures=True)
        self._db.shutdown(wait=True)
