"""Loading an arm controller (daemon/arm/controller.py): the arm file and a duty cycle taught
on it, and the goal names a duty cycle's poses get on a controller. Pure."""

from __future__ import annotations

from pathlib import Path

from daemon.arm.arm_model import ArmModel
from daemon.arm.controller import ArmController, ArmModelOptions
from daemon.arm.description import Arm
from daemon.arm.duty import DutyCycle, check_taught_on, load_duty_cycle
from daemon.arm.kinematics import inverse
from daemon.arm.loading import load_arm
from daemon.arm.run import FloatArray


def load_controller(
    arm_path: str | Path,
    duty_cycle: str | Path,
    options: ArmModelOptions,
    identified: ArmModel | None = None,
) -> ArmController:
    """The arm file and the duty cycle (tool poses in the file are solved on this arm)."""
    arm, duty = load_arm_and_duty(arm_path, duty_cycle)
    return ArmController(arm, duty, options, identified=identified)


def load_arm_and_duty(arm_path: str | Path, duty_cycle: str | Path) -> tuple[Arm, DutyCycle]:
    """The arm file and a duty cycle taught on it (tool poses in the file solved on this arm);
    ArmError or DutyCycleError in one line (``check_taught_on``)."""
    arm = load_arm(arm_path)
    return arm, load_duty_on(arm, arm_path, duty_cycle)


def load_duty_on(arm: Arm, arm_path: str | Path, duty_cycle: str | Path) -> DutyCycle:
    """A duty cycle taught on ``arm`` (loaded from ``arm_path``): its tool poses solved on
    it; DutyCycleError in one line (``check_taught_on``)."""

    def solve(pose: FloatArray, seed: FloatArray) -> FloatArray:
        return inverse(arm, pose, seed)

    duty = load_duty_cycle(duty_cycle, solve)
    check_taught_on(duty, arm, arm_path)
    return duty
