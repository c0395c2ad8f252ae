"""Run kind "followed" (issue 31): a robot that plays its own taught program (a UR with its
offset program, controller/ur/; drivers/base.py OffsetRobot) while the daemon follows it and
writes a 6-DOF correction every step.

Nothing is taught and nothing moves at the start: the program owns the motion; the run takes
the program as it is (``follow_program``: a later restart of the program is a fault). Each
step reads the robot's latest state (joints, joint temperatures, the "at measured pose"
register), advances the arm's model to the step's time with the motor heat of the motion the
robot made since the last step (every RTDE package's joints: daemon/run/followed/heat.py,
recorded as ``heat_json``; arm.heat_from duty-cycle: the taught cycle's), fuses the joint
temperatures as the model's thermal input (daemon/arm/joint_temperatures.py: no IR camera),
predicts the tool error at the robot's *current*
joints, checks the correction against the arm's limits (daemon/arm/correction.py) before
anything is written, writes it (refused by the driver after a hold: drivers/permit.py) and
records it with the joint temperatures and where the program was (compensation off, the
calibration run of ``calibrate model``: a zero correction is written, the program's heartbeat,
so the cameras see the whole drift). With tool cameras, the first
step of each dwell of the program at a measured pose (its at-pose register) then measures the
tool (daemon/run/followed/measure.py: the frames, the arm run's meter, the residual against the
pose's first measurement); between measured poses a step only corrects. A step with no
camera measurement records, on the UR bench, the bench truth's residual tool error (flag
``bench-truth``); with neither, nothing is measured (flag ``no-measurement``). With a room
thermometer (room.driver: a UR has none of its own) each step reads it first, records it
(``room_c``) and the model's ambient follows it (daemon/arm/controller.py follow_room, as an
A465 arm run: issue 29); without one the model holds model.ambient_c and the summary's
``room`` says so (a warming room would otherwise be read as the joints heating). The summary's
accuracy comes from the cameras' measurements (``measured``) and, on the bench, from the truth
(``bench_truth``, and ``measured_vs_truth``: the cameras against the truth).

A hold (pause, stop, fault, shutdown) freezes the correction first (the session's hold, the
driver's hold flag); then :meth:`FollowedKind.stop_playing` pauses the robot's program through
its Dashboard (program_pause.py, robot.pause_program_on_hold), and :meth:`resumed` plays again
a program that pause paused.
"""

from __future__ import annotations

import functools
import json
import math
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import numpy as np

from config import Settings
from daemon.analysis.arm import NO_ROOM_NOTE
from daemon.arm.correction import check_correction, correction_for
from daemon.arm.run import UM_PER_MM, rotation_urad, translation_um
from daemon.arm.types import FloatArray, Pose6
from daemon.model.compensation import UnsafeTargetError
from daemon.run.arm.record import camera_views
from daemon.run.arm.step import ROOM_ERROR, correction_limits
from daemon.run.events import ErrorLog
from daemon.run.followed.heat import DUTY_CYCLE, FollowedHeat
from daemon.run.followed.measure import DwellMeasurement, MeasuredTally
from daemon.run.followed.program_pause import ProgramPause
from daemon.run.followed.summary import followed_summary_rows
from daemon.run.followed.view import VIEW
from daemon.run.kind import KindBase, KindView
from daemon.run.scheduler import Tick
from daemon.run.sensors import Sensors
from daemon.run.stage_times import StageTimes
from daemon.run.states import RunParameters
from daemon.run.step import (
    OK,
    StepOutcome,
    Verdict,
    begin_record,
    finish_record,
)
from daemon.run.summary import SummaryBasis, SummaryRow, fixed_summary
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder
from daemon.storage.step_record import StepRecord
from drivers.base import OffsetRobot, OffsetRobotState
from drivers.clock import Clock
from drivers.errors import DeviceError
from drivers.permit import Ticket
from drivers.ur.motion import MotionSamples


class FollowedModel(Protocol):
    """The arm's model as a followed run uses it (daemon/arm/joint_temperatures.py)."""

    @property
    def time_s(self) -> float: ...

    def advance_to(self, t_s: float) -> None: ...

    def observe(self, temperatures_c: Sequence[float]) -> None: ...

    def tool_error(self, q_rad: Sequence[float] | FloatArray) -> Pose6: ...

    def temperatures_c(self) -> Mapping[str, float]: ...

    def follow_room(self, room_c: float) -> None: ...


class TruthErrors(Protocol):
    @property
    def residual(self) -> Pose6: ...

    @property
    def uncompensated(self) -> Pose6: ...


class BenchTruth(Protocol):
    """The simulated bench's truth (drivers/sim/ur/truth.py), when there is one."""

    def errors(self) -> TruthErrors: ...


