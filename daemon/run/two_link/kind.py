"""The two-link bench's run kind (daemon/run/kind.py): the thesis's run. One goal taught where
the robot stands (moves nothing: `here opgoal`, thesis 6.4.3), the bench started cold, the spot
at the goal as the reference (thesis 6.2), then one step per period (daemon/run/two_link/step.py:
model -> target check -> move -> measure -> record)."""

from __future__ import annotations

import functools
import logging
import threading
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from config import Settings
from daemon.run.events import ErrorLog
from daemon.run.kind import KindBase, KindView
from daemon.run.scheduler import Tick
from daemon.run.sensors import Sensors
from daemon.run.services import BenchControl
from daemon.run.states import RunParameters
from daemon.run.step import MeasuringStep, StepOutcome
from daemon.run.summary import SummaryBasis, SummaryRow
from daemon.run.two_link.step import StepPipeline
from daemon.run.two_link.summary import two_link_basis, two_link_summary, two_link_summary_rows
from daemon.run.two_link.view import VIEW
from daemon.run.two_link.work import RunWork
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder
from daemon.vision import CentroidError, measure_with_camera_settings
from drivers.base import Robot
from drivers.clock import Clock
from drivers.errors import DeviceError
from drivers.permit import Ticket

logger = logging.getLogger(__name__)


@dataclass(eq=False)
class TwoLinkKind(KindBase):
    title: ClassVar[str] = "a two-link run"
    name: ClassVar[str] = VIEW.name
    view: ClassVar[KindView] = VIEW
    work: RunWork
    pipeline: StepPipeline
    robot: Robot
    sensors: Sensors
    bench: BenchControl | None
    workers: Workers
    settings: Settings
    errors: ErrorLog
    clock: Clock

    @staticmethod
    def reference_hint(parameters: RunParameters) -> str:
        return "an uncompensated run of the two-link bench"

    async def teach(self, *, moving: bool) -> None:
        """The goal where the robot stands: moves nothing, so before the start's release."""
        if not moving:
            self.work.goal = await self.robot.teach_goal()

    async def start_bench(self) -> None:
        """The simulated links start cold with this run, at its scale and procedure: the truth
        built on a worker thread (0.25-0.55 s under load, which on the event loop held up every
        hold behind it; issue 26), the spot aligned on the loop, where the emulated robot
        lives. Nothing reads the bench until the reference frame."""
        bench, parameters = self.bench, self.work.parameters
        if bench is None:
            return
        start = functools.partial(
            bench.start_run,
            self.clock.now(),
            deformation_scale=parameters.deformation_scale,
            procedure=parameters.procedure,
            heater_off_s=parameters.heater_off_s,
        )
        build, align = getattr(bench, "build_run", None), getattr(bench, "align_spot", None)
        if build is None or align is None:
            start()  # a bench with no split (a test's)
            return
        await self.workers.step(functools.partial(build, *start.args, **start.keywords))
        align()

    async def references(self) -> None:
        """The spot at the operational goal before the first move: the zero of every drift.

        Thesis 6.2 sets the centroid "at the start at the operational goal". Taken here, the
        robot has not moved since the goal was taught, so the reference carries no positioning
        error. If no frame can be had, step 0's centroid is used."""
        work = self.work
        try:
            frame = await self.sensors.grab()
            result = await self.workers.step(
                functools.partial(
                    measure_with_camera_settings, camera_gain_e_per_count=frame.gain_e_per_count
                ),
                frame.image,
                self.settings.camera,
            )
        except (DeviceError, CentroidError) as err:
            if isinstance(err, DeviceError):
                self.errors.note(err)
            logger.warning(
                "run %d: no reference frame (%s): step 0 is the reference", work.run_id, err
            )
            return
        work.reference_um[0] = (result.x_um, result.y_um)
        work.reference_source = "goal before the first move"

    async def step(self, tick: Tick) -> StepOutcome | MeasuringStep:
        return await self.pipeline.run(self.work, tick)

    async def resumed(self) -> None:
        """The incremental mode continues from where the robot really is."""
        pose = await self.robot.actual_pose()
        goal = self.work.goal
        if goal is not None:
            self.work.last_target_mm = np.subtract(pose.position, goal.position)

    def play(self, grant: Ticket) -> None:
        """Nothing moves between the steps."""

    async def stop_playing(self, grace_s: float, *, held: bool) -> None:
        """Nothing moves between the steps."""

    def summary_basis(self, *, overruns: int, skipped: int, timing: dict[str, Any]) -> SummaryBasis:
        return two_link_basis(
            self.work, kind=self.name, overruns=overruns, skipped=skipped, timing=timing
        )

    @staticmethod
    def summary_rows(summary: dict[str, Any]) -> list[SummaryRow]:
        return two_link_summary_rows(summary)

    @staticmethod
    def summary_from_basis(
        recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
    ) -> dict[str, Any]:
        return two_link_summary(recorder, basis, abandon)
