"""Run kind "followed" (issue 27, skeleton): a robot that plays its own taught program (a UR
with its offset program; drivers/base.py OffsetRobot) while the daemon follows it and writes a
correction each step. Nothing is taught and nothing moves at the start: the program owns the
motion; each step predicts the tool error, checks the correction against the arm's limits
(daemon/arm/correction.py) before anything is written, writes it (refused by the driver after a
hold: drivers/permit.py) and records it with where the program was.

A skeleton: the prediction is a callable of the run time (zero error by default) and nothing is
measured; the UR driver's work wires the arm model of the program and the tool measurement in
here, touching this package and the factory only (daemon/run/kinds.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from config import Settings
from daemon.arm.correction import check_correction, correction_for
from daemon.arm.run import rotation_urad
from daemon.arm.types import Pose6
from daemon.model.compensation import UnsafeTargetError
from daemon.run.arm.step import correction_limits
from daemon.run.events import ErrorLog
from daemon.run.scheduler import Tick
from daemon.run.states import RunParameters
from daemon.run.summary import SummaryBasis, fixed_summary
from daemon.run.two_link.step import (
    OK,
    StepOutcome,
    Verdict,
    begin_record,
    finish_record,
)
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder
from drivers.base import OffsetRobot
from drivers.clock import Clock
from drivers.errors import DeviceError
from drivers.permit import Ticket

#: The tool error a followed run predicts at a run time (s): mm and rad, base frame.
Predictor = Callable[[float], Pose6]


def no_error(_run_time_s: float) -> Pose6:
    return Pose6.zero()


@dataclass(eq=False)
class FollowedKind:
    run_id: int
    parameters: RunParameters
    robot: OffsetRobot
    recorder: Recorder
    workers: Workers
    settings: Settings
    errors: ErrorLog
    clock: Clock
    predict: Predictor = no_error
    start_s: float = float("nan")
    name: str = "followed"
    last_correction: Pose6 = field(default_factory=Pose6.zero)
    corrections_written: int = 0

    async def teach(self, *, moving: bool) -> None:
        """The program's poses are taught on the robot: nothing to teach here."""

    async def start_bench(self) -> None:
        """No simulated bench follows a robot's own program (yet)."""

    async def references(self) -> None:
        """Each measured pose's first step is its reference."""

    async def step(self, tick: Tick) -> StepOutcome:
        record, flags = begin_record(self.run_id, self.parameters, self.start_s, tick)
        errors: list[str] = []
        stages: dict[str, float] = {}
        started = time.perf_counter()
        run_time_s = tick.scheduled_s - self.start_s
        latency_s = self.settings.compensation.latency_s
        error = self.predict((run_time_s + latency_s) * self.parameters.time_scale)
        verdict: Verdict = OK
        try:
            correction = check_correction(
                correction_for(error, self.parameters.deformation_scale),
                self.last_correction,
                correction_limits(self.settings),
            )
        except UnsafeTargetError as err:
            flags.append("unsafe-target")
            errors.append(f"correction refused: {err}")
            verdict = Verdict("pause", f"correction refused: {err}")
        else:
            try:
                t, r = correction.translation_mm, correction.rotation_rad
                await self.robot.set_correction(
                    (float(t[0]), float(t[1]), float(t[2])), (float(r[0]), float(r[1]), float(r[2]))
                )
                self.last_correction = correction
                self.corrections_written += 1
                record.offset_x_mm, record.offset_y_mm, record.offset_z_mm = map(float, t)
                rotation = rotation_urad(correction)
                record.correction_rx_urad, record.correction_ry_urad = rotation[0], rotation[1]
                record.correction_rz_urad = rotation[2]
                record.arm_pose = str(self.robot.robot_state().at_pose or "")
            except DeviceError as err:
                self.errors.note(err)
                flags.append("robot-error")
                errors.append(str(err))
                verdict = Verdict("fault", str(err))
        stages["move"] = time.perf_counter() - started
        flags.append("no-measurement")  # the skeleton measures nothing yet
        finish_record(record, flags, errors, stages)
        await self.workers.db(self.recorder.write_step, record)
        return StepOutcome(record, None, verdict, (), stages)

    async def resumed(self) -> None:
        """The program goes on where it is; the next correction is checked against the last."""
        self.robot.robot_state()  # the link answers (NotConnectedError otherwise)

    def play(self, grant: Ticket) -> None:
        """The robot plays its own program: nothing to start here."""

    async def stop_playing(self, grace_s: float) -> None:
        """The hold (the session's) freezes the program's offset: nothing more to stop."""

    def summary_basis(self, *, overruns: int, skipped: int, timing: dict[str, Any]) -> SummaryBasis:
        """Every figure of this kind's summary is in memory: the basis is all of it."""
        return {
            "kind": self.name,
            "run_id": self.run_id,
            "fixed": {
                "kind": self.name,
                "corrections_written": self.corrections_written,
                "overruns": overruns,
                "skipped_deadlines": skipped,
                "timing": timing,
            },
            "inputs": {},
            "after": {},
        }

    def summary(
        self, recorder: Recorder, basis: SummaryBasis, *, abandon: threading.Event | None
    ) -> dict[str, Any]:
        return fixed_summary(recorder, basis, abandon)
