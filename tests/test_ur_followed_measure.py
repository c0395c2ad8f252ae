"""When a followed run's step measures the tool (daemon/run/followed/measure.py), against a meter
that reports known poses: only at the first step of a dwell at a measured pose with the joints
at rest; once per dwell; the residual against the pose's first measurement with both sigmas;
the uncompensated drift less the change of the applied offset; frames the program left its
pose during discarded. (The same on the UR bench with real cameras and the emulator over
TCP: tests/test_ur_followed_cameras.py.)"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

import numpy as np
import pytest

from daemon.arm.run import ToolMeasurement
from daemon.arm.types import FloatArray
from daemon.run.followed.measure import MEASURING, MOVED, DwellMeasurement
from daemon.storage.step_record import StepRecord
from drivers.base import OffsetRobotState

SIGMA_MM = 0.003


def state(
    at_pose: int, *, speed: float = 0.0, applied_mm: float = 0.0, instance: int = 7
) -> OffsetRobotState:
    return OffsetRobotState(
        timestamp_s=0.0,
        received_s=0.0,
        joints_rad=(0.0,) * 6,
        joint_speeds_rad_s=(speed,) + (0.0,) * 5,
        tcp_pose=(0.0,) * 6,
        tcp_speed=(0.0,) * 6,
        joint_temperatures_c=(22.0,) * 6,
        robot_mode=7,
        safety_mode=1,
        runtime_state=2,
        at_pose=at_pose,
        accepted_sequence=0,
        program_status=0,
        applied_offset_mm=(applied_mm, 0.0, 0.0),
        applied_rotation_rad=(0.0, 0.0, 0.0),
        program_instance=instance,
    )


class Meter:
    """Reports the tool at x = ``x_mm`` (the test moves it), counting its measurements."""

    def __init__(self) -> None:
        self.x_mm = 0.0
        self.calls = 0

    async def measure(
        self, expected_pose: FloatArray, frames: int | None = None
    ) -> ToolMeasurement:
        self.calls += 1
        pose = np.eye(4)
        pose[0, 3] = 500.0 + self.x_mm
        return ToolMeasurement(pose, SIGMA_MM, True, {})


def record(step: int = 0, flags: str = "") -> StepRecord:
    return StepRecord(
        run_id=1, step=step, scheduled_s=0.0, actual_s=0.0, lateness_s=0.0, flags=flags
    )


class Rows:
    """The rows the measurement writes again (the kind's Recorder.write_step replace)."""

    def __init__(self) -> None:
        self.written: list[StepRecord] = []

    async def __call__(self, row: StepRecord) -> None:
        self.written.append(row)


async def measure_now(
    dwell: DwellMeasurement, s: OffsetRobotState, rows: Rows
) -> tuple[ToolMeasurement | None, StepRecord | None, list[str]]:
    """One step: start (when it is the dwell's first at rest), then the outcome awaited."""
    r = record(flags="bench-truth")
    flags: list[str] = []
    if not dwell.start(s, r, flags):
        return None, None, flags
    assert flags == [MEASURING] and dwell.pending
    r.flags = ",".join(["bench-truth", *flags])  # as the kind's finish_record writes it
    before = len(rows.written)
    measured = await dwell.collect(rows, wait_s=5.0)
    assert len(rows.written) == before + 1 and not dwell.pending
    row = rows.written[-1]
    return measured, row, row.flags.split(",")


async def test_one_measurement_per_dwell_at_rest_against_the_pose_zero() -> None:
    meter = Meter()
    after = [state(1)]
    rows = Rows()
    dwell = DwellMeasurement(meter, lambda q: np.eye(4), lambda: after[0], 6)

    async def step(s: OffsetRobotState) -> tuple[ToolMeasurement | None, StepRecord, list[str]]:
        measured, row, flags = await measure_now(dwell, s, rows)
        return measured, row if row is not None else record(), flags

    assert (await step(state(0)))[0] is None  # moving: no frame
    assert (await step(state(1, speed=0.05)))[0] is None  # at the pose, not at rest yet
    assert meter.calls == 0
    measured, r, flags = await step(state(1))  # at rest: the pose's zero
    assert measured is not None and "first-step-reference" in flags and r.drift_3d_um == 0.0
    # the camera's measurement replaced the truth's columns and flags of the step
    assert MEASURING not in flags and "bench-truth" not in flags
    assert (await step(state(1)))[0] is None and meter.calls == 1  # the same dwell: once
    await step(state(0))
    # the next dwell at pose 1: the tool 0.1 mm further, of which the program applied 0.04
    meter.x_mm = 0.1
    after[0] = state(1, applied_mm=0.04)
    measured, r, flags = await step(state(1))
    assert measured is not None and "first-step-reference" not in flags
    assert r.measured_tx_um == pytest.approx(100.0) and r.drift_3d_um == pytest.approx(100.0)
    assert r.measured_sigma_um == pytest.approx(math.hypot(SIGMA_MM, SIGMA_MM) * 1000.0)
    summary = dwell.tally.summary(6)
    assert summary["measurements"] == 1 and summary["poses"] == {"1": 1}
    assert summary["rms_residual_um"] == pytest.approx(100.0)
    assert summary["rms_uncompensated_um"] == pytest.approx(60.0)  # 100 less the 40 applied
    # another instance of the program at pose 1 is a new dwell
    after[0] = state(1, instance=8)
    assert (await step(state(1, instance=8)))[0] is not None and meter.calls == 3


def reads(*states: OffsetRobotState) -> Callable[[], OffsetRobotState]:
    """The robot's latest state, read after read: each of ``states`` once, the last for ever."""
    queue = list(states)
    return lambda: queue.pop(0) if len(queue) > 1 else queue[0]


async def test_a_dwell_the_latest_state_has_left_starts_nothing() -> None:
    """The step's state says pose 2 at rest, the latest one (read when starting) says the
    program moved on: no frame is grabbed."""
    meter = Meter()
    dwell = DwellMeasurement(meter, lambda q: np.eye(4), lambda: state(0), 6)
    assert not dwell.start(state(2), record(), []) and not dwell.pending and meter.calls == 0


async def test_frames_the_program_left_its_pose_during_are_discarded() -> None:
    meter = Meter()
    rows = Rows()
    dwell = DwellMeasurement(meter, lambda q: np.eye(4), reads(state(2), state(0)), 6)
    measured, row, flags = await measure_now(dwell, state(2), rows)
    assert measured is None and row is not None
    assert meter.calls == 1 and flags == ["bench-truth", MOVED] and "left pose 2" in row.error
    assert dwell.tally.summary(6)["discarded"] == {MOVED: 1}
    # a robot moving again after the frames (at the pose, not at rest): discarded too
    dwell = DwellMeasurement(meter, lambda q: np.eye(4), reads(state(2), state(2, speed=0.05)), 6)
    measured, row, flags = await measure_now(dwell, state(2), rows)
    assert measured is None and flags == ["bench-truth", MOVED]


class HeldMeter(Meter):
    """A meter whose measurement is in only when the test lets it be."""

    def __init__(self) -> None:
        super().__init__()
        self.release = asyncio.Event()
        self.started = False

    async def measure(
        self, expected_pose: FloatArray, frames: int | None = None
    ) -> ToolMeasurement:
        self.started = True
        await self.release.wait()
        return await super().measure(expected_pose, frames)


async def test_the_steps_do_not_wait_for_the_meter() -> None:
    """A measuring step returns with the meter still measuring; the steps after it go on
    (none waits, none starts a second measurement); the measurement, once in, is written into
    the measuring step's own row, not the collecting step's."""
    meter = HeldMeter()
    rows = Rows()
    dwell = DwellMeasurement(meter, lambda q: np.eye(4), lambda: state(1), 6)
    measuring = record(step=10)
    flags: list[str] = []
    assert dwell.start(state(1), measuring, flags) and flags == [MEASURING]
    measuring.flags = "bench-truth,measuring"
    for _ in range(3):  # the next steps: nothing in yet, nothing waited for, nothing started
        assert await asyncio.wait_for(dwell.collect(rows), 1.0) is None
        assert not dwell.start(state(1, instance=9), record(), [])  # another dwell: later
    assert meter.started and not rows.written and dwell.pending
    meter.release.set()
    measured = await dwell.collect(rows, wait_s=5.0)
    assert measured is not None and [r.step for r in rows.written] == [10]
    assert rows.written[0].flags == "first-step-reference"
    assert measuring.flags == "bench-truth,measuring"  # the step's own record is left alone


async def test_a_measurement_not_in_by_the_hold_is_given_up_on_its_step() -> None:
    meter = HeldMeter()
    rows = Rows()
    dwell = DwellMeasurement(meter, lambda q: np.eye(4), lambda: state(1), 6)
    assert dwell.start(state(1), record(step=4, flags="bench-truth,measuring"), [])
    assert await dwell.collect(rows, wait_s=0.05) is None and not dwell.pending
    assert [r.step for r in rows.written] == [4]
    assert rows.written[0].flags == "bench-truth,camera-error"
    assert "no measurement in 0.05 s" in rows.written[0].error
    assert dwell.tally.summary(6)["discarded"] == {"camera-error": 1}


def test_a_run_with_no_camera_says_so() -> None:
    dwell_tally = DwellMeasurement(Meter(), lambda q: np.eye(4), lambda: state(0), 0).tally
    summary = dwell_tally.summary(0)
    assert summary["cameras"] == 0 and "no camera" in summary["note"]
