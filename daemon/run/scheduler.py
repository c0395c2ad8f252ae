"""The fixed-step timer: absolute deadlines on the run's clock, no catch-up bursts.

Step k is due at ``start + k * period``. A step that ends after the next deadline is an
overrun: the schedule moves on to the first deadline still in the future (the missed ones are
skipped, not run back to back) and the overrun is counted. The thesis's LabVIEW chain could
only manage one step per ~34 s (143 steps in 4,800 s, 6.5–6.7); here the period is whatever
the link allows, 10 ms to 10 min.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from drivers.clock import Clock

#: The stages of one step, in the order they run (issue 6 "One step").
STAGES = ("model", "check", "move", "frame", "centroid", "ir", "record")

MIN_PERIOD_S = 0.01
MAX_PERIOD_S = 600.0


@dataclass(frozen=True, slots=True)
class Tick:
    """One step's slot: its number, when it was due, when it began."""

    step: int  # consecutive step number (0, 1, 2 ...), skipped deadlines get none
    slot: int  # deadline index: scheduled_s = start_s + slot * period_s
    scheduled_s: float
    actual_s: float

    @property
    def lateness_s(self) -> float:
        return self.actual_s - self.scheduled_s


class FixedStepTimer:
    """Hands out ticks on absolute deadlines of ``clock``."""

    def __init__(
        self, clock: Clock, period_s: float, start_s: float, precise_wake_s: float = 0.0
    ) -> None:
        if not MIN_PERIOD_S <= period_s <= MAX_PERIOD_S:
            raise ValueError(f"step period must be 10 ms to 10 min, not {period_s} s")
        self.clock = clock
        # asyncio sleeps end on whole milliseconds (epoll), so up to 1 ms late: on a wall
        # clock, sleep until this much (wall time) before the deadline, then yield to the
        # loop until it comes. A virtual clock has no ``factor`` and jumps exactly.
        factor = getattr(clock, "factor", None)
        self._spin_s = precise_wake_s * factor if isinstance(factor, int | float) else 0.0
        self.period_s = period_s
        self.start_s = start_s
        self.overruns = 0  # times a step ran past the next deadline
        self.skipped = 0  # deadlines given up because of overruns
        self._next_slot = 0
        self._step = 0

    def deadline(self, slot: int) -> float:
        return self.start_s + slot * self.period_s

    @property
    def next_deadline_s(self) -> float:
        return self.deadline(self._next_slot)

    @property
    def next_wake_s(self) -> float:
        """When a sleeper should wake to let :meth:`wait` meet the next deadline precisely."""
        return self.next_deadline_s - self._spin_s

    async def wait(self) -> Tick:
        """Sleep until the next deadline; return its tick."""
        scheduled = self.deadline(self._next_slot)
        if self._spin_s > 0:
            await self.clock.sleep_until(scheduled - self._spin_s)
            while self.clock.now() < scheduled:  # noqa: ASYNC110 -- a yield, not a poll
                await asyncio.sleep(0)  # other tasks (the API) still run meanwhile
        await self.clock.sleep_until(scheduled)
        tick = Tick(self._step, self._next_slot, scheduled, self.clock.now())
        self._step += 1
        self._next_slot += 1
        return tick

    def step_done(self) -> None:
        """Call when a step has ended: detects an overrun and skips the missed deadlines."""
        self._skip_to(self.clock.now(), count_overrun=True)

    def resync(self) -> None:
        """After a pause: continue at the first deadline not yet past (not an overrun)."""
        self._skip_to(self.clock.now(), count_overrun=False)

    def _skip_to(self, now: float, count_overrun: bool) -> None:
        if now <= self.deadline(self._next_slot):
            return
        # the first slot whose deadline is not yet past
        first_future = max(
            self._next_slot + 1, math.ceil((now - self.start_s) / self.period_s - 1e-9)
        )
        if count_overrun:
            self.overruns += 1
            self.skipped += first_future - self._next_slot
        self._next_slot = first_future


class TimingStats:
    """Lateness and per-stage durations of the recent ``window`` steps (bounded memory).

    :meth:`summary` is asked for by every API state request: it is recomputed at most every
    ``refresh_s`` seconds of wall time, so polling never costs the loop more than that.
    Added to on the control loop's thread, summarised on the API's: a lock guards the copy."""

    def __init__(self, window: int = 10_000, refresh_s: float = 0.5) -> None:
        self.lateness_s: deque[float] = deque(maxlen=window)
        self.stage_s: dict[str, deque[float]] = {s: deque(maxlen=window) for s in STAGES}
        self.max_lateness_s = 0.0
        self.steps = 0
        self._refresh_s = refresh_s
        self._cached: tuple[float, int, dict[str, object]] | None = None
        self._lock = threading.Lock()

    def add(self, lateness_s: float, stages: dict[str, float]) -> None:
        with self._lock:
            self.steps += 1
            self.lateness_s.append(lateness_s)
            self.max_lateness_s = max(self.max_lateness_s, lateness_s)
            for name, seconds in stages.items():
                self.stage_s[name].append(seconds)

    def summary(self, fresh: bool = False) -> dict[str, object]:
        """p50/p99/max lateness (s) and p50/p99/max of each stage (s); max over all steps."""
        now = time.monotonic()
        if self._cached is not None and not fresh:
            computed_at, steps, cached = self._cached
            if steps == self.steps or now - computed_at < self._refresh_s:
                return cached
        with self._lock:  # a copy, then the percentiles outside the lock
            steps, lateness, top = self.steps, list(self.lateness_s), self.max_lateness_s
            stages = {name: list(v) for name, v in self.stage_s.items() if v}
        summary: dict[str, object] = {
            "steps": steps,
            "lateness_s": percentiles(lateness, top),
            "stages_s": {name: percentiles(v) for name, v in stages.items()},
        }
        self._cached = (now, steps, summary)
        return summary


def percentiles(values: Iterable[float], overall_max: float | None = None) -> dict[str, float]:
    """p50, p99 and max of ``values`` (NaN when there are none)."""
    data = np.fromiter(values, dtype=np.float64)
    if data.size == 0:
        return {"p50": math.nan, "p99": math.nan, "max": math.nan}
    p50, p99 = np.percentile(data, [50, 99])
    top = float(data.max()) if overall_max is None else max(overall_max, float(data.max()))
    return {"p50": float(p50), "p99": float(p99), "max": top}


async def sleep_until_woken(clock: Clock, deadline_s: float, wake: asyncio.Event) -> None:
    """Sleep on ``clock`` until ``deadline_s``, or less when ``wake`` is set (cleared first):
    a run's sleep that any request ends early (daemon/run/session.py). The clock's own error
    (a deadline it refuses) is raised."""
    if clock.now() >= deadline_s:
        return
    wake.clear()
    sleeper = asyncio.ensure_future(clock.sleep_until(deadline_s))
    waker = asyncio.ensure_future(wake.wait())
    try:
        await asyncio.wait({sleeper, waker}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in (sleeper, waker):
            if not task.done():
                task.cancel()
        await asyncio.gather(sleeper, waker, return_exceptions=True)
    if sleeper.done() and not sleeper.cancelled():
        sleeper.result()
