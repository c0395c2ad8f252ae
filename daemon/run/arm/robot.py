"""The robot as an arm run uses it (issue 20): a driver with named taught goals and rotated
absolute moves (drivers/base.py GoalRobot, both C500C drivers) behind the ArmRobot face of
daemon/run/arm/step.py.

Teaching a measured pose of the duty cycle: the console teaches only where the robot stands
(`here <var>`, docs/reference/c500c-console.md), so the robot is first brought to the pose. The pose
where the robot stands at the start is taught as the default goal (`opgoal`, as the two-link bench
does), and each measured pose is reached by one absolute move from it (``set cur = opgoal``,
``wshift`` by the pose's tool position and orientation relative to it, ``moves cur``;
docs/reference/c500c-console.md "The absolute-move sequence") and taught there under its own name.
Every later step moves to "its goal + its correction". The driver's hold contract holds throughout:
each of these is a motion command refused after a hold, right before its bytes are written.
"""

from __future__ import annotations

import logging
from typing import cast

import numpy as np
from scipy.spatial.transform import Rotation

from daemon.arm.run import FloatArray, MeasuredPose
from daemon.arm.types import Pose6
from drivers.base import (
    DEFAULT_GOAL,
    GoalRobot,
    MoveResult,
    Pose,
    RobotStatus,
    SpeedGoalRobot,
    Vector3,
)
from drivers.errors import DeviceError
from drivers.permit import MotionPermit, Ticket

logger = logging.getLogger(__name__)


def pose_matrix(pose: Pose) -> FloatArray:
    """The console's WORLD pose (mm; z-rot, y-rot, x-rot in degrees: intrinsic z-y-x, the
    convention of Pose6.zyx_deg) as a 4x4 transform in the base frame."""
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_euler(
        "ZYX", [pose.z_rot, pose.y_rot, pose.x_rot], degrees=True
    ).as_matrix()
    matrix[:3, 3] = pose.position
    return matrix


def shift_to(target: FloatArray, start: FloatArray) -> tuple[Vector3, Vector3]:
    """The wshift (translation mm, rotation vector rad, base frame) that carries the pose
    ``start`` to ``target`` (both 4x4): ``t_target - t_start`` and the rotation vector of
    ``R_target R_start^T`` (the Pose6 convention the drivers send)."""
    translation = np.asarray(target[:3, 3] - start[:3, 3], dtype=np.float64)
    rotation = Rotation.from_matrix(target[:3, :3] @ start[:3, :3].T).as_rotvec()
    t = (float(translation[0]), float(translation[1]), float(translation[2]))
    r = (float(rotation[0]), float(rotation[1]), float(rotation[2]))
    return t, r


def sets_speed(robot: object) -> bool:
    """Whether the driver's moves take a speed (drivers/base.py SpeedGoalRobot: the console
    driver; the fast path's frames carry none)."""
    return bool(getattr(robot, "SETS_SPEED", False))


class GoalRobotArm:
    """ArmRobot over a GoalRobot driver (module docstring)."""

    def __init__(self, robot: GoalRobot) -> None:
        self.robot = robot
        self._start: Pose | None = None

    async def teach_pose(self, pose: MeasuredPose) -> Pose:
        robot = self.robot
        if self._start is None:
            # where the robot stands: the start of every teaching move (moves nothing)
            self._start = await robot.teach_goal(DEFAULT_GOAL)
        offset_mm, rotation_rad = shift_to(pose.tool_pose, pose_matrix(self._start))
        await robot.move_absolute(offset_mm, rotation_rad, goal=DEFAULT_GOAL)
        taught = await robot.teach_goal(pose.name)
        reached = np.subtract(taught.position, pose.tool_pose[:3, 3])
        logger.info(
            "taught pose %r at %s (%.3f mm from the model's tool pose)",
            pose.name,
            taught,
            float(np.linalg.norm(reached)),
        )
        return taught

    async def move_to_goal(
        self, goal: str, correction: Pose6, *, speed_percent: int | None = None
    ) -> MoveResult:
        """The taught ``goal`` + ``correction``; ``speed_percent``: at that speed (a played
        duty cycle, drivers/base.py SpeedGoalRobot), refused by a driver that cannot set it."""
        t, r = correction.translation_mm, correction.rotation_rad
        if goal not in self.robot.taught_goals():
            raise DeviceError("robot", f"goal {goal!r} is not taught")
        offset = (float(t[0]), float(t[1]), float(t[2]))
        rotation = (float(r[0]), float(r[1]), float(r[2]))
        if speed_percent is None:
            return await self.robot.move_absolute(offset, rotation, goal=goal)
        if not sets_speed(self.robot):
            raise DeviceError(
                "robot",
                f"the robot driver {type(self.robot).__name__} cannot set a move's speed",
            )
        robot = cast(SpeedGoalRobot, self.robot)
        return await robot.move_absolute(offset, rotation, goal=goal, speed_percent=speed_percent)

    @property
    def permit(self) -> MotionPermit:
        return self.robot.permit

    async def stop(self) -> None:
        await self.robot.stop()

    async def resume(self, ticket: Ticket | None = None) -> None:
        await self.robot.resume(ticket)

    async def actual_pose(self) -> Pose:
        return await self.robot.actual_pose()

    def status(self) -> RobotStatus:
        return self.robot.status()
