"""The steps whose measurement and record overlap later steps' moves (daemon/run/step.py
``MeasuringStep``, two-link runs), oldest first: the session collects each one in step order
-- publishes its committed record and acts on its verdict -- once it is done, and waits for
the oldest when too many are under way."""

from __future__ import annotations

import asyncio
import collections
import logging
from collections.abc import Awaitable, Callable

from daemon.run.events import ErrorLog
from daemon.run.step import MeasuringStep, StepOutcome

logger = logging.getLogger(__name__)

#: At most this many steps measure and record while a later one moves: a commit that waits on
#: a slow fsync (34 ms seen on a lab VM's disk, where the median is 0.5 ms) then delays the
#: publication of a few 20 ms steps, not their moves. A crash loses at most these steps'
#: records and the moving one's.
MEASURING_STEPS = 3


class StepsMeasuring:
    """``collect(step, outcome)``: the session's publication and judgement of a step."""

    def __init__(self, collect: Callable[[int, StepOutcome], Awaitable[None]]) -> None:
        self._collect = collect
        self._pending: collections.deque[MeasuringStep] = collections.deque()

    def __bool__(self) -> bool:
        return bool(self._pending)

    def add(self, step: MeasuringStep) -> None:
        self._pending.append(step)

    async def settle(self, *, keep: int = 0) -> None:
        """Collect each step done, oldest first, and as many more as leave at most ``keep``
        under way (a RecorderError one met is raised here, as from a step)."""
        pending = self._pending
        while pending and (len(pending) > keep or pending[0].outcome.done()):
            measuring = pending[0]
            try:
                # shielded: a stop that abandons the loop leaves it for settle_at_end
                outcome = await asyncio.shield(measuring.outcome)
            finally:
                if measuring.outcome.done():
                    pending.popleft()
            await self._collect(measuring.step, outcome)

    async def settle_at_end(self, run_id: int, errors: ErrorLog) -> None:
        """Every step left (the loop's task was cancelled): each still gets its record; what
        one met is logged and noted, and the run ends anyway."""
        while self._pending:
            step = self._pending[0].step
            try:
                await self.settle(keep=len(self._pending) - 1)
            except Exception as err:  # the run is ending: what is lost is said, once
                logger.error("run %d step %d: not recorded: %s", run_id, step, err)
                errors.note(err, device="storage")
