"""One clock for the whole bench and the scheduler: real, accelerated or virtual time.

Times are seconds since the clock started (the run's time base). A virtual clock jumps to the
deadline it is asked to sleep until, so an hour-long warm-up runs as fast as the steps can be
computed; an accelerated clock runs ``factor`` times faster than the wall clock.
"""

from __future__ import annotations

import asyncio
import contextlib
import heapq
import itertools
import math
import time
from collections.abc import Iterator
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float:
        """Seconds since the clock started."""
        ...

    async def sleep_until(self, deadline_s: float) -> None:
        """Return once ``now() >= deadline_s`` (at once if it already is)."""
        ...


class ScaledClock:
    """Wall time times ``factor`` (1 = real time)."""

    def __init__(self, factor: float = 1.0) -> None:
        if factor <= 0:
            raise ValueError(f"clock factor must be positive, not {factor}")
        self.factor = factor
        self._start = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._start) * self.factor

    async def sleep_until(self, deadline_s: float) -> None:
        # asyncio may wake up to one clock-resolution tick early; callers record lateness,
        # which is then at worst a fraction of a millisecond negative.
        remaining = deadline_s - self.now()
        await asyncio.sleep(max(remaining, 0.0) / self.factor)


#: Scheduling points a pacer gives woken followers before it moves the time on (the run's step
#: passes a few awaits between its timer's wake and reading the time of its tick).
FOLLOWER_YIELDS = 8


class VirtualClock:
    """Time that only moves when someone sleeps: it jumps to the deadline.

    **Paced** (issue 20, a duty cycle played on the arm bench): while a task holds
    :meth:`pacing` (the cycle's player: its moves' ``finish`` and its dwells), a *follower*
    (:meth:`follow_until`, the run's step timer through :class:`FollowingClock`) does not jump
    the time: it waits until the pacer's sleeps have carried it past its deadline, and a pacer's
    sleep stops at each follower's deadline on its way (a discrete-event clock: the steps come
    at their time within the cycle's motion, not ahead of it). Without a pacer a follower
    sleeps as anyone does."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._now = start_s
        self._pacers = 0
        self._followers: list[tuple[float, int, asyncio.Future[None]]] = []
        self._order = itertools.count()

    def now(self) -> float:
        return self._now

    @staticmethod
    def _check(deadline_s: float) -> None:
        if not math.isfinite(deadline_s):
            # a jump to infinity would leave every later deadline NaN (issue 15, point 7)
            raise ValueError(f"virtual clock: deadline {deadline_s} is not finite")

    async def sleep_until(self, deadline_s: float) -> None:
        self._check(deadline_s)
        # a follower due on the way wakes at its own time, and runs before time goes on
        while self._followers and self._followers[0][0] < deadline_s:
            self._now = max(self._now, self._followers[0][0])
            await self._let_woken_run()
        self._now = max(self._now, deadline_s)
        if not await self._let_woken_run():
            await asyncio.sleep(0)  # still a scheduling point, as a real sleep would be

    async def _let_woken_run(self) -> bool:
        """Wake the followers due now and give them a few scheduling points to get on with
        their step before the pacer moves the time again (a woken task's own awaits, e.g. the
        session's sleep's clean-up, each take one); whether any was woken."""
        woken = self._wake_due()
        for _ in range(FOLLOWER_YIELDS if woken else 0):
            await asyncio.sleep(0)
        return woken > 0

    async def follow_until(self, deadline_s: float) -> None:
        """Sleep until ``deadline_s`` without moving the time while a pacer holds it."""
        self._check(deadline_s)
        if self._pacers and self._now >= deadline_s:
            return  # due: on at once, before the pacer moves the time again
        while self._pacers and self._now < deadline_s:
            waiter = asyncio.get_running_loop().create_future()
            heapq.heappush(self._followers, (deadline_s, next(self._order), waiter))
            try:
                await waiter
            finally:
                if not waiter.done():  # cancelled: forget it
                    waiter.cancel()
                    self._followers = [f for f in self._followers if f[2] is not waiter]
                    heapq.heapify(self._followers)
            if self._now >= deadline_s:
                return  # woken at its time: on, before the pacer moves the time again
        await self.sleep_until(deadline_s)

    @contextlib.contextmanager
    def pacing(self) -> Iterator[None]:
        """While held, only sleep_until moves the time (class docstring)."""
        self._pacers += 1
        try:
            yield
        finally:
            self._pacers -= 1
            if not self._pacers:  # nobody paces: the followers sleep as anyone does
                self._wake_all()

    def _wake_due(self) -> int:
        woken = 0
        while self._followers and self._followers[0][0] <= self._now:
            _, _, waiter = heapq.heappop(self._followers)
            if not waiter.done():
                waiter.set_result(None)
                woken += 1
        return woken

    def _wake_all(self) -> None:
        followers, self._followers = self._followers, []
        for _, _, waiter in followers:
            if not waiter.done():
                waiter.set_result(None)


class FollowingClock:
    """A clock's view for a task whose sleeps must not move a paced virtual clock (the run's
    step timer while a duty cycle plays: VirtualClock's docstring); any other clock as is."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        factor = getattr(clock, "factor", None)
        if factor is not None:
            self.factor = factor  # the scheduler's precise wake reads it

    def now(self) -> float:
        return self.clock.now()

    async def sleep_until(self, deadline_s: float) -> None:
        follow = getattr(self.clock, "follow_until", None)
        if follow is None:
            await self.clock.sleep_until(deadline_s)
        else:
            await follow(deadline_s)


def make_clock(kind: str, factor: float = 1.0) -> Clock:
    """The clock named by the settings (``bench.clock``, ``bench.time_factor``)."""
    if kind == "real":
        return ScaledClock(1.0)
    if kind == "accelerated":
        return ScaledClock(factor)
    if kind == "virtual":
        return VirtualClock()
    raise ValueError(f"unknown clock {kind!r}: expected real, accelerated or virtual")
