"""An arm run's kind (issue 20; daemon/run/kind.py): each measured pose taught by a move (after
the start's release), the arm bench's truth started, each pose's reference measured at its
goal, then one step per period at the duty cycle's next measured pose (daemon/run/arm/step.py),
the robot moved by the step or, with a played duty cycle, by the player between the steps."""

from __future__ import annotations

import functools
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from config import Settings
from daemon.run.arm.prepare import ArmServices, measure_references, reference_frames, teach_poses
from daemon.run.arm.summary import arm_basis, arm_summary, arm_summary_rows
from daemon.run.arm.view import VIEW
from daemon.run.arm.work import ArmRunWork
from daemon.run.events import ErrorLog
from daemon.run.kind import KindBase, KindView
from daemon.run.scheduler import Tick
from daemon.run.states import RunParameters
from daemon.run.step import StepOutcome
from daemon.run.summary import SummaryBasis, SummaryRow
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder
from drivers.clock import Clock
from drivers.permit import Ticket


@dataclass(eq=False)
class ArmKind(KindBase):
    title: ClassVar[str] = "an arm run"
    own_parameters: ClassVar[frozenset[str]] = frozenset({"duty_cycle"})
    name: ClassVar[str] = VIEW.name
    view: ClassVar[KindView] = VIEW
    work: ArmRunWork
    arm: ArmServices
    bench: object | None  # the arm bench's truth (drivers/sim/arm_devices.py), when simulated
    workers: Workers
    settings: Settings
    errors: ErrorLog
    clock: Clock

    @staticmethod
    def reference_hint(parameters: RunParameters) -> str:
        assert parameters.duty_cycle is not None
        return f"an uncompensated run of duty cycle {Path(parameters.duty_cycle).stem!r}"

    @staticmethod
    def reference_refusal(parameters: RunParameters, reference: Mapping[str, Any]) -> str | None:
        """The reference followed the same duty cycle (by name): another cycle's drift is
        another motion's."""
        assert parameters.duty_cycle is not None
        theirs = Path(str(reference.get("duty_cycle"))).stem
        ours = Path(parameters.duty_cycle).stem
        if theirs != ours:
            return (
                f"followed duty cycle {theirs!r}, this run {ours!r}: their drifts are not "
                "comparable"
            )
        return None

    async def teach(self, *, moving: bool) -> None:
        """Each pose reached by a move and taught there: only once motion is allowed."""
        if moving:
            await teach_poses(self.work, self.arm.robot)

    async def start_bench(self) -> None:
        """The simulated arm (drivers/sim/arm_bench.py), built on a worker thread: a second."""
        start = getattr(self.bench, "start_arm_run", None)
        if start is not None:
            duty_cycle = self.work.parameters.duty_cycle
            await self.workers.step(
                functools.partial(start, self.clock.now(), duty_cycle=duty_cycle)
            )

    async def references(self) -> None:
        await measure_references(self.work, self.arm, self.errors, reference_frames(self.settings))

    async def step(self, tick: Tick) -> StepOutcome:
        return await self.arm.pipeline.run(self.work, tick)

    async def resumed(self) -> None:
        """Every step moves to its goal + correction: nothing carries over; the pose read
        back says the link answers."""
        await self.arm.robot.actual_pose()

    def play(self, grant: Ticket) -> None:
        if self.arm.player is not None:
            self.arm.player.start(grant)

    async def stop_playing(self, grace_s: float, *, held: bool) -> None:
        if self.arm.player is not None:
            await self.arm.player.stop(grace_s)

    def summary_basis(self, *, overruns: int, skipped: int, timing: dict[str, Any]) -> SummaryBasis:
        return arm_basis(
            self.work, kind=self.name, overruns=overruns, skipped=skipped, timing=timing
        )

    @staticmethod
    def summary_rows(summary: dict[str, Any]) -> list[SummaryRow]:
        return arm_summary_rows(summary)

    @staticmethod
    def summary_from_basis(
        recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
    ) -> dict[str, Any]:
        return arm_summary(recorder, basis, abandon)
