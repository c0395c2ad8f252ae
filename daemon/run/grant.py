"""The robot as one run may use it (daemon/run/session.py): motion only while no hold came after
the request that last allowed this run to move -- its grant, the ticket of its start and then
of each resume (drivers/permit.py; docs/explanation/hold.md) -- and the run's own hold.

The one owner of the run's grant. The run's state is not touched here: the session decides
what a refused release or a hold means for the run.
"""

from __future__ import annotations

import logging

from daemon.run.events import ErrorLog
from daemon.run.services import HeldRobot
from drivers.errors import DeviceError
from drivers.permit import MotionPermit, Ticket

logger = logging.getLogger(__name__)


class RunGrant:
    """``ticket``: the robot's permit as it was when the run's start request arrived."""

    def __init__(self, run_id: int, robot: HeldRobot, errors: ErrorLog, ticket: Ticket) -> None:
        self._run_id = run_id
        self._robot = robot
        self._errors = errors
        self.ticket = ticket  # the request that last allowed the run to move

    @property
    def permit(self) -> MotionPermit:
        return self._robot.permit

    @property
    def current(self) -> bool:
        """No hold came after the request that granted motion."""
        return self.permit.is_current(self.ticket)

    async def release(self) -> None:
        """A hold from before the grant's request is released (starting or resuming is an
        explicit request to move again); one that came after it never is: MotionHeldError
        (issue 15, point 2; issue 26)."""
        if not self.permit.held and self.current:
            return
        await self._robot.resume(self.ticket)

    async def hold(self, reason: str | None = None) -> None:
        """Hold the robot; ``reason`` is what its status says when this hold is the first
        since the last release (a request's own hold keeps its reason). A robot that cannot be
        reached is noted and logged, never raised: a hold is the first thing of every ending."""
        if reason is not None:
            self.permit.hold(reason)
        try:
            await self._robot.stop()
        except DeviceError as err:
            self._errors.note(err)
            logger.warning("run %d: could not hold the robot: %s", self._run_id, err)
