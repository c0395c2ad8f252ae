"""The duty cycle's player (issue 20): the robot runs its program of taught poses for the whole
arm run, as the arm would in production, and its motion heats the motors.

Each pose in the cycle's order: the move to its taught goal plus the latest correction the
step pipeline checked for that pose (daemon/run/arm/step.py: the correction of each taught pose at
its own configuration, checked against the arm.max_* limits before it is handed here; a refused
one never is), at the pose's speed (the console's `speed N`, sent by the driver only when it
changes; the acceleration is the controller's own: docs/reference/c500c-console.md has no command
for it), then the pose's dwell on the run clock. A step that measures a pose names it first
(:meth:`expect`, before its model runs); the move into that pose waits until the step has handed
over its corrections (:meth:`ready`); when the robot is there (:meth:`arrive`) the step measures the
tool during the dwell, and the player waits for the step (:meth:`release`) before it moves on, so
the robot never moves under a measurement.

The player owns no run state: daemon/run/session.py starts it when the run runs and stops it on a
pause, a fault and the end (:meth:`stop` lets a move already written end: cutting a console
move mid-exchange would hold the robot and dirty the link; the console cannot halt a motion
anyway, docs/reference/c500c-console.md), and restarts it on a resume from the pose after the last
one reached. An error (a DeviceError, a move refused after a hold) ends the playing; the next step's
:meth:`arrive` raises it, so it reaches the run through that step's verdict. The hold contract
is the driver's: after ``robot.stop()`` every move is refused right before its bytes are
written, so no move of the cycle reaches the robot after a hold.

On a virtual clock (the bench) the player paces it (drivers/clock.py VirtualClock.pacing):
the time moves with the cycle's moves and dwells, and the run's steps follow it. There a step
that has named its pose holds back EVERY move until its corrections are handed over, not only
the move into its pose: its model takes no run time (nobody else moves the time meanwhile), so
which moves carry the new corrections — and so the motion that heats the bench's motors — is
the same whatever its worker thread's speed (issue 27: a played run on a virtual clock is
reproducible from its seeds). On a real clock the robot's program keeps its pace: the moves
started while the model runs carry the previous corrections.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Protocol

from daemon.arm.run import CyclePose, MeasuredPose
from daemon.arm.types import Pose6
from drivers.base import MoveResult
from drivers.clock import Clock
from drivers.errors import DeviceError, MotionHeldError
from drivers.permit import MotionPermit, Ticket

logger = logging.getLogger(__name__)


class PlayingRobot(Protocol):
    """What the player needs of the robot (daemon/run/arm/robot.py GoalRobotArm)."""

    async def move_to_goal(
        self, goal: str, correction: Pose6, *, speed_percent: int | None = None
    ) -> MoveResult: ...


class PlayerStoppedError(DeviceError):
    """The cycle stopped playing while a step waited for a pose."""

    def __init__(self, message: str) -> None:
        super().__init__("robot", message)


@dataclass(frozen=True, slots=True)
class Arrival:
    """The robot at a measured pose: the move's result, the correction it was sent with, when
    it arrived (run clock)."""

    result: MoveResult
    correction: Pose6
    arrived_s: float


@dataclass(eq=False)
class _Request:
    name: str
    arrived: asyncio.Future[Arrival]
    ready: asyncio.Event = field(default_factory=asyncio.Event)  # the step's corrections in
    released: asyncio.Event = field(default_factory=asyncio.Event)


class ArmPlayer:
    """Plays ``cycle`` on ``robot`` (module docstring)."""

    def __init__(
        self,
        robot: PlayingRobot,
        cycle: tuple[CyclePose, ...],
        clock: Clock,
        run_id: int,
        permit: MotionPermit,
    ) -> None:
        if not cycle:
            raise ValueError("a duty cycle to play needs poses")
        self.cycle = cycle
        self._robot = robot
        self._permit = permit  # the robot's (drivers/permit.py): read before each move
        self._grant: Ticket | None = None  # the request this playing is for (start())
        self._clock = clock
        self._run_id = run_id
        self._corrections: dict[str, Pose6] = {}
        #: the correction of the latest move into each cycle pose that the robot made: the
        #: step limits apply against it (daemon/run/arm/step.py), not against the latest one
        #: handed over, which the robot may not have been sent yet (issue 26)
        self._sent: dict[str, Pose6] = {}
        self.next_index = 0  # the pose the next move goes to
        self.moves = 0
        self.error: DeviceError | None = None
        self._task: asyncio.Task[None] | None = None
        self._request: _Request | None = None
        self._moving = False
        self._stopping = False

    @property
    def playing(self) -> bool:
        return self._task is not None and not self._task.done()

    def teach_poses(self) -> tuple[MeasuredPose, ...]:
        """Every pose of the cycle to teach, each goal once."""
        seen: dict[str, MeasuredPose] = {}
        for entry in self.cycle:
            seen.setdefault(entry.pose.name, entry.pose)
        return tuple(seen.values())

    def set_corrections(self, corrections: Mapping[str, Pose6]) -> None:
        """The latest checked corrections by cycle pose name (daemon/run/arm/step.py); a pose not
        named keeps its previous one."""
        self._corrections.update(corrections)

    def correction(self, name: str) -> Pose6:
        return self._corrections.get(name, Pose6.zero())

    def sent_correction(self, name: str) -> Pose6:
        """The correction the robot last moved into the cycle pose ``name`` with (zero: only
        taught so far)."""
        return self._sent.get(name, Pose6.zero())

    # --- the session's side --------------------------------------------------------------

    def start(self, grant: Ticket) -> None:
        """Play from the pose after the last one reached (a resume), or the first, on behalf
        of the request that took ``grant``: the playing ends at the first move after a hold
        that came after it. Not while an error is pending: a step reports it first (the run
        faults), and :meth:`stop` clears it; a restart here would let the robot go on as if
        nothing had happened."""
        if self.playing or self.error is not None:
            return
        self._grant = grant
        self._stopping = False
        self._task = asyncio.get_running_loop().create_task(
            self._play(), name=f"run-{self._run_id}-duty-cycle"
        )

    async def stop(self, grace_s: float | None = None) -> None:
        """Stop playing: now in a dwell or a wait; otherwise once the move being written has
        ended, or after ``grace_s`` (a move waiting for the operator's PAUSE/CONTINUE may wait
        minutes): then it is cut, which holds the robot (drivers/c500c/link.py)."""
        task = self._task
        if task is None:
            self.error = None
            return
        self._stopping = True
        if not self._moving:
            task.cancel()
        _, pending = await asyncio.wait({task}, timeout=grace_s)
        if pending:
            logger.warning("run %d: cutting the duty cycle's move to stop", self._run_id)
            task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        self._task = None
        self.error = None  # the run paused or faulted: a resume is the operator's decision

    # --- the step's side -----------------------------------------------------------------

    def expect(self, name: str) -> None:
        """A step will measure at the cycle pose ``name``: the move into it waits until the
        step's corrections are handed over (:meth:`ready`), so that it carries them (and,
        on a virtual clock, so that which arrival a step measures does not depend on how long
        its model took on a worker thread); on a paced clock every move waits for them
        (module docstring). :meth:`release` withdraws it."""
        self.release()
        self._request = _Request(name, asyncio.get_running_loop().create_future())

    def ready(self) -> None:
        """The step's corrections are handed over: the move into its pose may start."""
        if self._request is not None:
            self._request.ready.set()

    async def arrive(self, name: str) -> Arrival:
        """Wait until the robot has arrived at the cycle pose ``name`` (its next arrival);
        the robot stays there until :meth:`release`. Raises the player's error."""
        if self.error is not None:
            raise self.error
        if not self.playing:
            raise PlayerStoppedError("the duty cycle is not playing")
        request = self._request
        if request is None or request.name != name:
            self.expect(name)
            request = self._request
            assert request is not None
        request.ready.set()
        try:
            return await request.arrived
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        """The step is done at the pose (or withdraws its request): the player may go on."""
        request, self._request = self._request, None
        if request is not None:
            request.ready.set()
            request.released.set()
            if not request.arrived.done():
                request.arrived.cancel()

    # --- the playing ---------------------------------------------------------------------

    @contextlib.contextmanager
    def _paced(self) -> Iterator[None]:
        pacing = getattr(self._clock, "pacing", None)
        if pacing is None:
            yield
        else:
            with pacing():
                yield

    async def _play(self) -> None:
        clock, count = self._clock, len(self.cycle)
        # a paced clock stands still while we wait: every move waits for a named step's
        # corrections (module docstring), a real clock's only the move into its pose
        paced = getattr(clock, "pacing", None) is not None
        logger.info("run %d: playing the duty cycle from pose %d", self._run_id, self.next_index)
        try:
            with self._paced():
                while not self._stopping:
                    entry = self.cycle[self.next_index]
                    request = self._request
                    if request is not None and (paced or request.name == entry.name):
                        await request.ready.wait()  # the move carries the step's corrections
                    correction = self.correction(entry.name)
                    # no move after a hold that came after this playing's request (the driver
                    # refuses it too, under its lock: this ends the playing at once)
                    self._permit.require(self._grant)
                    self._moving = True
                    try:
                        result = await self._robot.move_to_goal(
                            entry.pose.name, correction, speed_percent=entry.speed_percent
                        )
                    finally:
                        self._moving = False
                    self._sent[entry.name] = correction
                    arrived_s = clock.now()
                    self.next_index = (self.next_index + 1) % count
                    self.moves += 1
                    request = self._request
                    if request is not None and request.name == entry.name:
                        if not request.arrived.done():
                            request.arrived.set_result(Arrival(result, correction, arrived_s))
                        await request.released.wait()  # the step measures during the dwell
                    if self._stopping:
                        break
                    await clock.sleep_until(arrived_s + entry.dwell_s)
        except DeviceError as err:
            self.error = err
            # after a hold (a pause, the run's end) a refused move is how the playing ends
            log = logger.info if isinstance(err, MotionHeldError) else logger.warning
            log("run %d: the duty cycle stopped: %s", self._run_id, err)
        except Exception as err:  # a bug: the run learns it at its next step, not never
            logger.exception("run %d: the duty cycle's player failed", self._run_id)
            self.error = PlayerStoppedError(f"the duty cycle's player failed: {err!r}")
        finally:
            request = self._request
            if request is not None and not request.arrived.done():
                request.arrived.set_exception(
                    self.error or PlayerStoppedError("the duty cycle stopped playing")
                )
