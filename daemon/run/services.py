"""What the daemon gives every run's session (daemon/run/session.py), whatever its kind: the
robot's hold (its permit), the workers, the recorder and the outlets -- the event bus, the read
model the API reads, the end kept when it cannot be written. What a kind needs beyond this (its
devices, step pipeline, bench) is the kind's own (daemon/run/kind.py, built by
daemon/run/kinds.py). No callbacks into the daemon's façade (issue 27).

Values only: the run's state changes in RunSession alone (issue 15)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from config import Settings
from daemon.run.events import ErrorLog, EventBus
from daemon.run.gc_policy import GcPolicy
from daemon.run.readmodel import RunReadModel
from daemon.run.scheduler import TimingStats
from daemon.run.unrecorded_end import UnrecordedEnd
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder
from daemon.storage.report_queue import ReportQueue
from drivers.base import RobotStatus
from drivers.permit import MotionPermit, Ticket


class BenchControl(Protocol):
    """What a run tells the simulated bench (drivers.sim.bench.Bench) when it starts."""

    def start_run(
        self,
        t_s: float,
        *,
        deformation_scale: float | None = None,
        procedure: str | None = None,
        heater_off_s: float | None = None,
    ) -> None: ...


class HeldRobot(Protocol):
    """What the session needs of any robot (drivers/base.py Robot and OffsetRobot): its hold."""

    @property
    def permit(self) -> MotionPermit: ...

    async def stop(self) -> None: ...

    async def resume(self, ticket: Ticket | None = None) -> None: ...

    def status(self) -> RobotStatus: ...


@dataclass(frozen=True, slots=True)
class SessionServices:
    """What every run uses of the daemon."""

    settings: Settings
    robot: HeldRobot
    recorder: Recorder
    workers: Workers
    bus: EventBus
    errors: ErrorLog
    timing: TimingStats
    reports: ReportQueue
    read_model: RunReadModel  # the API's view of the run, and the control loop's liveness
    unrecorded_end: UnrecordedEnd  # an end the disk could not take, written again later
    #: runs a call on the API's loop, which owns the report queue and the unrecorded end
    #: (ControlLoop.post_home: the session runs on the control loop's thread)
    post_home: Callable[[Callable[[], None]], None] = field(default=lambda call: call())
    #: a hold request has held the permit and its pause or stop has not yet reached the run
    #: (it comes from the API's thread: a step refused meanwhile is not the run's fault)
    hold_pending: Callable[[], bool] = field(default=lambda: False)
    #: full garbage collections between the steps (the daemon's one, for the whole process)
    gc_policy: GcPolicy = field(default_factory=lambda: GcPolicy(enabled=False))
