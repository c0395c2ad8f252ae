"""What an arm run (issue 20) is built from before its first step: the controller's model of
the arm (arm description, duty cycle, thermal model: daemon/arm), its measured poses, the
robot's arm face and the tool's 3-D measurement over the open devices.

The daemon takes these as replaceable callables (``Daemon(arm_setup=..., arm_meter=...)``) so
that its tests can run an arm run on exact fakes; the defaults here build the real ones.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from config import CONFIG_DIR, Settings
from config.inputs import InputError
from daemon.arm.arm_model import ArmModel, load_arm_model, named_arm_model_path
from daemon.arm.controller import ArmModelOptions
from daemon.arm.controller_loading import load_controller
from daemon.arm.run import ArmPredictor, CyclePose, MeasuredPose
from daemon.run.arm.measure import MultiCameraMeter
from daemon.run.arm.robot import GoalRobotArm
from daemon.run.arm.work import ArmRobot, ToolMeter
from daemon.run.devices_check import Devices
from daemon.run.states import RunParameters
from daemon.run.workers import Workers
from daemon.vision.multiview import load_cameras
from drivers.base import GoalRobot, Robot


class ArmSetupError(InputError):
    """The arm run cannot be built (no arm section, a file that does not load)."""


@dataclass(frozen=True, eq=False)
class ArmPlan:
    """The controller's side of an arm run: its model, the poses it corrects, and what is
    recorded with the run of the model it used."""

    predictor: ArmPredictor
    poses: tuple[MeasuredPose, ...]
    snapshot: dict[str, Any] = field(default_factory=dict)
    #: every pose of the duty cycle as the robot plays it (daemon/run/arm/player.py)
    cycle: tuple[CyclePose, ...] = ()


ArmSetup = Callable[[Settings, RunParameters], ArmPlan]
ArmMeterFactory = Callable[[Settings, Devices, Workers], ToolMeter]

#: Preset arm descriptions (wt-kin: config/arms/<name>.toml).
ARMS_DIR = CONFIG_DIR / "arms"


def arm_file(settings: Settings) -> Path:
    """The arm description file: a preset name in config/arms or a path."""
    name = settings.arm.arm_file
    preset = ARMS_DIR / f"{name}.toml"
    return preset if preset.exists() else Path(name)


def plays_duty_cycle(settings: Settings) -> bool:
    """Whether arm runs play the whole duty cycle (arm.play_duty_cycle; unset: on the real
    console only, config/settings.py's description)."""
    play = settings.arm.play_duty_cycle
    return settings.robot.driver == "c500c" if play is None else play


def check_played_run(settings: Settings, parameters: RunParameters, plan: ArmPlan) -> None:
    """A played duty cycle moves the real arm in real time: time_scale 1, and the cycle."""
    if parameters.time_scale != 1.0:
        raise ArmSetupError(
            f"a played duty cycle needs time_scale 1, not {parameters.time_scale:g}: a real "
            "arm cannot be accelerated (set arm.play_duty_cycle = false to measure only)"
        )
    if not plan.cycle:
        raise ArmSetupError("a played duty cycle needs the cycle's poses (the arm setup gave none)")


def check_arm_run(settings: Settings, duty_cycle: str | None) -> None:
    """An arm run needs ``arm.enabled`` and a duty cycle."""
    if not settings.arm.enabled:
        raise ArmSetupError("an arm run (duty_cycle) needs the arm section: set arm.enabled")
    if duty_cycle is None:
        raise ArmSetupError("an arm run needs a duty cycle (run duty_cycle or arm.duty_cycle)")


#: The tool measurement's 1-sigma per axis the adaptation weighs it by (mm): the 3-D meter's
#: ~5 um (benchmarks/bench_arm.py's measured noise) over sqrt(3).
ADAPT_MARKER_SIGMA_MM = 0.003


def adapts(setting: bool | None, model: ArmModel | None, duty_cycle: str) -> tuple[bool, str]:
    """Whether an arm run adapts its factors online, and why (arm.adapt; issue 29): as set,
    else on when its arm model was calibrated on another duty cycle and is not fully
    calibrated. Such a model holds what its cycle could teach, the rest at the preset or
    only in combination; the adaptation starts from it, each of those from the wide prior,
    and learns them on this task (docs/explanation/bench-truth.md, "Transfer with the run
    learning": UR5e 16 of 16 transfers >= 93 % with 4 frames, 11 of 16 without)."""
    if setting is not None:
        return setting, f"arm.adapt = {str(setting).lower()}"
    # a model saved from a run records the run's duty cycle as given: a name or a file
    same_cycle = model is not None and Path(model.duty_cycle).stem == Path(duty_cycle).stem
    if model is None or model.calibrated or not model.duty_cycle or same_cycle:
        return False, "arm.adapt unset: the preset, or a model calibrated for this run"
    return True, (
        f"arm.adapt unset: arm model {model.name!r} was calibrated on {model.duty_cycle!r}, "
        f"this run plays {duty_cycle!r}, and it holds only for its cycle what it could not "
        "identify"
    )


def default_arm_setup(settings: Settings, parameters: RunParameters) -> ArmPlan:
    """The controller's model of the arm from the arm file and the run's duty cycle
    (daemon/arm/controller.py), stepped at the run's step in model time."""
    arm_settings = settings.arm
    assert parameters.duty_cycle is not None
    options = ArmModelOptions(
        motion_dt_s=arm_settings.motion_dt_s,
        ambient_c=settings.model.ambient_c,
        bending=arm_settings.bending,
        motor_side_share=arm_settings.motor_side_share,
        model_dt_s=parameters.step_s * parameters.time_scale,
    )
    identified = None
    if parameters.arm_model is not None:
        path = named_arm_model_path(parameters.arm_model, settings.storage.data_dir)
        identified = load_arm_model(path)
    controller = load_controller(arm_file(settings), parameters.duty_cycle, options, identified)
    if identified is not None and identified.arm != controller.arm.name:
        raise ArmSetupError(
            f"arm model {identified.name!r} was identified on arm {identified.arm!r}, "
            f"this run's arm is {controller.arm.name!r}"
        )
    if parameters.prediction == "model+ir":
        controller.enable_observer(settings.ir.noise_c)
    poses = controller.measured_poses(arm_settings.measured_poses)
    adapt, adapt_reason = adapts(arm_settings.adapt, identified, controller.duty.name)
    if adapt:  # issue 29: the factors estimated online (daemon/arm/adaptation.py)
        controller.enable_adaptation(poses, ADAPT_MARKER_SIGMA_MM, settings.ir.noise_c)
    snapshot = {
        "arm": controller.arm.name,
        "arm_file": str(arm_file(settings)),
        "duty_cycle": controller.duty.name,
        "period_s": controller.duty.period_s,
        "measured_poses": [pose.name for pose in poses],
        "node_names": list(controller.thermal.node_names),
        # over one cycle from its start: the cycle's mean (JointHeatProfile.mean_power_w)
        "mean_joint_heat_w": controller.mean_heat_w(0.0, controller.duty.period_s).tolist(),
        "motion_dt_s": arm_settings.motion_dt_s,
        "ambient_c": settings.model.ambient_c,
        "room": settings.room.driver,  # none: the model holds ambient_c (issue 29)
        "bending": arm_settings.bending,
        "arm_model": None if identified is None else identified.provenance(),
        "prediction": parameters.prediction,
        "adapt": adapt,
        "adapt_reason": adapt_reason,
    }
    cycle = controller.cycle_poses(poses)
    if plays_duty_cycle(settings):
        snapshot["played"] = [
            {
                "pose": c.name,
                "goal": c.pose.name,
                "speed_percent": c.speed_percent,
                "dwell_s": c.dwell_s,
            }
            for c in cycle
        ]
    return ArmPlan(controller, poses, snapshot, cycle)


def default_arm_meter(settings: Settings, devices: Devices, workers: Workers) -> ToolMeter:
    """The tool's measurement from the devices' cameras and their calibrated models (the
    arm's camera file, else the bench's own models)."""
    cameras = tuple(getattr(devices, "cameras", ()) or ())
    if not cameras:
        raise ArmSetupError(
            "an arm run needs the cameras watching the tool: on hardware set "
            "arm.camera_devices and arm.cameras_file, on the bench arm.enabled"
        )
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
    """The robot's arm face (daemon/run/arm/robot.py) over a driver with named taught goals and
    rotated absolute moves; ArmSetupError when the driver has none."""
    if not callable(getattr(robot, "taught_goals", None)):
        raise ArmSetupError(
            f"the robot driver {type(robot).__name__} cannot run an arm duty cycle "
            "(no named taught goals)"
        )
    return GoalRobotArm(cast(GoalRobot, robot))
