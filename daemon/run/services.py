"""What the daemon gives a run's session (daemon/run/session.py): its devices, workers, recorder
and outlets, the simulated bench it starts, and an arm run's own services (issue 20).

Values only: the run's state changes in RunSession alone (issue 15)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from config import Settings
from daemon.run.arm.prepare import ArmServices
from daemon.run.events import ErrorLog, EventBus
from daemon.run.readmodel import RunView
from daemon.run.scheduler import TimingStats
from daemon.run.sensors import Sensors
from daemon.run.two_link.step import StepPipeline
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder
from daemon.storage.report_queue import ReportQueue
from drivers.base import Robot
from drivers.clock import Clock


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


@dataclass(frozen=True, slots=True)
class SessionServices:
    """What a run uses of the daemon: its devices, workers, recorder and outlets."""

    settings: Settings
    clock: Clock
    robot: Robot
    sensors: Sensors
    bench: BenchControl | None
    pipeline: StepPipeline
    recorder: Recorder
    workers: Workers
    bus: EventBus
    errors: ErrorLog
    timing: TimingStats
    reports: ReportQueue
    on_view: Callable[[RunView], None]  # the daemon's read model
    on_progress: Callable[[], None]  # the control loop is alive (systemd watchdog)
    on_unrecorded_end: Callable[[int, str, dict[str, Any] | None, str | None], None]
    arm: ArmServices | None = None  # an arm run's robot, tool meter and step (issue 20)

    def arm_services(self) -> ArmServices:
        """An arm run's services; a RuntimeError for an arm run built without them (a bug)."""
        if self.arm is None:
            raise RuntimeError("an arm run without the arm's services")
        return self.arm
