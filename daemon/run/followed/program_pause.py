"""The robot's own program paused on a followed run's hold, and played again on its resume
(robot.pause_program_on_hold; a UR's Dashboard Server: drivers.base.ProgramControl).

Order: the hold comes first and is never waited on here. A followed run's session holds the
robot (the correction freezes: hold flag, nothing more written) *before* it calls the kind's
``stop_playing`` (daemon/run/session.py), which is where :meth:`ProgramPause.pause` runs; the
daemon's hold requests hold the permit on the caller's thread before anything else
(daemon/service.py). So a slow or dead Dashboard Server can delay only the pause itself, never
the freeze: its failure is logged and listed in the daemon's errors (a ``DeviceError`` noted),
never raised into the hold's path, and the pause gives up after the stop's grace period.

Only a program that was playing is paused, and only a program this pause paused is played
again by the resume: a program the operator paused or stopped, or that a protective stop
halted, stays as the operator left it (a program stopped meanwhile is a restart: the driver
refuses the resume, drivers/ur/robot.py).
"""

from __future__ import annotations

import asyncio
import logging

from daemon.run.events import ErrorLog
from drivers.base import ProgramControl
from drivers.errors import DeviceError, DeviceTimeoutError

logger = logging.getLogger(__name__)

DEVICE = "robot"
#: The Dashboard Server's word for a program that plays (``programState``).
PLAYING = "PLAYING"
PAUSED = "PAUSED"


class ProgramPause:
    """Pause a followed robot's program after a hold, play it again on the resume. ``control``
    None (a robot without one) or ``enabled`` False: nothing is ever sent."""

    def __init__(self, control: ProgramControl | None, *, enabled: bool, errors: ErrorLog) -> None:
        self.control = control if enabled else None
        self.errors = errors
        #: this pause paused the program and no resume has played it since
        self.paused = False

    async def pause(self, timeout_s: float) -> None:
        """After a hold: pause the program if it plays. Never raises a device's failure: it is
        logged and noted (module docstring)."""
        control = self.control
        if control is None or self.paused:
            return
        try:
            async with asyncio.timeout(timeout_s):
                state = await control.program_state()
                if state != PLAYING:
                    logger.info("the robot's program is %s: nothing to pause", state)
                    return
                await control.pause_program()
        except (DeviceError, TimeoutError) as err:
            self._failed("could not pause the robot's program after the hold", err, timeout_s)
            return
        self.paused = True
        logger.warning("the robot's program paused through the Dashboard Server (after the hold)")

    async def play_again(self, timeout_s: float) -> None:
        """After the run's resume: play the program again if this pause paused it and it is
        still paused. Never raises a device's failure (the run follows a paused program)."""
        control = self.control
        if control is None or not self.paused:
            return
        self.paused = False
        try:
            async with asyncio.timeout(timeout_s):
                state = await control.program_state()
                if state != PAUSED:
                    logger.info("the robot's program is %s: not played again", state)
                    return
                await control.play_program()
        except (DeviceError, TimeoutError) as err:
            self._failed(
                "could not play the robot's program again after the resume", err, timeout_s
            )
            return
        logger.info("the robot's program played again through the Dashboard Server")

    def _failed(self, what: str, err: BaseException, timeout_s: float) -> None:
        if isinstance(err, DeviceError):
            noted: DeviceError = DeviceError(DEVICE, f"{what}: {err.message}")
        else:  # the whole exchange ran out of time (several Dashboard commands)
            noted = DeviceTimeoutError(DEVICE, f"{what}: no answer within {timeout_s} s")
        logger.warning("%s", noted)
        self.errors.note(noted)
