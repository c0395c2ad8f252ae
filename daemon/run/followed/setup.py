"""What a followed run (daemon/run/followed/kind.py) is built from: the arm's model of the
program the robot plays (the arm file and the run's duty cycle: daemon/arm/controller.py;
with ``arm_model`` the factors ``calibrate model`` identified on this arm, as an arm run's
``--arm-model``), followed by the robot's joint temperatures
(daemon/arm/joint_temperatures.py)."""

from __future__ import annotations

from config import Settings
from daemon.arm.arm_model import ArmModel, load_arm_model, named_arm_model_path
from daemon.arm.controller import ArmModelOptions
from daemon.arm.controller_loading import load_controller
from daemon.arm.joint_temperatures import JointTemperatureModel
from daemon.run.arm.setup import arm_file
from daemon.run.setup import RunParameterError
from daemon.run.states import RunParameters

#: 1-sigma of a joint temperature reading (degC): the emulator's sensor, 0.05 degC noise and
#: a 1/16 degC resolution (sqrt(0.05^2 + 0.0625^2 / 12)); an ESTIMATE for a real UR, whose
#: sensors' accuracy is not published.
JOINT_SENSOR_NOISE_C = 0.053


def followed_model(settings: Settings, parameters: RunParameters) -> JointTemperatureModel:
    """The model of a followed run; RunParameterError when the run cannot have one. With
    prediction ``model`` the joint temperatures are recorded but not fused (the model alone);
    otherwise they are the model's thermal input."""
    duty = parameters.duty_cycle or settings.arm.duty_cycle
    if not settings.arm.enabled or duty is None:
        raise RunParameterError(
            "a followed run (robot.driver ur-rtde) needs the arm section: arm.enabled, "
            "arm.arm_file and arm.duty_cycle (the program the robot plays)"
        )
    options = ArmModelOptions(
        motion_dt_s=settings.arm.motion_dt_s,
        ambient_c=settings.model.ambient_c,
        bending=settings.arm.bending,
        motor_side_share=settings.arm.motor_side_share,
        model_dt_s=parameters.step_s * parameters.time_scale,
    )
    try:
        identified = _identified(settings, parameters.arm_model)
        controller = load_controller(arm_file(settings), duty, options, identified)
    except (OSError, ValueError) as err:
        raise RunParameterError(f"followed run: {err}") from err
    if identified is not None and identified.arm != controller.arm.name:
        raise RunParameterError(
            f"followed run: arm model {identified.name!r} was identified on arm "
            f"{identified.arm!r}, this run's arm is {controller.arm.name!r}"
        )
    return JointTemperatureModel(
        controller, JOINT_SENSOR_NOISE_C, observe=parameters.prediction != "model"
    )


def _identified(settings: Settings, name: str | None) -> ArmModel | None:
    """The arm model ``name`` in the data directory (``calibrate model --save NAME``), or
    None for the arm's preset."""
    if name is None:
        return None
    return load_arm_model(named_arm_model_path(name, settings.storage.data_dir))
