"""The control loop's own thread and event loop: where the devices live and a run's steps run.

On a busy lab PC a step that shares its event loop with the API, the event fan-out, report
writing and export streaming waits behind them: at a 20 ms step on the fast path, 30 % of steps
overran at load 3-5 with one loop for everything (docs/explanation/benchmarks.md). Here the
run's critical path (model -> target check -> move -> measure -> record) runs on a thread of
its own with its own event loop; the rest of the daemon talks to it only through
:meth:`ControlLoop.call` (a request, answered on the caller's loop), the frozen read model
(daemon/run/readmodel.py) and the bounded outbox of :class:`HomeOutbox` (events and the few
calls that belong to the API's loop). The run's state keeps one owner: RunSession, on this
thread.

A thread, not a process: the devices (serial port, cameras) and the run's session then stay
objects of one process, the hold still reaches the driver with one synchronous call
(drivers/permit.py, whose lock makes "check, then write" atomic against a hold from any
thread), and no state is copied between processes. The GIL is the price: the other threads'
Python work can still delay a step by up to the interpreter's switch interval, lowered here to
:data:`SWITCH_INTERVAL_S`.

Real-time scheduling is asked for the control thread (and the threads a step waits on) when
``realtime_priority`` > 0 (``SCHED_FIFO``; Linux applies ``sched_setscheduler(0, ...)`` to the
calling thread), and a lower niceness for the daemon's other threads (:func:`home_priority`);
the background work (exports, reports, deferred summaries) goes back to normal scheduling at a
higher niceness first (drivers/realtime.py ``background_priority``). When the host does not
permit it (no ``CAP_SYS_NICE`` nor ``LimitRTPRIO``), a lower niceness is tried, then one log
line says what the loop runs with. deploy/thermocomp.service grants what it needs.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import functools
import logging
import os
import sys
import threading
from collections.abc import Awaitable, Callable
from concurrent.futures import Future
from types import TracebackType
from typing import TypeVar

from drivers.realtime import lower_niceness, realtime_scheduling

logger = logging.getLogger(__name__)

_T = TypeVar("_T")

#: The interpreter's GIL switch interval while a control thread runs (default 5 ms): a thread
#: woken by its serial reply waits at most this long for a CPU-bound Python thread to let go.
SWITCH_INTERVAL_S = 0.0005
#: Niceness change of the daemon's other threads when real-time scheduling is asked for
#: (relative: from 0 under systemd, -5).
HOME_NICENESS = -5
#: Largest number of posts waiting for the API's loop; the oldest is dropped past it (a loop
#: stalled that long has lost its subscribers' events anyway: their queues are bounded too).
OUTBOX_SIZE = 10_000
#: Seconds to wait for the thread to end at shutdown (its loop is stopped first).
JOIN_TIMEOUT_S = 10.0


class HomeOutbox:
    """Calls from the control thread to be run on the home (API) loop, in order, bounded: the
    control thread never waits for the home loop, and one wake-up carries a whole batch."""

    def __init__(self, home: asyncio.AbstractEventLoop, size: int = OUTBOX_SIZE) -> None:
        self._home = home
        self._size = size
        self._items: collections.deque[Callable[[], None]] = collections.deque()
        self._lock = threading.Lock()
        self._scheduled = False
        self.dropped = 0

    def post(self, call: Callable[[], None]) -> None:
        with self._lock:
            if len(self._items) >= self._size:
                self._items.popleft()
                self.dropped += 1
            self._items.append(call)
            wake, self._scheduled = not self._scheduled, True
        if wake:
            with contextlib.suppress(RuntimeError):  # the home loop is closed: daemon gone
                self._home.call_soon_threadsafe(self._drain)

    def _drain(self) -> None:
        with self._lock:
            items = list(self._items)
            self._items.clear()
            self._scheduled = False
        for call in items:
            try:
                call()
            except Exception:
                logger.exception("a post from the control loop failed")


def home_priority(priority: int) -> str:
    """The daemon's other threads (this one and those it starts later inherit it) made
    :data:`HOME_NICENESS` less nice when real-time scheduling is asked for: the control thread waits
    for the GIL whenever another thread holds it, and a holder preempted by the lab PC's other
    processes would make it wait for a whole time slice. Real-time scheduling for them too
    (``SCHED_FIFO`` 1, below the control thread) was measured against this and gained nothing
    (0 and 1 overruns in 3,000 20 ms steps against 0 and 0, two busy loops, load 2.1-2.5;
    benchmarks/bench_loop_isolation.py), so the API's work stays below the PC's real-time
    budget."""
    if priority <= 0:
        return "normal scheduling"
    try:
        niceness = lower_niceness(HOME_NICENESS)
    except (PermissionError, OSError, AttributeError) as err:
        return f"normal scheduling (niceness {HOME_NICENESS:+d} not permitted: {err})"
    return f"niceness {niceness}"


class ControlLoop:
    """The control loop's event loop: a thread of its own (``threaded``) or, for virtual
    clocks and tests, the caller's own loop (every call then simply awaits on it).

    Use as an async context manager from the home loop; :attr:`scheduling` says what the
    thread runs with."""

    def __init__(self, *, threaded: bool, realtime_priority: int = 0) -> None:
        self.threaded = threaded
        self._priority = realtime_priority
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._home: asyncio.AbstractEventLoop | None = None
        self._outbox: HomeOutbox | None = None
        self._switch_interval = sys.getswitchinterval()
        self.scheduling = "the API's event loop (no control thread)"
        self.home_scheduling = "unchanged"
        self._home_tid = 0
        self._home_niceness = 0

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            raise RuntimeError("the control loop is not started")
        return self._loop

    def on_control_thread(self) -> bool:
        """True on the control loop's thread (always, when not threaded)."""
        return not self.threaded or self._thread is threading.current_thread()

    async def __aenter__(self) -> ControlLoop:
        self._home = asyncio.get_running_loop()
        if not self.threaded:
            self._loop = self._home
            return self
        self._outbox = HomeOutbox(self._home)
        self._home_tid = threading.get_native_id()
        self._home_niceness = os.getpriority(os.PRIO_PROCESS, self._home_tid)
        self.home_scheduling = home_priority(self._priority)
        ready: Future[asyncio.AbstractEventLoop] = Future()
        self._thread = threading.Thread(
            target=self._serve, args=(ready,), name="control-loop", daemon=True
        )
        self._thread.start()
        self._loop = await asyncio.wrap_future(ready)
        sys.setswitchinterval(min(self._switch_interval, SWITCH_INTERVAL_S))
        logger.info(
            "control loop on its own thread: %s; the daemon's other threads: %s",
            self.scheduling,
            self.home_scheduling,
        )
        return self

    def _serve(self, ready: Future[asyncio.AbstractEventLoop]) -> None:
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self.scheduling = realtime_scheduling(self._priority)
        ready.set_result(loop)
        try:
            loop.run_forever()
        finally:
            try:
                pending = asyncio.all_tasks(loop)
                for task in pending:
                    task.cancel()
                if pending:
                    loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
                loop.run_until_complete(loop.shutdown_asyncgens())
                loop.run_until_complete(loop.shutdown_default_executor())
            finally:
                loop.close()

    def critical_thread_setup(self) -> Callable[[], object] | None:
        """For the threads a step waits on (its CPU work, its recorder): the control thread's
        real-time scheduling; None without a control thread or when none is asked for."""
        if not self.threaded or self._priority <= 0:
            return None
        return functools.partial(realtime_scheduling, self._priority)

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if not self.threaded or self._thread is None or self._loop is None:
            return
        self._loop.call_soon_threadsafe(self._loop.stop)
        await asyncio.to_thread(self._thread.join, JOIN_TIMEOUT_S)
        if self._thread.is_alive():
            logger.error("the control loop's thread did not end in %.0f s", JOIN_TIMEOUT_S)
        sys.setswitchinterval(self._switch_interval)
        with contextlib.suppress(OSError):  # back to what it was (a raise is always allowed)
            os.setpriority(os.PRIO_PROCESS, self._home_tid, self._home_niceness)
        self._thread = None

    async def call(self, function: Callable[[], Awaitable[_T]]) -> _T:
        """Run ``function()`` (a coroutine) on the control loop; its result here. Cancelling
        the caller cancels it there."""
        if not self.threaded:
            return await function()

        async def run() -> _T:
            return await function()

        future = asyncio.run_coroutine_threadsafe(run(), self.loop)
        try:
            return await asyncio.wrap_future(future)
        except asyncio.CancelledError:
            future.cancel()
            raise

    async def run(self, function: Callable[[], _T]) -> _T:
        """Run the synchronous ``function()`` on the control loop (between its callbacks, so
        never in the middle of a state change there); its result here."""
        if not self.threaded:
            return function()
        future: Future[_T] = Future()

        def call() -> None:
            if not future.set_running_or_notify_cancel():
                return
            try:
                future.set_result(function())
            except BaseException as err:
                future.set_exception(err)

        self.loop.call_soon_threadsafe(call)
        return await asyncio.wrap_future(future)

    def post_home(self, call: Callable[[], None]) -> None:
        """From the control loop: run ``call()`` on the home loop, in order, never waiting
        (directly when there is no control thread, or when already there)."""
        if self._outbox is None or not self.on_control_thread():
            call()
            return
        self._outbox.post(call)

    @property
    def dropped_posts(self) -> int:
        return 0 if self._outbox is None else self._outbox.dropped
