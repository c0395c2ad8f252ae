"""One step of a run (thesis 6.4), top to bottom: model -> target check -> move -> frame ->
centroid and IR -> record. The pipeline computes the step and returns its outcome (the
committed record, the frame, and a verdict: ok, pause(reason) or fault(reason)); it never
changes the run's state. What the verdict does to the run is decided in one place,
daemon/run/session.py, against the operator's requests that may have arrived meanwhile.

Once the frame is taken the step returns a MeasuringStep (issue 30): its centroid, IR reading
and record overlap the next steps' moves, which the thesis's step allows -- the move is computed
from the model alone (6.4.1), and the measurement only says what the move achieved. The frame
itself is taken before the next move (it must show this step's pose); measurements and records
stay in step order; an observer (whose update the next prediction uses) or the "pause" sensor
policy (which must act before another move) makes the next step wait for it first.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from config import Settings
from daemon.model.compensation import (
    CompensationLimits,
    UnsafeTargetError,
    check_offset,
    compensation_offset_mm,
)
from daemon.run.events import ErrorLog
from daemon.run.scheduler import Tick
from daemon.run.sensors import Sensors
from daemon.run.stage_times import StageTimes
from daemon.run.states import ProcedurePoint, heat_at, procedure_point
from daemon.run.step import (
    SENSOR_ERROR_FLAGS,
    MeasuringStep,
    StepOutcome,
    begin_record,
    finish_record,
    step_verdict,
)
from daemon.run.two_link.measure import StepMeasurement
from daemon.run.two_link.work import RunWork
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder, RecorderError, StepRecord
from drivers.base import Frame, MoveResult, Pose, Robot
from drivers.errors import DeviceError

logger = logging.getLogger(__name__)

#: Model advances above this many node-substeps of work go to the step's worker thread (numpy
#: releases the GIL); a 17-node exact step is a few microseconds and stays on the loop.
MODEL_WORK_OFF_LOOP = 200_000


class StepPipeline:
    def __init__(
        self,
        settings: Settings,
        *,
        robot: Robot,
        sensors: Sensors,
        recorder: Recorder,
        workers: Workers,
        errors: ErrorLog,
        clock_now: Callable[[], float],
    ) -> None:
        self._settings = settings
        self._robot = robot
        self._sensors = sensors
        self._recorder = recorder
        self._workers = workers
        self._errors = errors
        self._now = clock_now
        self._measurement = StepMeasurement(
            settings, sensors=sensors, workers=workers, errors=errors, clock_now=clock_now
        )
        # the last step's place in the order of measurements and records (MeasuringStep)
        self._last_turn: _Turn | None = None

    async def run(self, work: RunWork, tick: Tick) -> StepOutcome | MeasuringStep:
        parameters = work.parameters
        run_time_s = tick.scheduled_s - work.start_s
        record, flags = begin_record(work.run_id, parameters, work.start_s, tick)
        errors: list[str] = []
        stages = StageTimes()
        point = procedure_point(parameters, tick.step, run_time_s)

        # 1. the model, to the time the move is expected to execute (latency-compensated)
        started = time.perf_counter()
        predicted_um = await self._advance_model(work, run_time_s)
        self._record_model(work, record, predicted_um)
        stages.end("model", started)

        # 2. the compensation target, checked before anything reaches the robot
        started = time.perf_counter()
        offset, target, unsafe = self._target(work, point, predicted_um)
        record.offset_x_mm, record.offset_y_mm, record.offset_z_mm = map(float, offset)
        stages.end("check", started)

        # 3. the move (absolute from the goal, incremental, or none), then the actual pose
        started = time.perf_counter()
        device_fault: str | None = None
        round_trips_s: tuple[float, ...] = ()
        if unsafe is not None:
            flags.append("unsafe-target")
            errors.append(unsafe)
        else:
            try:
                pose, round_trips_s = await self._move(work, target)
                work.last_offset_mm = offset
                work.last_target_mm = target
                if pose is None:  # robot.readback_every > 1: this move was not read back
                    flags.append("no-readback")
                else:
                    record.pose_x_mm, record.pose_y_mm, record.pose_z_mm = pose.position
            except DeviceError as err:
                self._errors.note(err)
                flags.append("robot-error")
                errors.append(str(err))
                device_fault = str(err)
        stages.end("move", started)

        # 4. measure: the frame now (it shows the pose this step moved to); its centroid, the
        # IR reading and the record overlap the next steps' moves (MeasuringStep)
        previous, turn = self._last_turn, _Turn()
        self._last_turn = turn
        if point.capture and device_fault is None and unsafe is None:
            frame, age_s = await self._measurement.grab(flags, errors, stages)
            measuring = asyncio.create_task(
                self._measured(
                    work,
                    point=point,
                    tick=tick,
                    record=record,
                    frame=frame,
                    frame_age_s=age_s,
                    flags=flags,
                    errors=errors,
                    stages=stages,
                    round_trips_s=round_trips_s,
                    previous=previous,
                    turn=turn,
                ),
                name=f"run {work.run_id} step {tick.step}: measure and record",
            )
            return MeasuringStep(tick.step, measuring, self._settle_before_next(work))
        return await self._recorded(
            work,
            tick=tick,
            record=record,
            frame=None,
            flags=flags,
            errors=errors,
            stages=stages,
            unsafe=unsafe,
            device_fault=device_fault,
            round_trips_s=round_trips_s,
            previous=previous,
            turn=turn,
        )

    def _settle_before_next(self, work: RunWork) -> bool:
        """Whether the next step must wait for this one's measurement before it begins: an
        observer fuses the measurement into the model the next step predicts with, and the
        "pause" policy pauses on a sensor error before another move is made."""
        return work.observer is not None or self._settings.scheduler.sensor_error_policy == "pause"

    async def _measured(
        self,
        work: RunWork,
        *,
        point: ProcedurePoint,
        tick: Tick,
        record: StepRecord,
        frame: Frame | None,
        frame_age_s: float,
        flags: list[str],
        errors: list[str],
        stages: StageTimes,
        round_trips_s: tuple[float, ...],
        previous: _Turn | None,
        turn: _Turn,
    ) -> StepOutcome:
        """The step's centroid and IR reading after the previous step's (the devices are
        read in step order), then its record after the previous step's record."""
        try:
            if previous is not None:
                await previous.measured.wait()
            started = time.perf_counter()
            if frame is not None:
                await self._measurement.centroid(
                    work,
                    point=point,
                    frame=frame,
                    age_s=frame_age_s,
                    record=record,
                    flags=flags,
                    errors=errors,
                )
            stages.end("centroid", started)
            started = time.perf_counter()
            await self._measurement.infrared(work, record, flags, errors)
            stages.end("ir", started)
        finally:
            turn.measured.set()  # whatever happened here: the next step's measurement goes on
        return await self._recorded(
            work,
            tick=tick,
            record=record,
            frame=frame,
            flags=flags,
            errors=errors,
            stages=stages,
            unsafe=None,
            device_fault=None,
            round_trips_s=round_trips_s,
            previous=previous,
            turn=turn,
        )

    async def _recorded(
        self,
        work: RunWork,
        *,
        tick: Tick,
        record: StepRecord,
        frame: Frame | None,
        flags: list[str],
        errors: list[str],
        stages: StageTimes,
        unsafe: str | None,
        device_fault: str | None,
        round_trips_s: tuple[float, ...],
        previous: _Turn | None,
        turn: _Turn,
    ) -> StepOutcome:
        """5. record, committed after the previous step's (the records stay in step order:
        readers page through them by step) and before the next step's; then the verdict."""
        turn.measured.set()
        try:
            if previous is not None:
                await previous.written.wait()
                if previous.failed is not None:  # no gap: nothing is written after it
                    turn.failed = previous.failed
                    raise RecorderError(f"step {tick.step} not recorded: {previous.failed}")
            finish_record(record, flags, errors, stages)
            started = time.perf_counter()
            archive_every = self._settings.storage.archive_every
            if frame is not None and archive_every and tick.step % archive_every == 0:
                record.frame_path = await self._workers.db(
                    self._recorder.archive_frame, work.run_id, tick.step, frame.image
                )
            await self._workers.db(self._recorder.write_step, record)
            stages.end("record", started)
        except BaseException as err:
            turn.failed = turn.failed or f"step {tick.step}'s record failed: {err}"
            raise
        finally:
            # a failed write is the session's to handle (it collects this step): the next
            # record still goes after this one
            turn.written.set()
        verdict = step_verdict(
            self._settings,
            unsafe=unsafe,
            device_fault=device_fault,
            flags=flags,
            record=record,
            sensor_error_flags=SENSOR_ERROR_FLAGS,
        )
        return StepOutcome(record, frame, verdict, round_trips_s, stages, stages.ends_s)

    # --- 1. the model ------------------------------------------------------------------

    async def _advance_model(self, work: RunWork, run_time_s: float) -> NDArray[np.float64]:
        """Advance the model to the expected execution time, switching the heaters at the
        procedure's switching time exactly; return the predicted deformation vector (um)."""
        parameters = work.parameters
        scale = parameters.time_scale
        target_model_s = (run_time_s + self._settings.compensation.latency_s) * scale
        model = work.model
        if parameters.heater_off_s is not None:
            switch_s = parameters.heater_off_s * scale
            if model.time_s < switch_s <= target_model_s:
                await self._advance_to(work, switch_s)
                if work.observer is not None:  # adaptation scales the heat of each interval
                    work.observer.predict(model.time_s)
        if target_model_s > model.time_s:
            await self._advance_to(work, target_model_s)
        if work.observer is not None:
            work.observer.predict(model.time_s)  # the covariance follows the model's mean
            # an adapted expansion factor (observer.adapt, "alpha") scales the prediction
            return model.deformation_um() * work.observer.deformation_gain
        return model.deformation_um()

    async def _advance_to(self, work: RunWork, model_s: float) -> None:
        model = work.model
        # the heat over the interval is the procedure's at its start (a step input)
        heat = heat_at(work.parameters, model.time_s / work.parameters.time_scale + 1e-9)
        if heat != work.model_heat:
            model.set_heat(heat)
            work.model_heat = heat
        nodes = len(model.network.node_names)
        work_units = nodes * nodes * max(1.0, (model_s - model.time_s) / max(model.dt_s, 1e-9))
        if work_units > MODEL_WORK_OFF_LOOP:
            await self._workers.step(model.advance_to, model_s)
        else:
            model.advance_to(model_s)

    @staticmethod
    def _record_model(work: RunWork, record: StepRecord, predicted_um: NDArray[np.float64]) -> None:
        model = work.model
        record.model_time_s = model.time_s
        record.predicted_x_um, record.predicted_y_um, record.predicted_z_um = map(
            float, predicted_um
        )
        temperatures = np.round(model.temperatures_c, 4).tolist()
        record.model_temperatures_json = json.dumps(
            dict(zip(model.network.node_names, temperatures, strict=True))
        )
        if work.observer is not None:
            record.deformation_sigma_um = work.observer.corrected_deformation_um()[1]

    # --- 2. the target -----------------------------------------------------------------

    def _target(
        self, work: RunWork, point: ProcedurePoint, predicted_um: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.float64], str | None]:
        """The compensating offset (thesis 6.4.4: -scale x deformation from the goal), the
        motion target, and why it is refused (limits, non-finite) or None."""
        parameters = work.parameters
        offset = np.zeros(3)
        target = np.asarray(point.pose_offset_mm, dtype=np.float64)
        unsafe: str | None = None
        if parameters.compensation != "off":
            limits = CompensationLimits(
                self._settings.compensation.max_step_change_mm,
                self._settings.compensation.max_total_offset_mm,
            )
            try:
                offset = check_offset(
                    compensation_offset_mm(predicted_um, parameters.deformation_scale),
                    work.last_offset_mm,
                    limits,
                )
            except UnsafeTargetError as err:
                unsafe = f"compensation target refused: {err}"
            target = target + offset
        if unsafe is None and not np.all(np.isfinite(target)):
            unsafe = f"motion target is not finite: {target.tolist()}"
        return offset, target, unsafe

    # --- 3. the move ---------------------------------------------------------------------

    async def _move(
        self, work: RunWork, target_mm: NDArray[np.float64]
    ) -> tuple[Pose | None, tuple[float, ...]]:
        """The move of this step, if any: the actual pose after it (None when the driver did
        not read it back), and the round trip of each console command it took."""
        mode = work.parameters.compensation
        moving_procedure = work.parameters.procedure != "stationary"
        result: MoveResult | None = None
        if mode == "absolute" or (mode == "off" and moving_procedure):
            result = await self._robot.move_absolute(_vector3(target_mm))
        elif mode == "incremental":
            # thesis 6.4.3: each move is relative to where the previous one should have ended
            result = await self._robot.move_incremental(_vector3(target_mm - work.last_target_mm))
        if result is not None:
            return result.pose, result.round_trips_s
        return await self._robot.actual_pose(), ()


@dataclass(eq=False)
class _Turn:
    """A step's place in the order of measurements and records: the next step measures once
    this one has (``measured``) and writes its record once this one's is written."""

    measured: asyncio.Event = field(default_factory=asyncio.Event)
    written: asyncio.Event = field(default_factory=asyncio.Event)
    failed: str | None = None  # why its record was not written (then no later one is)


def _vector3(array: NDArray[np.float64]) -> tuple[float, float, float]:
    return (float(array[0]), float(array[1]), float(array[2]))