@dataclass
class TruthTally:
    """Sums of squares of the bench truth's 3-D tool error, with and without the correction
    (um^2), for the run's removal: 1 - rms(residual) / rms(uncompensated)."""

    steps: int = 0
    residual_um2: float = 0.0
    uncompensated_um2: float = 0.0
    worst_residual_um: float = 0.0
    worst_uncompensated_um: float = 0.0

    def add(self, errors: TruthErrors) -> float:
        residual = errors.residual.translation_norm_mm * UM_PER_MM
        uncompensated = errors.uncompensated.translation_norm_mm * UM_PER_MM
        self.steps += 1
        self.residual_um2 += residual**2
        self.uncompensated_um2 += uncompensated**2
        self.worst_residual_um = max(self.worst_residual_um, residual)
        self.worst_uncompensated_um = max(self.worst_uncompensated_um, uncompensated)
        return residual

    def summary(self) -> dict[str, Any]:
        if self.steps == 0:
            return {"steps": 0}
        rms_residual = math.sqrt(self.residual_um2 / self.steps)
        rms_uncompensated = math.sqrt(self.uncompensated_um2 / self.steps)
        removed = 1.0 - rms_residual / rms_uncompensated if rms_uncompensated > 0 else None
        return {
            "steps": self.steps,
            "rms_residual_um": rms_residual,
            "rms_uncompensated_um": rms_uncompensated,
            "worst_residual_um": self.worst_residual_um,
            "worst_uncompensated_um": self.worst_uncompensated_um,
            "removed_fraction": removed,
        }


@dataclass
class RoomTally:
    """The room thermometer's readings over the run, for its summary (an arm run's
    daemon/analysis/arm.py room_summary, kept in memory as the followed run's other figures)."""

    readings: int = 0
    first_c: float = math.nan
    last_c: float = math.nan
    min_c: float = math.inf
    max_c: float = -math.inf
    errors: int = 0

    def add(self, room_c: float) -> None:
        if self.readings == 0:
            self.first_c = room_c
        self.readings += 1
        self.last_c = room_c
        self.min_c, self.max_c = min(self.min_c, room_c), max(self.max_c, room_c)

    def summary(self, thermometer: bool) -> dict[str, Any]:
        if not thermometer or self.readings == 0:
            note = NO_ROOM_NOTE if not thermometer else "the room thermometer gave no reading"
            return {"measured": False, "readings": 0, "errors": self.errors, "note": note}
        return {
            "measured": True,
            "readings": self.readings,
            "errors": self.errors,
            "first_c": self.first_c,
            "last_c": self.last_c,
            "min_c": self.min_c,
            "max_c": self.max_c,
        }


@dataclass
class FollowedWork:
    """What a followed run's steps carry besides the kind's services: its identity and start
    (the last correction written and the bench truth's tally are the kind's)."""

    run_id: int
    parameters: RunParameters
    start_s: float = float("nan")  # run clock at step 0


