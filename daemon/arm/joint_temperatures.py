"""Joint temperatures as the arm model's thermal input (issue 31): a robot that reports one
temperature per joint (a UR's ``joint_temperatures`` over RTDE) gives the arm observer what
the IR regions give it on the A465, with no camera.

Each joint's sensor is read as a measurement of that joint's heat node (the node the joint's
motor and gearbox losses go into: daemon/arm/thermal.py ``joint_node_names``), through
daemon.model.observer's Kalman filter, each with an unknown constant offset (the sensor sits
on the motor housing, not in the node's mean: its prior JOINT_OFFSET_SIGMA_C). The model is
the arm's (daemon/arm/controller.py: the program's duty cycle gives the motor heat between two
readings); the tool error is computed at any configuration -- the robot's current joints --
not only at the duty cycle's measured poses. Pure.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from daemon.arm.controller import ArmController
from daemon.arm.kinematics import tool_error
from daemon.arm.run import FloatArray
from daemon.arm.types import Pose6

#: A joint sensor's region name in the observer: joint1 .. jointN (base to tool).
JOINT_REGION = "joint{}"
#: Prior 1-sigma of a joint sensor's offset from its heat node's temperature (degC): an
#: ESTIMATE (UR publishes neither the sensor's place nor its accuracy); the observer refines it.
JOINT_OFFSET_SIGMA_C = 1.0
#: Prior 1-sigma of the model's node temperatures at the run's start (degC): 0, a run starts
#: on a cold robot (after a night), as on the A465. Measured: with 10 degC (a robot started
#: warm) the joints' readings move the nodes they sit on but not the links' nodes between
#: them, and the tool error after 3 h missed the truth by 34 um instead of under 12 um.
JOINT_INITIAL_SIGMA_C = 0.0


class JointTemperatureError(ValueError):
    """A reading that cannot be fused (wrong number of joints)."""


def joint_regions(controller: ArmController) -> dict[str, tuple[int, ...]]:
    """Each joint's region: the index of its heat node in the thermal model."""
    thermal = controller.thermal
    names = list(thermal.node_names)
    return {
        JOINT_REGION.format(k + 1): (names.index(node),)
        for k, node in enumerate(thermal.joint_node_names)
    }


class JointTemperatureModel:
    """The arm's model followed by its joint temperatures (module docstring)."""

    def __init__(
        self,
        controller: ArmController,
        sensor_noise_c: float,
        *,
        offset_sigma_c: float = JOINT_OFFSET_SIGMA_C,
        initial_sigma_c: float = JOINT_INITIAL_SIGMA_C,
        observe: bool = True,
    ) -> None:
        self.controller = controller
        self.regions = joint_regions(controller)
        self.observing = observe
        self.updates = 0
        if observe:  # identified sensor offsets (an arm model's) win over the prior
            controller.attach_observer(
                self.regions, sensor_noise_c, offset_sigma_c, initial_sigma_c
            )

    @property
    def time_s(self) -> float:
        return self.controller.time_s

    def advance_to(self, t_s: float) -> None:
        self.controller.advance_to(t_s)

    def follow_room(self, room_c: float) -> None:
        """A room thermometer's reading, taken before the next advance: the model's ambient
        follows it (ArmController.follow_room; the first reading is the cold arm's
        temperature). A UR reports no air temperature: a lab adds one (room.driver)."""
        self.controller.follow_room(room_c)

    def observe(self, temperatures_c: Sequence[float]) -> None:
        """Fuse one reading (degC, base joint first); non-finite values are skipped."""
        if len(temperatures_c) != len(self.regions):
            raise JointTemperatureError(
                f"{len(temperatures_c)} joint temperatures for an arm of {len(self.regions)} joints"
            )
        if not self.observing:
            return
        reading = {
            name: float(value)
            for name, value in zip(self.regions, temperatures_c, strict=True)
            if math.isfinite(value)
        }
        self.controller.observe(reading)
        self.updates += 1

    def tool_error(self, q_rad: Sequence[float] | FloatArray) -> Pose6:
        """The warm arm's tool error at joints ``q_rad`` (base frame): its negative is the
        correction (daemon.arm.correction)."""
        c = self.controller
        return tool_error(
            c.arm, np.asarray(q_rad, np.float64), c.link_states(), bending=c.options.bending
        )

    def temperatures_c(self) -> Mapping[str, float]:
        """The joints' heat nodes (degC), what the readings are compared with (the whole
        network is ArmController.temperatures_c)."""
        thermal = self.controller.thermal
        values = thermal.temperatures_c
        return {
            name: float(values[nodes[0]])
            for name, nodes in zip(thermal.joint_node_names, self.regions.values(), strict=True)
        }
