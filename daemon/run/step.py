"""What every run kind's step has in common (daemon/run/kind.py ``step``): its outcome and
verdict, which the session acts on (daemon/run/session.py), and the parts of the record every
kind's pipeline fills the same way (its times and lateness, flags, errors, stage timings, the
IR reading). A kind's own step is in its package (daemon/run/two_link/step.py, arm/step.py,
followed/kind.py)."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

from numpy.typing import NDArray

from config import Settings
from daemon.run.events import ErrorLog
from daemon.run.scheduler import Tick
from daemon.run.sensors import Sensors
from daemon.run.states import RunParameters
from daemon.storage.recorder import StepRecord
from drivers.base import Frame, IrReading
from drivers.errors import DeviceError

#: A step that begins more than this fraction of a period after its deadline is flagged late.
LATE_FRACTION = 0.1
#: Flags that scheduler.sensor_error_policy acts on (issue 10). A stale frame or reading
#: counts: it is recorded but never used, so the step has no measurement.
SENSOR_ERROR_FLAGS = frozenset(
    {"camera-error", "ir-error", "centroid-error", "stale-frame", "stale-ir"}
)


@dataclass(frozen=True, slots=True)
class Verdict:
    """What a step asks of its run: go on, pause (a refused target, a sensor error under the
    "pause" policy) or park in fault (a device fault)."""

    kind: Literal["ok", "pause", "fault"]
    reason: str | None = None


OK = Verdict("ok")


@dataclass(frozen=True, slots=True)
class StepOutcome:
    record: StepRecord  # committed before the outcome is returned
    frame: Frame | None
    verdict: Verdict
    round_trips_s: tuple[float, ...] = ()  # each console command of the move (s)
    stages_s: dict[str, float] = field(default_factory=dict)  # scheduler.STAGES timings
    # when each stage ended, from the step's start (s; daemon/run/stage_times.py)
    stage_ends_s: dict[str, float] = field(default_factory=dict)
    # an arm step: each tool camera's frame and the markers it measured, for live views
    views: tuple[CameraView, ...] = ()


@dataclass(frozen=True, eq=False)
class MeasuringStep:
    """A step whose move is made and whose frame is taken, while its centroid, IR reading and
    record are still under way (issue 30: they overlap the next steps' moves, so a 20 ms step
    pays only model -> check -> move -> frame on its period). ``outcome`` ends with the
    committed step's outcome; the session collects it in step order once it is done, at most
    session.MEASURING_STEPS behind the step moving, or at once
    when ``settle_before_next``: the next step needs this measurement before it predicts (an
    observer fuses it into the model) or before it moves (sensor_error_policy "pause")."""

    step: int
    outcome: asyncio.Future[StepOutcome]
    settle_before_next: bool

    @property
    def may_overlap(self) -> bool:
        """Whether later steps may move before this one is collected."""
        return not (self.settle_before_next or self.outcome.done())

    @classmethod
    def of(cls, step: int, outcome: StepOutcome | MeasuringStep) -> MeasuringStep:
        """``outcome`` as a step to collect in order (a step that measured nothing is done)."""
        if isinstance(outcome, MeasuringStep):
            return outcome
        done: asyncio.Future[StepOutcome] = asyncio.get_running_loop().create_future()
        done.set_result(outcome)
        return cls(step, done, settle_before_next=True)


@dataclass(frozen=True, eq=False)
class CameraView:
    """One tool camera's frame of an arm step, for the dashboard (issue 28): the camera's
    name, its image (a reference, never written to again) and the marker centroids (px)."""

    camera: str
    image: NDArray[Any]
    markers_px: tuple[tuple[float, float], ...] = ()


def begin_record(
    run_id: int, parameters: RunParameters, start_s: float, tick: Tick
) -> tuple[StepRecord, list[str]]:
    """The step's record with its times (run clock from ``start_s``), and its first flags:
    ``late`` when it begins more than LATE_FRACTION of a period after its deadline."""
    record = StepRecord(
        run_id=run_id,
        step=tick.step,
        scheduled_s=tick.scheduled_s - start_s,
        actual_s=tick.actual_s - start_s,
        lateness_s=tick.actual_s - tick.scheduled_s,
        deformation_scale=parameters.deformation_scale,
    )
    flags: list[str] = []
    if record.lateness_s > LATE_FRACTION * parameters.step_s:
        flags.append("late")
    return record, flags


def finish_record(
    record: StepRecord, flags: list[str], errors: list[str], stages: dict[str, float]
) -> None:
    """The step's flags, errors and stage timings (ms) into its record, before it is written
    (the record's own stage cannot be in it: it is in the timing statistics only)."""
    record.flags = ",".join(flags)
    record.error = "; ".join(errors)
    record.stage_ms_json = json.dumps({k: round(v * 1e3, 3) for k, v in stages.items()})


def step_verdict(
    settings: Settings,
    *,
    unsafe: str | None,
    device_fault: str | None,
    flags: list[str],
    record: StepRecord,
    sensor_error_flags: frozenset[str],
) -> Verdict:
    """What the step asks of its run: a pause for a refused target, a fault for a device
    fault, a pause for a sensor error (one of ``sensor_error_flags``) under the "pause"
    policy (scheduler.sensor_error_policy), else go on."""
    if unsafe is not None:
        return Verdict("pause", unsafe)
    if device_fault is not None:
        return Verdict("fault", device_fault)
    if settings.scheduler.sensor_error_policy == "pause" and (set(flags) & sensor_error_flags):
        return Verdict("pause", f"sensor error: {record.error}")
    return OK


async def read_infrared(
    sensors: Sensors,
    errors_log: ErrorLog,
    now: Callable[[], float],
    settings: Settings,
    *,
    record: StepRecord,
    flags: list[str],
    errors: list[str],
) -> IrReading | None:
    """The step's IR reading, recorded (``ir_json``; identification reads it back) and
    flagged: ``ir-error`` when it failed, ``stale-ir`` when older than ir.max_age_s. The
    reading when it may be fused into the model, None otherwise (a stale reading is recorded,
    never fused)."""
    try:
        reading = await sensors.read_ir()
    except DeviceError as err:
        errors_log.note(err)
        flags.append("ir-error")
        errors.append(str(err))
        return None
    record.ir_json = json.dumps(
        {
            name: {"mean_c": region.mean_c, "max_c": region.max_c}
            for name, region in reading.regions.items()
        }
    )
    age_s = now() - reading.timestamp_s
    if age_s > settings.ir.max_age_s:
        flags.append("stale-ir")
        errors.append(sensors.stale("ir", "reading", age_s))
        return None
    return reading
