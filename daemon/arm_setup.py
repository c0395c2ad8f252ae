"""What an arm run (issue 20) is built from before its first step: the controller's model of
the arm (arm description, duty cycle, thermal model: daemon/arm), its measured poses, the
robot's arm face and the tool's 3-D measurement over the open devices.

The daemon takes these as replaceable callables (``Daemon(arm_setup=..., arm_meter=...)``) so
that its tests can run an arm run on exact fakes; the defaults here build the real ones.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from config import CONFIG_DIR, Settings
from daemon.arm.run import ArmPredictor, MeasuredPose
from daemon.arm_step import ArmRobot, ToolMeter
from daemon.devices_check import Devices
from daemon.workers import Workers
from drivers.base import Robot


class ArmSetupError(ValueError):
    """The arm run cannot be built (no arm section, a file that does not load)."""


@dataclass(frozen=True, eq=False)
class ArmPlan:
    """The controller's side of an arm run: its model, the poses it corrects, and what is
    recorded with the run of the model it used."""

    predictor: ArmPredictor
    poses: tuple[MeasuredPose, ...]
    snapshot: dict[str, Any] = field(default_factory=dict)


ArmSetup = Callable[[Settings, str], ArmPlan]
ArmMeterFactory = Callable[[Settings, Devices, Workers], ToolMeter]

#: Preset arm descriptions (wt-kin: config/arms/<name>.toml).
ARMS_DIR = CONFIG_DIR / "arms"


def arm_file(settings: Settings) -> Path:
    """The arm description file: a preset name in config/arms or a path."""
    name = settings.arm.arm_file
    preset = ARMS_DIR / f"{name}.toml"
    return preset if preset.exists() else Path(name)


def check_arm_run(settings: Settings, duty_cycle: str | None) -> None:
    """An arm run needs ``arm.enabled`` and a duty cycle."""
    if not settings.arm.enabled:
        raise ArmSetupError("an arm run (duty_cycle) needs the arm section: set arm.enabled")
    if duty_cycle is None:
        raise ArmSetupError("an arm run needs a duty cycle (run duty_cycle or arm.duty_cycle)")


def default_arm_setup(settings: Settings, duty_cycle: str) -> ArmPlan:
    """The controller's model of the arm from the arm file and the duty cycle (daemon/arm:
    kinematics, motors, thermal, duty)."""
    try:
        controller = importlib.import_module("daemon.arm.controller")
    except ImportError as err:
        raise ArmSetupError(f"the arm model is not available: {err}") from err
    build = cast(Callable[[Settings, Path, str], ArmPlan], controller.build_arm_plan)
    return build(settings, arm_file(settings), duty_cycle)


def default_arm_meter(settings: Settings, devices: Devices, workers: Workers) -> ToolMeter:
    """The tool's measurement from the devices' cameras and their calibrated models (the
    arm's camera file, else the bench's own models)."""
    from daemon.arm_measure import MultiCameraMeter
    from daemon.vision.multiview import load_cameras

    cameras = tuple(getattr(devices, "cameras", ()) or ())
    if not cameras:
        raise ArmSetupError("an arm run needs the arm's cameras (drivers.factory: arm.enabled)")
    cameras_file = settings.arm.cameras_file
    if cameras_file is not None:
        models = tuple(load_cameras(Path(cameras_file)))
    else:
        models = tuple(getattr(devices, "camera_models", ()) or ())
    if len(models) != len(cameras):
        raise ArmSetupError(
            f"{len(cameras)} cameras but {len(models)} camera models: set arm.cameras_file"
        )
    return MultiCameraMeter(settings, cameras, models, workers)


def arm_robot(robot: Robot) -> ArmRobot:
    """The robot's arm face (named goals, moves with a rotation); ArmSetupError when the
    driver has none."""
    for method in ("teach_pose", "move_to_goal"):
        if not callable(getattr(robot, method, None)):
            raise ArmSetupError(
                f"the robot driver {type(robot).__name__} cannot run an arm duty cycle "
                f"(no {method})"
            )
    return cast(ArmRobot, robot)