@dataclass(eq=False)
class FollowedKind(KindBase):
    title: ClassVar[str] = "a followed run"
    name: ClassVar[str] = VIEW.name
    view: ClassVar[KindView] = VIEW
    work: FollowedWork
    robot: OffsetRobot
    recorder: Recorder
    workers: Workers
    settings: Settings
    errors: ErrorLog
    clock: Clock
    model: FollowedModel
    truth: BenchTruth | None = None
    #: pauses the robot's program after a hold, plays it again on the resume
    #: (robot.pause_program_on_hold; daemon/run/followed/program_pause.py)
    program: ProgramPause | None = None
    #: the tool cameras' measurements at the program's dwells (None: no camera)
    measurement: DwellMeasurement | None = None
    #: the daemon's sensors, for the room thermometer (None, or none open: the model holds
    #: model.ambient_c)
    sensors: Sensors | None = None
    #: the motor heat of the motion the robot makes (arm.heat_from measured:
    #: daemon/run/followed/heat.py); None: the duty cycle's, for ``heat_note``'s reason
    heat: FollowedHeat | None = None
    heat_note: str = ""
    last_correction: Pose6 = field(default_factory=Pose6.zero)
    corrections_written: int = 0
    tally: TruthTally = field(default_factory=TruthTally)
    room: RoomTally = field(default_factory=RoomTally)

    async def teach(self, *, moving: bool) -> None:
        """The program's poses are taught on the robot: the run takes the program as it is
        (moves nothing; its restart from now on is a fault)."""
        if not moving:
            await self.robot.follow_program()
        if self.heat is not None:
            self.heat.take()  # the motion before the run is not the run's heat

    async def start_bench(self) -> None:
        """The UR bench plays from the daemon's start: nothing to start."""

    async def references(self) -> None:
        """The model's cold state at the run's start is the reference."""

    @property
    def has_room(self) -> bool:
        return self.sensors is not None and self.sensors.has_room

    def _predict(
        self,
        model_time_s: float,
        state: OffsetRobotState,
        room_c: float | None = None,
        motion: MotionSamples | None = None,
    ) -> tuple[Pose6, str | None]:
        """On a worker: the room's reading to the model (its ambient until the next one), the
        heat of the robot's ``motion`` since the last step held over the advance (measured
        heat: its ``heat_json``), the model to ``model_time_s``, the joint temperatures fused,
        the tool error at the robot's current joints."""
        if room_c is not None:
            self.model.follow_room(room_c)
        heat = None
        if self.heat is not None and motion is not None:
            heat = self.heat.hold(motion, self.model.time_s, model_time_s)
        self.model.advance_to(model_time_s)
        self.model.observe(state.joint_temperatures_c)
        return self.model.tool_error(np.asarray(state.joints_rad, np.float64)), heat

    async def step(self, tick: Tick) -> StepOutcome:
        record, flags = begin_record(self.run_id, self.parameters, self.start_s, tick)
        errors: list[str] = []
        stages = StageTimes()
        started = time.perf_counter()
        run_time_s = tick.scheduled_s - self.start_s
        latency_s = self.settings.compensation.latency_s
        model_time_s = (run_time_s + latency_s) * self.parameters.time_scale
        verdict: Verdict = OK
        try:
            state = self.robot.robot_state()
        except DeviceError as err:
            self.errors.note(err)
            flags.append("robot-error")
            errors.append(str(err))
            finish_record(record, flags, errors, stages)
            await self.workers.db(self.recorder.write_step, record)
            return StepOutcome(record, None, Verdict("fault", str(err)), (), stages, stages.ends_s)
        self._state_into(record, state)
        room_c = await self._read_room(record, flags, errors)
        motion = self.heat.take() if self.heat is not None else None
        error, record.heat_json = await self.workers.step(
            self._predict, model_time_s, state, room_c, motion
        )
        record.model_time_s = model_time_s
        self._prediction_into(record, error)
        stages.end("model", started)
        started = time.perf_counter()
        try:
            correction = check_correction(
                self._correction(error),
                self.last_correction,
                correction_limits(self.settings),
            )
        except UnsafeTargetError as err:
            flags.append("unsafe-target")
            errors.append(f"correction refused: {err}")
            verdict = Verdict("pause", f"correction refused: {err}")
            stages.end("check", started)
        else:
            stages.end("check", started)
            started = time.perf_counter()
            try:
                t, r = correction.translation_mm, correction.rotation_rad
                await self.robot.set_correction(
                    (float(t[0]), float(t[1]), float(t[2])), (float(r[0]), float(r[1]), float(r[2]))
                )
                self.last_correction = correction
                self.corrections_written += 1
                record.correction_tx_mm, record.correction_ty_mm, record.correction_tz_mm = map(
                    float, t
                )
                rotation = rotation_urad(correction)
                record.correction_rx_urad, record.correction_ry_urad = rotation[0], rotation[1]
                record.correction_rz_urad = rotation[2]
                record.offset_x_mm, record.offset_y_mm, record.offset_z_mm = map(float, t)
            except DeviceError as err:
                self.errors.note(err)
                flags.append("robot-error")
                errors.append(str(err))
                verdict = Verdict("fault", str(err))
            stages.end("move", started)
        measured = None
        if self.measurement is not None:
            # the measurement is off the step's path (measure.py): a finished one is written
            # into its own step's row, and this step starts one when the program dwells
            started = time.perf_counter()
            measured = await self.measurement.collect(self._rewrite)
            if verdict is OK:
                self.measurement.start(state, record, flags)
            stages.end("frame", started)
        self._measure(record, flags)
        finish_record(record, flags, errors, stages)
        started = time.perf_counter()
        await self.workers.db(self.recorder.write_step, record)
        stages.end("record", started)
        # the tool cameras' frames of a measured step, with their markers, for the live views
        views = camera_views(measured)
        return StepOutcome(record, None, verdict, (), stages, stages.ends_s, views)

    async def _read_room(
        self, record: StepRecord, flags: list[str], errors: list[str]
    ) -> float | None:
        """The room thermometer's reading (recorded), or None: no thermometer, or it failed
        (flagged room-error, noted; the model keeps the last room, as an arm run's)."""
        if self.sensors is None or not self.sensors.has_room:
            return None
        try:
            reading = await self.sensors.read_room()
        except DeviceError as err:
            self.errors.note(err)
            self.room.errors += 1
            flags.append(ROOM_ERROR)
            errors.append(str(err))
            return None
        record.room_c = reading.temperature_c
        self.room.add(reading.temperature_c)
        return reading.temperature_c

    def _correction(self, error: Pose6) -> Pose6:
        """The correction to write: the one cancelling ``error``, or zero in an uncompensated
        run (compensation off: ``calibrate model``'s calibration run, whose cameras must see
        the arm's whole drift; zero is still written each step, the program's heartbeat)."""
        if self.parameters.compensation == "off":
            return Pose6.zero()
        return correction_for(error, self.parameters.deformation_scale)

    @staticmethod
    def _state_into(record: StepRecord, state: OffsetRobotState) -> None:
        record.arm_pose = str(state.at_pose) if state.at_pose else ""
        record.pose_x_mm, record.pose_y_mm, record.pose_z_mm = state.tcp_pose[:3]
        record.ir_json = json.dumps(
            {
                f"joint{k + 1}": {"mean_c": value, "max_c": value}
                for k, value in enumerate(state.joint_temperatures_c)
            }
        )

    def _prediction_into(self, record: StepRecord, error: Pose6) -> None:
        tx, ty, tz = translation_um(error)
        record.predicted_tx_um, record.predicted_ty_um, record.predicted_tz_um = tx, ty, tz
        rx, ry, rz = rotation_urad(error)
        record.predicted_rx_urad, record.predicted_ry_urad, record.predicted_rz_urad = rx, ry, rz
        temperatures = self.model.temperatures_c()
        record.model_temperatures_json = json.dumps(
            {k: round(v, 4) for k, v in temperatures.items()}
        )

    async def _rewrite(self, record: StepRecord) -> None:
        """A measuring step's row again, with its measurement (measure.py)."""
        await self.workers.db(functools.partial(self.recorder.write_step, record, replace=True))

    def _measure(self, record: StepRecord, flags: list[str]) -> None:
        """On the UR bench the truth's residual into the run's tally, and into the step's
        measurement columns (a camera measurement this step started replaces them when it is
        in: measure.py); elsewhere the step says nothing is measured (yet)."""
        if self.truth is None:
            flags.append("no-measurement")
            return
        errors = self.truth.errors()
        residual = self.tally.add(errors)
        tx, ty, tz = translation_um(errors.residual)
        record.measured_tx_um, record.measured_ty_um, record.measured_tz_um = tx, ty, tz
        rx, ry, rz = rotation_urad(errors.residual)
        record.measured_rx_urad, record.measured_ry_urad, record.measured_rz_urad = rx, ry, rz
        record.drift_3d_um = residual
        flags.append("bench-truth")

    async def resumed(self) -> None:
        """The program goes on where it is; the next correction is checked against the last.
        A program the hold paused is played again (after the driver's resume: the correction
        is live before the robot moves; a Dashboard failure is noted, not raised)."""
        self.robot.robot_state()  # the link answers (NotConnectedError otherwise)
        if self.program is not None:
            await self.program.play_again(self.settings.scheduler.stop_grace_s)

    def play(self, grant: Ticket) -> None:
        """The robot plays its own program: nothing to start here."""

    async def stop_playing(self, grace_s: float, *, held: bool) -> None:
        """The session's hold has frozen the program's offset already; after a hold (not at
        the run's end) the program itself is paused, within ``grace_s`` (program_pause.py).
        Then a measurement in flight is waited for (within ``grace_s``) and written into its
        step's row: the run's summary, taken next, counts it."""
        if held and self.program is not None:
            await self.program.pause(grace_s)
        if self.measurement is not None:
            await self.measurement.collect(self._rewrite, wait_s=grace_s)

    def summary_basis(self, *, overruns: int, skipped: int, timing: dict[str, Any]) -> SummaryBasis:
        """Every figure of this kind's summary is in memory: the basis is all of it."""
        after: dict[str, Any] = {}
        measurement = self.measurement
        after["measured"] = (
            measurement.tally.summary(measurement.cameras)
            if measurement is not None
            else MeasuredTally().summary(0)
        )
        after["room"] = self.room.summary(self.has_room)
        after["heat"] = (
            self.heat.summary()
            if self.heat is not None
            else {"from": DUTY_CYCLE, "note": self.heat_note}
        )
        if self.truth is not None:
            after["bench_truth"] = self.tally.summary()
            if measurement is not None:
                after["measured_vs_truth"] = measurement.tally.truth_summary()
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
            "after": after,
        }

    @staticmethod
    def summary_rows(summary: dict[str, Any]) -> list[SummaryRow]:
        return followed_summary_rows(summary)

    @staticmethod
    def summary_from_basis(
        recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
    ) -> dict[str, Any]:
        return fixed_summary(recorder, basis, abandon)
