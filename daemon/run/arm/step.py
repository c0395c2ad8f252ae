"""One step of an arm run (issue 20), top to bottom, like daemon/run/two_link/step.py's
StepPipeline: model -> correction check -> move -> measure -> record.

Each fixed step advances the controller's arm model (motor heat from the duty cycle's
commanded motion) to the step's time, takes the duty cycle's next measured pose, predicts the
tool error at that pose's configuration, checks the correction (``-error``: translation and
rotation, daemon/arm/correction.py) before anything reaches the robot, moves to the taught
goal of that pose plus the correction, measures the tool in every camera (markers ->
triangulation -> pose) and records the 6-DOF prediction, correction and measurement. It
returns a StepOutcome with a verdict and never changes the run's state: what a verdict does is
decided in daemon/run/session.py, as for the two-link bench.

A refused correction (a limit, a non-finite value) is never sent: the step records it with the
flag ``unsafe-target`` and asks for a pause, as the 1-D path. A hold that comes at any point
of the step is enforced by the driver, which refuses the move under its lock right before the
bytes are written (drivers/base.py Robot.stop).

With a played duty cycle (daemon/run/arm/player.py) the robot is moved by the player, not by the
step: the step predicts the tool error at every pose of the cycle (the arm warmed once), checks
each pose's correction and hands the accepted ones to the player (a refused one is never sent,
and flags the step ``unsafe-target`` as above), then waits for the robot to arrive at its
measured pose, measures the tool during the dwell and releases the player. A player's error
arrives here as the DeviceError of that wait (``robot-error``).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable

import numpy as np

from config import Settings
from daemon.arm.correction import CorrectionLimits, check_correction, correction_for
from daemon.arm.run import (
    ArmPredictor,
    MeasuredPose,
    MeasurementError,
    ToolMeasurement,
)
from daemon.arm.types import Pose6
from daemon.model.compensation import UnsafeTargetError
from daemon.run.arm.player import ArmPlayer
from daemon.run.arm.record import (
    camera_views,
    record_correction,
    record_measurement,
    record_model,
)
from daemon.run.arm.work import ArmRobot, ArmRunWork, ToolMeter
from daemon.run.events import ErrorLog
from daemon.run.scheduler import Tick
from daemon.run.sensors import Sensors
from daemon.run.stage_times import StageTimes
from daemon.run.step import (
    SENSOR_ERROR_FLAGS,
    StepOutcome,
    begin_record,
    finish_record,
    read_infrared,
    step_verdict,
)
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder, StepRecord
from drivers.errors import DeviceError

logger = logging.getLogger(__name__)

#: The flag of a step whose markers could not give a tool pose (a sensor error, like a
#: centroid error of the two-link bench).
MARKER_ERROR = "marker-error"
#: The step whose measurement became its pose's zero: no reference was measured there before
#: the first correction (daemon/run/arm/prepare.py), so its drift is zero by construction.
REFERENCE_MISSING = "first-step-reference"
#: The flag of a step whose room thermometer failed (the model keeps the last room).
ROOM_ERROR = "room-error"
ARM_SENSOR_ERROR_FLAGS = SENSOR_ERROR_FLAGS | {MARKER_ERROR, ROOM_ERROR}

#: ArmRunWork is also named here: a step pipeline's callers build its work with it
__all__ = ["ArmRunWork", "ArmStepPipeline", "correction_limits"]


def correction_limits(settings: Settings) -> CorrectionLimits:
    arm = settings.arm
    return CorrectionLimits(
        arm.max_translation_mm,
        arm.max_rotation_deg,
        arm.max_step_translation_mm,
        arm.max_step_rotation_deg,
    )


class ArmStepPipeline:
    def __init__(
        self,
        settings: Settings,
        *,
        robot: ArmRobot,
        meter: ToolMeter,
        sensors: Sensors,
        recorder: Recorder,
        workers: Workers,
        errors: ErrorLog,
        clock_now: Callable[[], float],
        player: ArmPlayer | None = None,
    ) -> None:
        self._player = player  # a played duty cycle: the robot is moved by it
        self._settings = settings
        self._robot = robot
        self._meter = meter
        self._sensors = sensors
        self._recorder = recorder
        self._workers = workers
        self._errors = errors
        self._now = clock_now
        self._limits = correction_limits(settings)

    async def run(self, work: ArmRunWork, tick: Tick) -> StepOutcome:
        record, flags = begin_record(work.run_id, work.parameters, work.start_s, tick)
        pose = work.pose_at(tick.step)
        record.arm_pose = pose.name
        if self._player is None:
            return await self._step(work, tick, pose, record, flags)
        self._player.expect(pose.name)  # before the model: the move into it waits for it
        try:
            return await self._step(work, tick, pose, record, flags)
        finally:
            self._player.release()

    async def _step(
        self,
        work: ArmRunWork,
        tick: Tick,
        pose: MeasuredPose,
        record: StepRecord,
        flags: list[str],
    ) -> StepOutcome:
        parameters = work.parameters
        run_time_s = tick.scheduled_s - work.start_s
        errors: list[str] = []
        stages = StageTimes()

        # 1. the room now (the model's ambient, issue 29), the model to the time the move is
        # expected to execute, then the tool error there
        started = time.perf_counter()
        room_c = await self._read_room(record, flags, errors)
        model_s = (run_time_s + self._settings.compensation.latency_s) * parameters.time_scale
        player = self._player
        if player is None:
            error = await self._workers.step(self._predict, work, model_s, pose, room_c)
            errors_by_pose = {pose.name: error}
        else:  # every pose of the played cycle at its own configuration, the arm warmed once
            errors_by_pose = await self._workers.step(self._predict_cycle, work, model_s, room_c)
            error = errors_by_pose[pose.name]
        record_model(work, record, error)
        stages.end("model", started)

        # 2. the corrections, checked before anything reaches the robot
        started = time.perf_counter()
        correction, unsafe = self._correction(work, pose, error)
        if player is not None and unsafe is None:
            unsafe = self._hand_to_player(work, player, errors_by_pose)
        if player is not None:
            (player.release if unsafe is not None else player.ready)()
        record_correction(record, correction)
        stages.end("check", started)

        # 3. the move to the pose's taught goal + the correction (played: the cycle's arrival)
        started = time.perf_counter()
        device_fault: str | None = None
        round_trips_s: tuple[float, ...] = ()
        if unsafe is not None:
            flags.append("unsafe-target")
            errors.append(unsafe)
        else:
            try:
                if player is None:
                    result = await self._robot.move_to_goal(pose.name, correction)
                    work.last_correction[pose.name] = correction
                else:
                    arrival = await player.arrive(pose.name)
                    result = arrival.result
                    record_correction(record, arrival.correction)
                round_trips_s = result.round_trips_s
                if result.pose is None:
                    flags.append("no-readback")
                else:
                    record.pose_x_mm, record.pose_y_mm, record.pose_z_mm = result.pose.position
            except DeviceError as err:
                self._errors.note(err)
                flags.append("robot-error")
                errors.append(str(err))
                device_fault = str(err)
        stages.end("move", started)

        # 4. measure the tool in every camera, and the IR regions
        # (played: the robot stays at the pose until the step is recorded, run() releases it:
        # a few ms beyond the dwell, and which arrival each step measures is reproducible)
        measurement: ToolMeasurement | None = None
        if device_fault is None and unsafe is None:
            measurement = await self._measure(
                work, pose=pose, record=record, flags=flags, errors=errors, stages=stages
            )

        # 5. record, committed before the next step begins
        finish_record(record, flags, errors, stages)
        started = time.perf_counter()
        await self._workers.db(self._recorder.write_step, record)
        stages.end("record", started)
        verdict = step_verdict(
            self._settings,
            unsafe=unsafe,
            device_fault=device_fault,
            flags=flags,
            record=record,
            sensor_error_flags=ARM_SENSOR_ERROR_FLAGS,
        )
        return StepOutcome(
            record,
            None,
            verdict,
            round_trips_s,
            stages,
            stages.ends_s,
            views=camera_views(measurement),
        )

    # --- 1. the model ------------------------------------------------------------------

    async def _read_room(
        self, record: StepRecord, flags: list[str], errors: list[str]
    ) -> float | None:
        """The room thermometer's reading (recorded), or None: no thermometer, or it failed
        (flagged room-error; the model keeps the last room)."""
        if not getattr(self._sensors, "has_room", False):
            return None
        try:
            reading = await self._sensors.read_room()
        except DeviceError as err:
            self._errors.note(err)
            flags.append(ROOM_ERROR)
            errors.append(str(err))
            return None
        record.room_c = reading.temperature_c
        return reading.temperature_c

    @staticmethod
    def _follow_room(predictor: ArmPredictor, room_c: float | None) -> None:
        """The room's reading to a predictor that follows one (daemon/arm/controller.py)."""
        follow = getattr(predictor, "follow_room", None)
        if room_c is not None and callable(follow):
            follow(room_c)

    @staticmethod
    def _predict(
        work: ArmRunWork, model_s: float, pose: MeasuredPose, room_c: float | None = None
    ) -> Pose6:
        """On the step's worker thread: the arm's model is tens of nodes per link and the
        motor heat integrates the duty cycle's motion over the step."""
        predictor = work.predictor
        ArmStepPipeline._follow_room(predictor, room_c)
        if model_s > predictor.time_s:
            predictor.advance_to(model_s)
        return predictor.tool_error(pose)

    @staticmethod
    def _predict_cycle(
        work: ArmRunWork, model_s: float, room_c: float | None = None
    ) -> dict[str, Pose6]:
        """The tool error at every pose of the played cycle (kinematics.tool_errors through
        the predictor's ``tool_errors`` when it has one), by cycle pose name; the measured
        poses under their names too."""
        predictor = work.predictor
        ArmStepPipeline._follow_room(predictor, room_c)
        if model_s > predictor.time_s:
            predictor.advance_to(model_s)
        poses = [entry.pose for entry in work.cycle]
        many = getattr(predictor, "tool_errors", None)
        found = many(poses) if callable(many) else [predictor.tool_error(p) for p in poses]
        out = {entry.name: e for entry, e in zip(work.cycle, found, strict=True)}
        for pose in work.poses:
            out.setdefault(pose.name, predictor.tool_error(pose))
        return out

    # --- 2. the correction ---------------------------------------------------------------

    def _correction(
        self, work: ArmRunWork, pose: MeasuredPose, error: Pose6
    ) -> tuple[Pose6, str | None]:
        """The correction of this step (zero when the run is not compensated) and why it is
        refused, or None."""
        if work.parameters.compensation == "off":
            return Pose6.zero(), None
        try:
            correction = correction_for(error, work.parameters.deformation_scale)
            return check_correction(correction, work.previous(pose), self._limits), None
        except UnsafeTargetError as err:
            return Pose6.zero(), f"correction of pose {pose.name!r} refused: {err}"

    def _hand_to_player(
        self, work: ArmRunWork, player: ArmPlayer, errors_by_pose: dict[str, Pose6]
    ) -> str | None:
        """Each played pose's correction, checked against the limits and the correction the
        robot was last sent into that pose (ArmPlayer.sent_correction); the accepted ones go
        to the player (the next move into each pose uses it), a refused one never does: the
        first refusal is returned for the step's verdict."""
        if work.parameters.compensation == "off":
            return None
        accepted: dict[str, Pose6] = {}
        refused: str | None = None
        for entry in work.cycle:
            try:
                correction = correction_for(
                    errors_by_pose[entry.name], work.parameters.deformation_scale
                )
                # against what the robot was last SENT into this pose: two handovers between
                # its visits must not add up to more than one step's change (issue 26)
                previous = player.sent_correction(entry.name)
                accepted[entry.name] = check_correction(correction, previous, self._limits)
            except UnsafeTargetError as err:
                refused = refused or f"correction of pose {entry.name!r} refused: {err}"
        work.last_correction.update(accepted)
        player.set_corrections(accepted)
        return refused

    # --- 4. measure ----------------------------------------------------------------------

    async def _measure(
        self,
        work: ArmRunWork,
        *,
        pose: MeasuredPose,
        record: StepRecord,
        flags: list[str],
        errors: list[str],
        stages: StageTimes,
    ) -> ToolMeasurement | None:
        started = time.perf_counter()
        measurement: ToolMeasurement | None = None
        try:
            measurement = await self._meter.measure(pose.tool_pose)
        except DeviceError as err:
            self._errors.note(err)
            flags.append("camera-error")
            errors.append(str(err))
        except MeasurementError as err:
            flags.append(MARKER_ERROR)
            errors.append(f"markers: {err}")
        stages.end("frame", started)
        if measurement is not None and record_measurement(work, pose, measurement, record):
            flags.append(REFERENCE_MISSING)
        started = time.perf_counter()
        means = await self._infrared(work, record, flags, errors)
        stages.end("ir", started)
        adapt = getattr(work.predictor, "adapt", None)
        if (
            measurement is not None
            and callable(adapt)
            and getattr(work.predictor, "adapting", False)
        ):
            # arm.adapt (issue 29): the tool's thermal displacement (the drift less the
            # correction commanded, as identification reads it) into the online estimate
            displacement = np.array(
                [
                    (record.measured_tx_um or 0.0) / 1000.0 - (record.correction_tx_mm or 0.0),
                    (record.measured_ty_um or 0.0) / 1000.0 - (record.correction_ty_mm or 0.0),
                    (record.measured_tz_um or 0.0) / 1000.0 - (record.correction_tz_mm or 0.0),
                ]
            )
            await self._workers.step(adapt, pose, displacement, means or {})
            estimates = work.predictor.adaptation_estimates()  # type: ignore[attr-defined]
            if estimates:
                record.observer_json = json.dumps(
                    {name: [round(v, 6) for v in pair] for name, pair in estimates.items()}
                )
        return measurement

    async def _infrared(
        self, work: ArmRunWork, record: StepRecord, flags: list[str], errors: list[str]
    ) -> dict[str, float] | None:
        """The IR regions on the links, recorded (identification reads them back:
        daemon/commands/arm_identify.py) and, with prediction model+ir, fused into the model."""
        reading = await read_infrared(
            self._sensors,
            self._errors,
            self._now,
            self._settings,
            record=record,
            flags=flags,
            errors=errors,
        )
        if reading is None:
            return None
        means = {name: region.mean_c for name, region in reading.regions.items()}
        observe = getattr(work.predictor, "observe", None)
        if callable(observe):
            # prediction model+ir: the IR regions correct the arm model's nodes, for the next
            # step's prediction (on the step's worker: a Kalman update of tens of nodes)
            await self._workers.step(observe, means)
        return means
