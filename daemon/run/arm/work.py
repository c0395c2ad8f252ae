"""What an arm run's steps need and carry (daemon/run/arm/step.py): the robot and the tool
meter they use, and the run's work handed from one step to the next.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

from daemon.arm.run import ArmPredictor, CyclePose, FloatArray, MeasuredPose, ToolMeasurement
from daemon.arm.types import Pose6
from daemon.run.states import RunParameters
from drivers.base import MoveResult, Pose, RobotStatus
from drivers.permit import MotionPermit, Ticket


class ArmRobot(Protocol):
    """What an arm run needs of the robot (daemon/run/arm/robot.py over a driver with named taught
    goals and rotated absolute moves, drivers/base.py GoalRobot). The hold contract is
    drivers/base.py Robot's: after ``stop()`` every motion command is refused right before its
    bytes are written."""

    async def teach_pose(self, pose: MeasuredPose) -> Pose:
        """Bring the tool to ``pose`` and teach it there as the goal ``pose.name``."""
        ...

    async def move_to_goal(
        self, goal: str, correction: Pose6, *, speed_percent: int | None = None
    ) -> MoveResult:
        """Move to the taught goal ``goal`` shifted by ``correction`` (base frame), at
        ``speed_percent`` of the controller's speed (None: its current one)."""
        ...

    @property
    def permit(self) -> MotionPermit: ...

    async def stop(self) -> None: ...

    async def resume(self, ticket: Ticket | None = None) -> None: ...

    async def actual_pose(self) -> Pose: ...

    def status(self) -> RobotStatus: ...


class ToolMeter(Protocol):
    """The tool's 3-D measurement: every camera's frame -> marker centroids -> triangulated
    markers -> tool pose (daemon/run/arm/measure.py). Raises DeviceError (a camera) or
    MeasurementError (the markers)."""

    async def measure(
        self, expected_pose: FloatArray, frames: int | None = None
    ) -> ToolMeasurement:
        """``frames`` per camera (None: the meter's own number, arm.frames_per_measurement)."""
        ...


@dataclass(eq=False)
class ArmRunWork:
    """What an arm run's steps carry from one to the next (the arm's RunWork)."""

    run_id: int
    parameters: RunParameters
    predictor: ArmPredictor
    poses: tuple[MeasuredPose, ...]
    start_s: float = float("nan")  # run clock at step 0
    taught: dict[str, Pose] = field(default_factory=dict)  # goal name -> pose read back
    #: the last correction sent for each pose: the step limits apply per pose
    last_correction: dict[str, Pose6] = field(default_factory=dict)
    #: the tool pose measured at each taught goal before the first move: the drift's zero
    reference: dict[str, FloatArray] = field(default_factory=dict)
    reference_source: str = "each pose's first step"
    #: the poses whose reference could not be measured before the first correction, with why:
    #: their zero is their first step's measurement (flagged REFERENCE_MISSING), and the run's
    #: summary says so (daemon/run/summary.py), never a silent zero
    missing_references: dict[str, str] = field(default_factory=dict)
    #: a played duty cycle (daemon/run/arm/player.py): every pose in order, each taught; empty:
    #: the robot moves to the measured poses only, one per step
    cycle: tuple[CyclePose, ...] = ()

    def pose_at(self, step: int) -> MeasuredPose:
        """The measured poses in turn, one per step (the duty cycle's order)."""
        return self.poses[step % len(self.poses)]

    def previous(self, pose: MeasuredPose) -> Pose6:
        return self.last_correction.get(pose.name, Pose6.zero())
