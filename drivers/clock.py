"""One clock for the whole bench and the scheduler: real, accelerated or virtual time.

Times are seconds since the clock started (the run's time base). A virtual clock jumps to the
deadline it is asked to sleep until, so an hour-long warm-up runs as fast as the steps can be
computed; an accelerated clock runs ``factor`` times faster than the wall clock.
"""

from __future__ import annotations

import asyncio
import math
import time
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


class VirtualClock:
    """Time that only moves when someone sleeps: it jumps to the deadline."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._now = start_s

    def now(self) -> float:
        return self._now

    async def sleep_until(self, deadline_s: float) -> None:
        if not math.isfinite(deadline_s):
            # a jump to infinity would leave every later deadline NaN (issue 15, point 7)
            raise ValueError(f"virtual clock: deadline {deadline_s} is not finite")
        self._now = max(self._now, deadline_s)
        await asyncio.sleep(0)  # still a scheduling point, as a real sleep would be


def make_clock(kind: str, factor: float = 1.0) -> Clock:
    """The clock named by the settings (``bench.clock``, ``bench.time_factor``)."""
    if kind == "real":
        return ScaledClock(1.0)
    if kind == "accelerated":
        return ScaledClock(factor)
    if kind == "virtual":
        return VirtualClock()
    raise ValueError(f"unknown clock {kind!r}: expected real, accelerated or virtual")
