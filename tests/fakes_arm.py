"""The arm run's fake robot and its truth, shared by the arm-run tests and the Robot contract
suite (tests/contract/adapters.py): a fake kept beside the other fakes, not in a test module,
so the contract suite does not import a test module.

The fake arm's truth is the fake predictor's own law with its rates scaled by TRUTH_FACTOR:
the tool error grows linearly in time at each pose (tests/test_arm_run.py checks the daemon's
recorded drift and residual against it).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from daemon.arm.run import MeasuredPose
from daemon.arm.types import Pose6
from drivers.base import DEFAULT_GOAL, MoveResult, Pose
from drivers.clock import Clock
from tests.fakes import FakeRobot

#: The truth's error law (per model second): translation along each pose's direction and a
#: rotation about its axis.
RATE_MM_PER_S = 2e-4  # 40 um over the run
RATE_RAD_PER_S = 1e-7  # 20 urad over the run
TRUTH_FACTOR = 1.25  # the truth heats 25 % faster than the controller's model


def _pose(name: str, x: float, direction: tuple[float, float, float]) -> MeasuredPose:
    tool = np.eye(4)
    tool[:3, :3] = Rotation.from_euler("z", x / 10.0, degrees=True).as_matrix()
    tool[:3, 3] = (x, 100.0, 400.0)
    return MeasuredPose(name, np.full(6, x / 1000.0), tool)


POSES = (_pose("pick", 500.0, (1.0, 0.0, 0.0)), _pose("place", 300.0, (0.0, 0.6, 0.8)))
DIRECTIONS = {"pick": np.array([1.0, 0.0, 0.0]), "place": np.array([0.0, 0.6, 0.8])}
AXES = {"pick": np.array([0.0, 0.0, 1.0]), "place": np.array([1.0, 0.0, 0.0])}


def error_law(name: str, t_s: float, factor: float = 1.0) -> Pose6:
    return Pose6(
        factor * RATE_MM_PER_S * t_s * DIRECTIONS[name],
        factor * RATE_RAD_PER_S * t_s * AXES[name],
    )


class ArmTruth:
    """The fake arm bench: the tool error of the truth since the run started."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.start_s: float | None = None
        self.duty_cycles: list[str | None] = []

    def start_arm_run(self, t_s: float, *, duty_cycle: str | None) -> None:
        self.start_s = t_s
        self.duty_cycles.append(duty_cycle)

    def error(self, name: str) -> Pose6:
        assert self.start_s is not None, "the session must start the arm bench"
        return error_law(name, self.clock.now() - self.start_s, TRUTH_FACTOR)


class FakeArmRobot(FakeRobot):
    """The suite's one fake robot (tests/fakes.py FakeRobot, which passes the Robot contract
    suite) with the tool's position following the moves from each taught goal; the tool's
    error is the truth's (FakeMeter)."""

    def __init__(self, truth: ArmTruth) -> None:
        super().__init__()
        self.truth = truth
        self.position = np.array([400.0, 0.0, 300.0])  # where the tool stands at the start

    def _pose(self) -> Pose:
        return Pose(*self.position)

    def _moved(self, offset_mm: np.ndarray, goal: str) -> None:
        self.position = np.add(self.taught[goal].position, offset_mm)

    async def teach_goal(self, goal: str = DEFAULT_GOAL) -> Pose:
        """Moves nothing: the goal is where the robot stands."""
        pose = await super().teach_goal(goal)
        self.goal, self.correction = goal, Pose6.zero()
        return pose

    async def move_incremental(self, delta_mm: Any) -> MoveResult:
        raise AssertionError("an arm run moves to its named goals only")
