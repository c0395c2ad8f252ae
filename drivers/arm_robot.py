"""An arm run's robot (issue 20) over either C500C driver: what daemon/arm_step.py's
``ArmRobot`` asks (wt-armrun), built on :class:`drivers.base.GoalRobot` and the arm's
kinematics (daemon.arm, the pure core).

- ``teach_pose(name, q_rad)``: the duty cycle gives a pose as joint angles; the controller is
  driven in world locations, so the pose is the forward kinematics of the controller's arm
  description at ``q_rad`` (drivers/goals.py's location convention), reached by
  ``move_to_pose`` (joint-interpolated) and taught there as the goal ``name``.
- ``move_to_goal(goal, correction)``: goal + the 6-DOF correction (daemon.arm.types.Pose6:
  translation in mm, rotation vector in rad, base frame) in one absolute move.

Everything else (stop, resume, actual_pose, status) is the driver's, with its hold contract.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import TracebackType
from typing import Self

import numpy as np
from numpy.typing import NDArray

from daemon.arm.description import Arm
from daemon.arm.kinematics import forward
from daemon.arm.types import Pose6
from drivers.base import GoalRobot, MoveResult, Pose, RobotStatus, Vector3
from drivers.goals import location_of


def _vector3(values: NDArray[np.float64]) -> Vector3:
    x, y, z = (float(v) for v in values)
    return (x, y, z)


class ArmRobot:
    """A GoalRobot seen as an arm run's robot. Entering it enters the driver."""

    def __init__(self, robot: GoalRobot, arm: Arm) -> None:
        self.robot = robot
        self.arm = arm

    async def __aenter__(self) -> Self:
        await self.robot.__aenter__()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        await self.robot.__aexit__(exc_type, exc, traceback)

    def pose_at(self, q_rad: Sequence[float] | NDArray[np.float64]) -> Pose:
        """The world location (mm, degrees) of the tool at the joint angles ``q_rad``."""
        return Pose(*location_of(forward(self.arm, np.asarray(q_rad, dtype=np.float64))))

    async def teach_pose(self, name: str, q_rad: Sequence[float] | NDArray[np.float64]) -> Pose:
        """Move to the joint angles' world location, then teach it as the goal ``name``; returns
        the pose the controller read back when teaching."""
        await self.robot.move_to_pose(self.pose_at(q_rad))
        return await self.robot.teach_goal(name)

    async def move_to_goal(self, goal: str, correction: Pose6) -> MoveResult:
        return await self.robot.move_absolute(
            _vector3(correction.translation_mm), _vector3(correction.rotation_rad), goal=goal
        )

    async def stop(self) -> None:
        await self.robot.stop()

    async def resume(self) -> None:
        await self.robot.resume()

    async def actual_pose(self) -> Pose:
        return await self.robot.actual_pose()

    def status(self) -> RobotStatus:
        return self.robot.status()
