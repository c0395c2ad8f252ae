"""Bounded waits on a device: wall time, minus the time the simulator spends computing.

A grab or a read is bounded in wall time (issue 10): a hung device, driver thread or emulator
must not hold a step forever, and the run clock cannot bound it (a virtual clock would jump a
run-clock deadline forward at once). On the simulated bench, though, a frame is *computed*: a
5 MP render keeps a worker thread busy for seconds on a loaded machine, time in which the
modelled camera has long delivered. So the simulated devices run that work through
:func:`off_the_clock`, and a :func:`device_deadline` stands still meanwhile: it bounds the
device's latency as the bench models it (its injected faults included: ``no-frame`` still
times out, ``late=S`` still waits S seconds of the run clock), not how busy the machine is.
A real device never calls :func:`off_the_clock`, so its deadline is plain wall time.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Awaitable, Callable
from contextvars import ContextVar
from dataclasses import dataclass
from typing import ParamSpec, TypeVar

from drivers.errors import DeviceTimeoutError

_T = TypeVar("_T")
_P = ParamSpec("_P")


@dataclass
class _Computing:
    """Wall time (event-loop seconds) spent in the simulator's own computing within one
    deadline: overlapping computations (several cameras of one grab) count once."""

    spent_s: float = 0.0
    running: int = 0
    since_s: float = 0.0

    def begin(self, now_s: float) -> None:
        if not self.running:
            self.since_s = now_s
        self.running += 1

    def end(self, now_s: float) -> None:
        self.running -= 1
        if not self.running:
            self.spent_s += now_s - self.since_s

    def spent(self, now_s: float) -> float:
        return self.spent_s + (now_s - self.since_s if self.running else 0.0)


#: The deadline the current task's device operation runs under (copied into the tasks it
#: starts, e.g. one grab per camera under asyncio.gather).
_DEADLINE: ContextVar[_Computing | None] = ContextVar("device_deadline", default=None)


@contextlib.asynccontextmanager
async def device_deadline(timeout_s: float) -> AsyncIterator[asyncio.Timeout]:
    """Like ``asyncio.timeout(timeout_s)`` (the body is cancelled and TimeoutError raised;
    the yielded scope's ``expired()`` tells that timeout from the device's own), except that
    the time spent in :func:`off_the_clock` within the body does not count."""
    loop = asyncio.get_running_loop()
    start_s = loop.time()
    computing = _Computing()
    token = _DEADLINE.set(computing)
    handle: asyncio.TimerHandle | None = None
    try:
        async with asyncio.timeout(None) as scope:

            def check() -> None:
                nonlocal handle
                now_s = loop.time()
                left_s = timeout_s - (now_s - start_s - computing.spent(now_s))
                if left_s <= 0.0:
                    scope.reschedule(now_s)  # expires now: the body is cancelled
                else:
                    handle = loop.call_later(left_s, check)

            handle = loop.call_later(timeout_s, check)
            yield scope
    finally:
        if handle is not None:
            handle.cancel()
        _DEADLINE.reset(token)


async def off_the_clock(function: Callable[_P, _T], *args: _P.args, **kwargs: _P.kwargs) -> _T:
    """Run the simulator's own blocking computation (a render, the physics) in a worker
    thread, as ``asyncio.to_thread``; an enclosing :func:`device_deadline` stands still
    meanwhile (module docstring)."""
    computing = _DEADLINE.get()
    if computing is None:
        return await asyncio.to_thread(function, *args, **kwargs)
    loop = asyncio.get_running_loop()
    computing.begin(loop.time())
    try:
        return await asyncio.to_thread(function, *args, **kwargs)
    finally:
        computing.end(loop.time())


async def bounded(operation: Awaitable[_T], device: str, what: str, timeout_s: float) -> _T:
    """``operation`` within ``timeout_s`` (:func:`device_deadline`), else DeviceTimeoutError
    ``"<device>: no <what> within <timeout_s> s"``; the device's own DeviceError as it is."""
    try:
        async with device_deadline(timeout_s) as scope:
            return await operation
    except TimeoutError as err:
        if not scope.expired():
            raise  # the device's own timeout (a DeviceTimeoutError): as it is
        raise DeviceTimeoutError(device, f"no {what} within {timeout_s:g} s") from err
