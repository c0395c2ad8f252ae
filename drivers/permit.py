"""The one owner of "may the robot move" (issue 26): a hold is a fact that only a request made
after it undoes.

Every hold -- a request (``POST /robot/stop``, a pause, a stop, the daemon's shutdown), a run's
fault, a link fault inside a driver -- calls :meth:`MotionPermit.hold`, which is synchronous:
the generation is bumped and motion is refused before the caller awaits anything. A request
that may release a hold (a run's start, a resume) takes a :class:`Ticket` when it *arrives*
(the API samples it before reading the body: api/tickets.py), carries it through every await
(the run's build, the database, the request lock) and releases the hold with it:
:meth:`release` refuses a ticket older than the latest hold. So a hold answered to the operator
can never be undone by a start or resume that was already in flight.

The drivers read the permit under their write lock, right before a motion command's bytes are
written (:meth:`require`), and the run (daemon/run/session.py) and the duty cycle's player read
it between their phases, so they stop early instead of trying moves the driver would refuse.
There is one permit per robot driver (``robot.permit``); nothing else keeps a copy of "held".

A hold may come from another thread than the driver's (the API's loop, while the driver lives
on the control loop's thread: daemon/run/control_loop.py). The drivers therefore check and
write inside :meth:`guard`, and :meth:`hold` takes the same lock: a hold either comes before the
check (the motion is refused) or after the bytes were handed to the port (the driver's HOLD
then follows them), never in between.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator
from dataclasses import dataclass

from drivers.errors import MotionHeldError

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Ticket:
    """The permit's generation when a request arrived: what that request may release."""

    generation: int


class MotionPermit:
    """Held or not, why, and how many holds there were (the generation)."""

    def __init__(self, device: str = "robot", *, held: bool = False, reason: str | None = None):
        self.device = device
        self._generation = 0
        self._held = held
        self._reason = reason if held else None
        self._lock = threading.RLock()  # hold() against a driver's check-then-write

    @property
    def generation(self) -> int:
        """Bumped by every hold: a ticket from before a hold releases nothing."""
        return self._generation

    @property
    def held(self) -> bool:
        return self._held

    @property
    def reason(self) -> str | None:
        """Why motion is held (the first hold since the last release); None when not held."""
        return self._reason if self._held else None

    def hold(self, reason: str) -> None:
        """Refuse motion from now on (synchronous: no await before or in here)."""
        with self._lock:
            self._generation += 1
            if not self._held:
                self._reason = reason
            self._held = True

    @contextlib.contextmanager
    def guard(self, motion: bool = True, ticket: Ticket | None = None) -> Iterator[None]:
        """For a driver: ``require`` (when ``motion``; else only ``ticket`` is checked) and the
        write inside, atomic against a :meth:`hold` from any thread. Only around synchronous
        code (no await inside)."""
        with self._lock:
            if motion:
                self.require(ticket)
            elif ticket is not None and not self.is_current(ticket):
                raise MotionHeldError(self.device, "a hold came after this request was made")
            yield

    def ticket(self) -> Ticket:
        """Take when a request that may release a hold arrives, before anything is awaited."""
        return Ticket(self._generation)

    def is_current(self, ticket: Ticket) -> bool:
        """No hold came after ``ticket`` was taken."""
        return ticket.generation == self._generation

    def release(self, ticket: Ticket) -> None:
        """Allow motion again on behalf of the request that took ``ticket``; MotionHeldError
        (the hold stays) when a hold came after that request arrived."""
        with self._lock:
            if ticket.generation != self._generation:
                raise MotionHeldError(
                    self.device,
                    f"held after the request was made, stays held: {self._reason or 'a hold'}",
                )
            if self._held:
                logger.info("robot motion released")
            self._held = False
            self._reason = None

    def require(self, ticket: Ticket | None = None) -> None:
        """Raise MotionHeldError when motion is held, or when ``ticket`` (the motion's own
        request) is older than the latest hold. Drivers call this under their write lock
        right before a motion command's bytes are written."""
        if self._held:
            raise MotionHeldError(self.device, f"motion is held until resume(): {self._reason}")
        if ticket is not None and ticket.generation != self._generation:
            raise MotionHeldError(self.device, "a hold came after this motion was requested")
