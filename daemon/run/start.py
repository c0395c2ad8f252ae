"""What a run is built from when the daemon starts it: its parameters resolved and checked, its
row in the run database, its work, and the services its session is given.

The two-link bench's run: model, admissible scale, reference run and observer
(daemon/run/setup.py). An arm run (issue 20): the arm's plan, its robot face, tool meter,
played duty cycle and step pipeline (daemon/run/arm/setup.py). RunParameterError when the run is
not admissible. Nothing here starts a run or changes a run's state: daemon/service.py builds
under its request lock and daemon/run/session.py runs what was built.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from config import Settings
from daemon import __version__
from daemon.run.arm.player import ArmPlayer
from daemon.run.arm.prepare import ArmServices
from daemon.run.arm.setup import (
    ArmMeterFactory,
    ArmSetup,
    ArmSetupError,
    arm_robot,
    check_arm_run,
    check_played_run,
    plays_duty_cycle,
)
from daemon.run.arm.step import ArmRunWork, ArmStepPipeline
from daemon.run.devices_check import Devices
from daemon.run.events import ErrorLog
from daemon.run.sensors import Sensors
from daemon.run.setup import (
    RunParameterError,
    build_model,
    build_observer,
    check_admissible_scale,
    check_reference_run,
    network_snapshot,
    unit_vector,
)
from daemon.run.states import RunParameters
from daemon.run.two_link.step import RunWork
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder
from drivers.clock import Clock

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class RunBuilder:
    """The daemon's parts a new run is built from (one per start)."""

    settings: Settings
    clock: Clock
    #: the daemon's open devices, read where they are used (RuntimeError once it is closed)
    devices: Callable[[], Devices]
    sensors: Sensors | None  # None until the daemon's devices are open
    workers: Workers
    recorder: Recorder
    errors: ErrorLog
    arm_setup: ArmSetup  # an arm run's model and poses (issue 20)
    arm_meter: ArmMeterFactory  # ... and its tool measurement

    async def create_run(self, parameters: RunParameters, snapshot: dict[str, Any] | None) -> int:
        """The run's row in the run database, with its parameters, settings and ``snapshot``
        (its network or arm model); returns its id."""
        return await self.workers.db(
            self.recorder.create_run,
            parameters.model_dump(mode="json"),
            self.settings.model_dump(mode="json"),
            snapshot,
            __version__,
        )

    async def two_link_work(self, parameters: RunParameters) -> RunWork:
        """The two-link bench's run: its model, checked scale, reference run and observer."""
        workers, recorder = self.workers, self.recorder
        built = await workers.step(build_model, self.settings, parameters)
        parameters, network, model = built.parameters, built.network, built.model
        logger.info("run heat: %s (from %s)", parameters.heat_w, built.heat_source)
        direction = unit_vector(self.settings.model.direction)
        await workers.step(check_admissible_scale, self.settings, parameters, network, direction)
        await workers.db(check_reference_run, recorder, parameters)
        observer = None
        if parameters.prediction == "model+ir":
            reader_regions = tuple(getattr(self.devices().ir, "regions", ()) or ())
            observer = build_observer(self.settings, model, reader_regions)
        run_id = await self.create_run(parameters, network_snapshot(network, built.heat_source))
        return RunWork(run_id, parameters, model, direction, observer)

    async def arm_work(self, parameters: RunParameters) -> tuple[ArmRunWork, ArmServices]:
        """An arm run (issue 20): the arm's model and poses, its robot face, tool meter and
        step pipeline; RunParameterError when the arm run cannot be built."""
        workers, recorder = self.workers, self.recorder
        try:
            check_arm_run(self.settings, parameters.duty_cycle)
            assert parameters.duty_cycle is not None
            plan = await workers.step(self.arm_setup, self.settings, parameters)
            robot = arm_robot(self.devices().robot)
            meter = self.arm_meter(self.settings, self.devices(), workers)
        except (ArmSetupError, ValueError, OSError) as err:
            raise RunParameterError(f"arm run: {err}") from err
        if not plan.poses:
            raise RunParameterError("arm run: the duty cycle has no measured pose")
        played = plays_duty_cycle(self.settings)
        if played:
            try:
                check_played_run(self.settings, parameters, plan)
            except ArmSetupError as err:
                raise RunParameterError(f"arm run: {err}") from err
        elif self.settings.robot.driver != "sim":
            logger.warning(
                "arm run: the duty cycle is not played (arm.play_duty_cycle): the robot moves "
                "to its measured poses only; run the cycle's motion on the controller"
            )
        await workers.db(check_reference_run, recorder, parameters)
        run_id = await self.create_run(parameters, plan.snapshot)
        sensors = self.sensors
        assert sensors is not None
        permit = self.devices().robot.permit
        player = ArmPlayer(robot, plan.cycle, self.clock, run_id, permit) if played else None
        pipeline = ArmStepPipeline(
            self.settings,
            robot=robot,
            meter=meter,
            sensors=sensors,
            recorder=recorder,
            workers=workers,
            errors=self.errors,
            clock_now=self.clock.now,
            player=player,
        )
        work = ArmRunWork(
            run_id, parameters, plan.predictor, plan.poses, cycle=plan.cycle if played else ()
        )
        return work, ArmServices(robot, meter, pipeline, player)
