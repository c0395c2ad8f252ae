"""The UR bench's truth as a followed run sees it (issue 31): the tool's true error now, at
the emulated arm's actual joints (the program's path plus the offset it applies) against the
cold true arm at the program's nominal joints, and the same without the offset (what the tool
would do uncompensated). The bench's own seeded geometry, heat, convection and expansion
(drivers/sim/arm_bench.py) make the truth differ from the daemon's model. Read at the
controller's current cycle, so both joint sets are of one instant."""

from __future__ import annotations

from dataclasses import dataclass

from daemon.arm.types import Pose6, pose_difference
from drivers.sim.ur.controller import URController


@dataclass(frozen=True, slots=True)
class TruthErrors:
    residual: Pose6  # the tool's true error with the applied offset (mm, rad; base frame)
    uncompensated: Pose6  # ... without it


class URBenchTruth:
    """The emulated controller's truth (module docstring)."""

    def __init__(self, controller: URController) -> None:
        self.controller = controller

    def errors(self) -> TruthErrors:
        controller = self.controller
        t_s = controller.time_s
        bench = controller.bench
        bench.advance_to(t_s)
        actual, _, nominal = controller.joint_state(t_s)
        cold = bench.tool_pose_cold(nominal)
        return TruthErrors(
            residual=pose_difference(cold, bench.tool_pose_true(actual)),
            uncompensated=pose_difference(cold, bench.tool_pose_true(nominal)),
        )
