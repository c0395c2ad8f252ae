"""A followed run built (daemon/run/kinds.py chose it: the robot plays its own program): the
arm's model of that program (daemon/run/followed/setup.py), the run's row in the run database,
the bench truth when the UR bench is simulated, and the pause of the robot's program on a
hold (robot.pause_program_on_hold: daemon/run/followed/program_pause.py), the motor heat of
the motion the robot makes (arm.heat_from measured: daemon/run/followed/heat.py), and the tool
cameras' measurement at the program's dwells when the devices have tool cameras
(daemon/run/followed/measure.py; none: a run by the model and the joint temperatures).
RunParameterError when it cannot be built."""

from __future__ import annotations

import functools
import logging
from pathlib import Path
from typing import Any

import numpy as np

from config import Settings
from daemon.arm import kinematics
from daemon.arm.joint_temperatures import JointTemperatureModel
from daemon.arm.loading import load_arm
from daemon.arm.types import FloatArray
from daemon.run.arm.measure import MultiCameraMeter
from daemon.run.arm.setup import arm_file
from daemon.run.followed.heat import (
    DUTY_CYCLE,
    MEASURED,
    FollowedHeat,
    MotionFeed,
)
from daemon.run.followed.kind import BenchTruth, FollowedKind, FollowedWork
from daemon.run.followed.measure import DwellHold, DwellMeasurement
from daemon.run.followed.program_pause import ProgramPause
from daemon.run.followed.setup import followed_model
from daemon.run.setup import RunParameterError
from daemon.run.start import RunBuilder
from daemon.run.states import RunParameters
from daemon.vision.cameras import CameraFileError, load_cameras
from drivers.base import OffsetRobot, ProgramControl

logger = logging.getLogger(__name__)

#: Why a followed run does not adapt (arm.adapt, issue 29): its model follows the joint
#: temperatures through a Kalman filter on the nodes (daemon/arm/joint_temperatures.py) and
#: feeds no tool measurement to the online estimate of the factors (daemon/arm/adaptation.py),
#: which only an A465 arm run's step does (daemon/run/arm/step.py).
NOT_ADAPTING = (
    "arm.adapt is not honoured by a followed run (a robot that plays its own program): the "
    "factors stay the arm model's (or the preset's); only an arm run adapts them"
)


async def build_followed(
    builder: RunBuilder, parameters: RunParameters, robot: OffsetRobot
) -> FollowedKind:
    model = await builder.workers.step(followed_model, builder.settings, parameters)
    devices = builder.devices()
    truth: BenchTruth | None = getattr(devices, "ur_truth", None)
    measurement = await _measurement(builder, devices, robot, truth)
    identified = model.controller.identified  # the arm model (calibrate model), or None
    snapshot: dict[str, Any] = {
        "kind": FollowedKind.name,
        "arm_model": None if identified is None else identified.provenance(),
    }
    heat, heat_note = _heat(builder.settings, model, robot)
    snapshot["heat_from"] = MEASURED if heat is not None else DUTY_CYCLE
    if builder.settings.arm.adapt:  # said, not silently ignored (NOT_ADAPTING)
        snapshot["adapt"] = False
        snapshot["adapt_note"] = NOT_ADAPTING
        logger.warning("followed run: %s", NOT_ADAPTING)
    run_id = await builder.create_run(parameters, snapshot, kind=FollowedKind.name)
    return FollowedKind(
        FollowedWork(run_id, parameters),
        robot,
        builder.recorder,
        builder.workers,
        builder.settings,
        builder.errors,
        builder.clock,
        model,
        truth,
        ProgramPause(
            robot if isinstance(robot, ProgramControl) else None,
            enabled=builder.settings.robot.pause_program_on_hold,
            errors=builder.errors,
        ),
        measurement,
        builder.sensors,
        heat,
        heat_note,
    )


def _heat(
    settings: Settings, model: JointTemperatureModel, robot: OffsetRobot
) -> tuple[FollowedHeat | None, str]:
    """The measured motor heat (arm.heat_from measured, a robot that logs its motion), its
    record made the model's heat source; else None and why the duty cycle's heat is used."""
    if settings.arm.heat_from == DUTY_CYCLE:
        return None, "arm.heat_from is duty-cycle"
    if not isinstance(robot, MotionFeed):
        note = "the robot logs no motion: the duty cycle's heat"
        logger.warning("followed run: %s", note)
        return None, note
    return FollowedHeat.on(model.controller, robot), ""


async def _measurement(
    builder: RunBuilder, devices: Any, robot: OffsetRobot, truth: BenchTruth | None
) -> DwellMeasurement | None:
    """The tool cameras' measurement (the arm run's meter on the devices' tool cameras and
    their models: arm.cameras_file when set, e.g. the one `calibrate cameras --robot` wrote,
    else the devices' own, as an A465 arm run's daemon/run/arm/setup.py), or None when the
    devices have no tool camera."""
    cameras = tuple(getattr(devices, "cameras", ()) or ())
    if not cameras:
        return None
    cameras_file = builder.settings.arm.cameras_file
    if cameras_file is None:
        models = tuple(getattr(devices, "camera_models", ()) or ())
    else:
        try:
            models = tuple(await builder.workers.step(load_cameras, Path(cameras_file)))
        except CameraFileError as err:
            raise RunParameterError(f"arm.cameras_file: {err}") from err
    if len(models) != len(cameras):
        raise RunParameterError(
            f"{len(cameras)} tool cameras but {len(models)} camera models "
            f"(arm.cameras_file {cameras_file}): one model per camera, same order"
        )
    arm = await builder.workers.step(load_arm, arm_file(builder.settings))

    def truth_residual_mm() -> FloatArray:
        assert truth is not None
        return np.asarray(truth.errors().residual.translation_mm, dtype=np.float64)

    return DwellMeasurement(
        MultiCameraMeter(builder.settings, cameras, models, builder.workers),
        functools.partial(kinematics.forward, arm),
        robot.robot_state,
        len(cameras),
        truth=None if truth is None else truth_residual_mm,
        hold=robot if isinstance(robot, DwellHold) else None,
    )
