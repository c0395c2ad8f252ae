"""The controller's model of the arm during a duty cycle (issue 20): the ArmPredictor of an arm
run (daemon/arm_step.py). Pure.

Each advance takes the motor heat of the duty cycle's *commanded* motion over the interval
(the duty cycle's joint positions, speeds and accelerations on ``motion_dt_s``, the joint
torques they need, each joint's motor and gearbox losses: daemon/arm/motors.py, integrated
once per cycle by daemon/arm/heat.py JointHeatProfile), holds its mean power over the
interval (a zero-order hold of the interval's mean: it carries the interval's energy
exactly) and advances the arm's thermal network (daemon/arm/thermal.py). The tool error at
a measured pose is kinematics.tool_error at that pose's joint angles with the links' current
thermal states.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from daemon.arm.description import Arm, load_arm
from daemon.arm.duty import DutyCycle, load_duty_cycle
from daemon.arm.heat import JointHeatProfile
from daemon.arm.kinematics import forward, inverse, tool_error
from daemon.arm.run import FloatArray, MeasuredPose
from daemon.arm.thermal import ArmThermalModel
from daemon.arm.types import Pose6


@dataclass(frozen=True, slots=True)
class ArmModelOptions:
    motion_dt_s: float = 0.05  # the duty cycle's motion samples for motor heat (s)
    ambient_c: float = 22.0
    bending: bool = False
    node_spacing_mm: float = 50.0
    model_dt_s: float = 1.0  # the thermal model's step (its stepper is exact: any dt)


class ArmController:
    """The arm's model advanced by the duty cycle's motion (module docstring)."""

    def __init__(
        self,
        arm: Arm,
        duty: DutyCycle,
        options: ArmModelOptions = ArmModelOptions(),
        *,
        heat: JointHeatProfile | None = None,
        thermal: ArmThermalModel | None = None,
    ) -> None:
        self.arm = arm
        self.duty = duty
        self.options = options
        self.heat = heat or JointHeatProfile.from_duty(arm, duty, resolution_s=options.motion_dt_s)
        self.thermal = thermal or ArmThermalModel(
            arm,
            node_spacing_mm=options.node_spacing_mm,
            ambient_c=options.ambient_c,
            dt_s=options.model_dt_s,
        )
        self.last_heat_w: FloatArray = np.zeros(len(arm.joints))

    @property
    def time_s(self) -> float:
        return float(self.thermal.time_s)

    def mean_heat_w(self, start_s: float, end_s: float) -> FloatArray:
        """Each joint's mean motor heat (W) over ``[start_s, end_s]`` of the duty cycle."""
        return self.heat.step_power_w(start_s, end_s)

    def advance_to(self, t_s: float) -> None:
        start = self.time_s
        if t_s <= start:
            return
        self.last_heat_w = self.mean_heat_w(start, t_s)
        self.thermal.advance_to(t_s, self.last_heat_w)

    def tool_error(self, pose: MeasuredPose) -> Pose6:
        return tool_error(
            self.arm, pose.q_rad, self.thermal.link_states(), bending=self.options.bending
        )

    def temperatures_c(self) -> Mapping[str, float]:
        return dict(zip(self.thermal.node_names, self.thermal.temperatures_c.tolist(), strict=True))

    def measured_poses(self, names: tuple[str, ...] = ()) -> tuple[MeasuredPose, ...]:
        """The duty cycle's measured poses (``names``: these poses instead, in that order),
        each with the cold arm's tool pose at its joint angles."""
        by_name = {pose.name: pose for pose in self.duty.poses}
        if names:
            unknown = [name for name in names if name not in by_name]
            if unknown:
                raise ValueError(
                    f"arm.measured_poses names {unknown}, not poses of the duty cycle "
                    f"({', '.join(by_name)})"
                )
            chosen = [by_name[name] for name in names]
        else:
            chosen = list(self.duty.measured_poses())
        return tuple(
            MeasuredPose(pose.name, np.array(pose.q_rad), forward(self.arm, pose.q_rad))
            for pose in chosen
        )


def load_controller(
    arm_path: str | Path, duty_cycle: str | Path, options: ArmModelOptions
) -> ArmController:
    """The arm file and the duty cycle (tool poses in the file are solved on this arm)."""
    arm = load_arm(arm_path)

    def solve(pose: FloatArray, seed: FloatArray) -> FloatArray:
        return inverse(arm, pose, seed)

    duty = load_duty_cycle(duty_cycle, solve)
    if duty.joint_count != len(arm.joints):
        raise ValueError(
            f"duty cycle {duty.name!r} has {duty.joint_count} joints, arm {arm.name!r} "
            f"{len(arm.joints)}"
        )
    return ArmController(arm, duty, options)
