"""The tool measured by the cameras in a followed run (issue 31), when the robot's own program
dwells at a measured pose.

The program says where it is: its "at measured pose" register (controller/ur/
thermocomp_offset.script, drivers/ur/registers.py) is k while it dwells at pose k of its cycle
and that pose is measured, 0 elsewhere. The first step of each dwell with the joints at rest
starts one measurement of the tool (a failed try is not repeated in that dwell):
every camera's frames (``arm.frames_per_measurement``), the marker centroids, the tool's pose
(the arm run's meter, daemon/run/arm/measure.py, several cameras: thesis 7.2.2), starting from
the nominal arm's pose at the robot's current joints. The frames count only if the program was
still at that dwell when they were taken: the state read before the grab and the one read after
it both say pose k, the same program instance, and joints at rest (``STILL_RAD_S``); else the
measurement is thrown away (flag ``moved-during-frames``) and nothing is recorded from it.

**The program holds its dwell for the frames** (a robot with ``hold_dwell``: :class:`DwellHold`,
drivers/ur/robot.py). A PC slower than the taught dwell saw the program leave during every
measurement: on a loaded PC (two busy loops beside the run) the frames and the fit took
0.8-2.9 s against dwells of 0.5-1 s, and every measurement was thrown away. So the measurement
first asks the program to hold the dwell (the frames register, answered by the program's
``tc_wait_for_frames``: controller/ur/README.md) and takes its frames only when the
controller's read-back shows the program still at that dwell; it lets the program go once the
state after the frames is read (also when it fails or is cancelled). The program holds at most
its FRAMES_TIMEOUT_S (5 s), and not while the PC is silent: past that the check after the
frames throws them away as before. Why not the other ways: computing after the frames would
take only the fit out of the dwell, while the frames too slow down with the PC's load; the
emulator in its own process would spare only the bench, not a lab PC (docs/how-to/
universal-robots.md, "Cameras on a UR").

**The steps do not wait for the meter.** Six cameras' frames and the fit take 60-100 ms on the
UR bench (closing note of 2026-11-27), most of a 0.1 s step: measured inside the step, a
measuring step overran its period while the robot dwelt, and the correction of the next step
came late. So the measuring step only *starts* the measurement (a task of its own, flag
``measuring``) and goes on: its record is written as any step's. A later step (or the run's
hold or end: :meth:`DwellMeasurement.collect` with a wait) takes the finished measurement and
rewrites the measuring step's row with it (Recorder.write_step ``replace``): the measurement
stays attached to the step whose frames it is, with that step's joints and time, and the flag
``measuring`` gives way to the outcome. One measurement at a time: a dwell that begins while
the last one is still being measured starts its own at its first step after that.

As in an arm run (daemon/run/arm/record.py), a pose's drift is its measured pose relative to
its *reference*: here the run's first measurement at that pose (flag
``first-step-reference``: its drift is zero by construction). The robot applies the offset
the daemon wrote, so the measured drift is the residual (what the correction left); its
1-sigma combines the measurement's and the reference's. The uncompensated drift is the
residual less the change of the offset the program applied since the reference.

On the UR bench the truth's residual at the same instant is kept beside each measurement (the
summary's ``measured_vs_truth``: how far the cameras are from the truth, in their own sigmas);
the step's columns hold the camera's measurement.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import math
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from daemon.arm.run import (
    UM_PER_MM,
    MeasurementError,
    ToolMeasurement,
    angle_urad,
    norm_um,
    rotation_urad,
    translation_um,
)
from daemon.arm.types import FloatArray, pose_difference
from daemon.run.arm.step import REFERENCE_MISSING
from daemon.storage.step_record import StepRecord
from drivers.base import OffsetRobotState
from drivers.errors import DeviceError

#: A joint faster than this (rad/s) before or after the frames: the robot was not at rest
#: (0.01 rad/s is 5 mm/s at half a metre; the program's own offset moves the joints by at most
#: its rate limit, 1 mm/s: controller/ur/thermocomp_offset.script MAX_SPEED_M_S).
STILL_RAD_S = 0.01
#: The flag of a measurement thrown away because the program left the dwell during its frames.
MOVED = "moved-during-frames"
#: The flag of a step whose measurement was started and was not in when its row was written.
MEASURING = "measuring"
#: The flags a camera measurement replaces (kind.py: the step's "nothing measured" marks).
UNMEASURED_FLAGS = frozenset({MEASURING, "bench-truth", "no-measurement"})
#: The record's measurement columns: a camera measurement replaces all of them (the bench
#: truth's values that the measuring step recorded meanwhile included).
MEASURED_COLUMNS = (
    "measured_tx_um",
    "measured_ty_um",
    "measured_tz_um",
    "measured_rx_urad",
    "measured_ry_urad",
    "measured_rz_urad",
    "drift_3d_um",
    "rotation_error_urad",
    "measured_sigma_um",
    "measured_rotation_sigma_urad",
)


class Meter(Protocol):
    """The tool's 3-D measurement (daemon/run/arm/work.py ToolMeter)."""

    async def measure(
        self, expected_pose: FloatArray, frames: int | None = None
    ) -> ToolMeasurement: ...


@dataclass
class MeasuredTally:
    """The camera-measured residuals of a run: sums for the summary's accuracy, the
    discarded measurements by cause, and (bench) the cameras against the truth."""

    measurements: int = 0
    residual_um2: float = 0.0
    uncompensated_um2: float = 0.0
    worst_residual_um: float = 0.0
    sigma_um_sum: float = 0.0
    poses: dict[str, int] = field(default_factory=dict)
    discarded: dict[str, int] = field(default_factory=dict)
    #: (bench) each measurement's distance from the truth, in um and in its own sigmas
    truth_difference_um: list[float] = field(default_factory=list)
    truth_difference_sigmas: list[float] = field(default_factory=list)

    def summary(self, cameras: int) -> dict[str, Any]:
        if cameras == 0:
            return {
                "cameras": 0,
                "measurements": 0,
                "note": "no camera: the correction is the model's and the joint temperatures' "
                "alone, nothing measured",
            }
        out: dict[str, Any] = {
            "cameras": cameras,
            "measurements": self.measurements,
            "poses": dict(self.poses),
            "discarded": dict(self.discarded),
            "reference": "each pose's first measurement in the run",
        }
        if self.measurements:
            rms = math.sqrt(self.residual_um2 / self.measurements)
            rms_uncompensated = math.sqrt(self.uncompensated_um2 / self.measurements)
            out |= {
                "rms_residual_um": rms,
                "worst_residual_um": self.worst_residual_um,
                "rms_uncompensated_um": rms_uncompensated,
                "removed_fraction": 1.0 - rms / rms_uncompensated
                if rms_uncompensated > 0
                else None,
                "mean_sigma_um": self.sigma_um_sum / self.measurements,
            }
        return out

    def truth_summary(self) -> dict[str, Any]:
        """The cameras against the bench truth (the bench only)."""
        n = len(self.truth_difference_um)
        if n == 0:
            return {"measurements": 0}
        return {
            "measurements": n,
            "rms_difference_um": math.sqrt(float(np.mean(np.square(self.truth_difference_um)))),
            "worst_difference_sigmas": max(self.truth_difference_sigmas),
            "within_3_sigma_fraction": float(np.mean(np.less(self.truth_difference_sigmas, 3.0))),
        }


@dataclass
class _Reference:
    pose: FloatArray  # the tool's measured pose (4x4)
    sigma_mm: float
    applied_mm: FloatArray  # the offset the program applied then
    truth_mm: FloatArray | None  # (bench) the truth's residual then


@dataclass(frozen=True)
class _Taken:
    """A measurement whose frames were taken during the dwell."""

    pose_name: str
    measurement: ToolMeasurement
    after: OffsetRobotState  # the robot's state read after the frames
    truth: FloatArray | None  # (bench) the truth's residual right after the frames


@dataclass(frozen=True)
class _Discarded:
    flag: str
    message: str


@dataclass(eq=False)
class _Pending:
    """A measurement in flight: the measuring step's record (as written) and its task."""

    record: StepRecord
    task: asyncio.Task[_Taken | _Discarded]


#: Writes a step's row again (the kind's: Recorder.write_step with replace, on the db worker).
RowWriter = Callable[[StepRecord], Awaitable[object]]


@runtime_checkable
class DwellHold(Protocol):
    """A robot whose program holds a measured pose's dwell while the PC takes its frames
    (module docstring; drivers/ur/robot.py URRobot)."""

    async def hold_dwell(self, pose: int) -> OffsetRobotState:
        """Ask for the hold at measured pose ``pose``; the state after the controller read
        the request back."""
        ...

    def release_dwell(self) -> None:
        """The frames are taken (never raises)."""
        ...


@dataclass
class DwellMeasurement:
    """The followed run's measurements at the program's dwells (module docstring); owned by
    the run's steps (one step at a time), with at most one measurement in flight."""

    meter: Meter
    #: the nominal arm's tool pose (4x4) at joints q: where the meter looks for the markers
    expected_pose: Callable[[FloatArray], FloatArray]
    read_state: Callable[[], OffsetRobotState]
    cameras: int
    #: (bench) the truth's residual tool translation now (mm; drivers/sim/ur/truth.py)
    truth: Callable[[], FloatArray] | None = None
    #: the robot's dwell hold for the frames (module docstring); None: the program's dwells
    #: end on time
    hold: DwellHold | None = None
    tally: MeasuredTally = field(default_factory=MeasuredTally)
    references: dict[str, _Reference] = field(default_factory=dict)
    #: the dwell last measured or tried (at-pose register, program instance); None: moving
    _dwell: tuple[int, int] | None = None
    _pending: _Pending | None = None

    @property
    def pending(self) -> bool:
        """A measurement is in flight (started, not collected)."""
        return self._pending is not None

    def start(self, state: OffsetRobotState, record: StepRecord, flags: list[str]) -> bool:
        """Start measuring the tool if this step is the first of a dwell at a measured pose
        with the joints at rest (and no measurement is in flight); True when started (flag
        ``measuring`` on the step). Returns at once: :meth:`collect` takes the result."""
        dwell = (state.at_pose, state.program_instance) if state.at_pose else None
        if dwell is None or dwell == self._dwell:
            self._dwell = dwell  # moving, or this dwell was measured (or tried) already
            return False
        if not _still(state) or self._pending is not None:
            return False  # not at rest yet, or the last dwell's still measured: next step
        try:
            latest = self.read_state()
        except DeviceError:
            return False
        # the latest state too (the step's may be a DB write or a collected measurement old):
        # frames are grabbed right after this, as when the step measured itself
        if (latest.at_pose, latest.program_instance) != dwell or not _still(latest):
            return False
        self._dwell = dwell
        flags.append(MEASURING)
        task = asyncio.get_running_loop().create_task(
            self._measure(state, dwell), name=f"followed-measurement-{record.step}"
        )
        self._pending = _Pending(record, task)
        return True

    async def collect(
        self, write: RowWriter, *, wait_s: float | None = None
    ) -> ToolMeasurement | None:
        """The measurement in flight, when it is in: its outcome into the measuring step's
        row (rewritten through ``write``) and the tally; the measurement when the row took
        it, else None. ``wait_s``: wait that long for it (the run's hold or end), then give it
        up (flag camera-error on its step); None: only take it if it is in already."""
        pending = self._pending
        if pending is None:
            return None
        task = pending.task
        if not task.done():
            if wait_s is None:
                return None
            await asyncio.wait({task}, timeout=wait_s)
        self._pending = None
        if task.done():
            outcome = task.result()  # a bug in the meter raises here, in a step
        else:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
            outcome = _Discarded("camera-error", f"tool cameras: no measurement in {wait_s} s")
        record = dataclasses.replace(pending.record)
        flags = [f for f in record.flags.split(",") if f and f != MEASURING]
        errors = [record.error] if record.error else []
        measurement = None
        if isinstance(outcome, _Taken):
            flags = [f for f in flags if f not in UNMEASURED_FLAGS]
            for name in MEASURED_COLUMNS:
                setattr(record, name, None)
            self._record(outcome, record=record, flags=flags)
            measurement = outcome.measurement
        else:
            self._discard(outcome.flag, outcome.message, flags, errors)
        record.flags = ",".join(flags)
        record.error = "; ".join(errors)
        await write(record)
        return measurement

    async def _measure(
        self, state: OffsetRobotState, dwell: tuple[int, int]
    ) -> _Taken | _Discarded:
        """The dwell held, the frames, the fit and the check that the program stayed in its
        dwell (a task of its own: module docstring). Camera and marker failures are outcomes,
        never raised."""
        hold = self.hold
        if hold is None:
            return await self._frames(state, dwell)
        pose_name = str(state.at_pose)
        try:
            try:
                held = await hold.hold_dwell(state.at_pose)
            except DeviceError as err:
                return _Discarded(MOVED, f"the dwell at pose {pose_name} was not held: {err}")
            if (held.at_pose, held.program_instance) != dwell or not _still(held):
                return _Discarded(
                    MOVED,
                    f"the program left pose {pose_name} before it held the dwell for the frames "
                    f"(at pose {held.at_pose}): no frames taken",
                )
            return await self._frames(state, dwell)
        finally:
            hold.release_dwell()

    async def _frames(self, state: OffsetRobotState, dwell: tuple[int, int]) -> _Taken | _Discarded:
        """The frames and the fit, then the state after them: the program still at the dwell,
        or the measurement is thrown away."""
        pose_name = str(state.at_pose)
        try:
            measurement = await self.meter.measure(
                self.expected_pose(np.asarray(state.joints_rad, dtype=np.float64))
            )
        except DeviceError as err:
            return _Discarded("camera-error", f"tool cameras: {err}")
        except MeasurementError as err:
            return _Discarded("marker-error", f"tool markers: {err}")
        truth = None if self.truth is None else self.truth()
        try:
            after = self.read_state()
        except DeviceError as err:
            return _Discarded(MOVED, f"no robot state after the frames: {err}")
        if (after.at_pose, after.program_instance) != dwell or not _still(after):
            return _Discarded(
                MOVED,
                f"the program left pose {pose_name} during the frames (at pose {after.at_pose}"
                "): measurement discarded",
            )
        return _Taken(pose_name, measurement, after, truth)

    def _discard(self, flag: str, message: str, flags: list[str], errors: list[str]) -> None:
        """The measurement thrown away, flagged (nothing of it recorded)."""
        flags.append(flag)
        errors.append(message)
        self.tally.discarded[flag] = self.tally.discarded.get(flag, 0) + 1

    def _record(self, taken: _Taken, *, record: StepRecord, flags: list[str]) -> None:
        pose_name, measurement, after, truth = (
            taken.pose_name,
            taken.measurement,
            taken.after,
            taken.truth,
        )
        applied = np.asarray(after.applied_offset_mm, dtype=np.float64)
        reference = self.references.get(pose_name)
        if reference is None:
            reference = _Reference(measurement.pose, measurement.sigma_mm, applied, truth)
            self.references[pose_name] = reference
            flags.append(REFERENCE_MISSING)
        zero = reference.pose is measurement.pose  # this measurement is the pose's zero
        drift = pose_difference(reference.pose, measurement.pose)
        sigma_mm = 0.0 if zero else math.hypot(measurement.sigma_mm, reference.sigma_mm)
        record.measured_tx_um, record.measured_ty_um, record.measured_tz_um = translation_um(drift)
        record.drift_3d_um = norm_um(drift)
        record.measured_sigma_um = sigma_mm * UM_PER_MM
        if measurement.oriented:
            record.measured_rx_urad, record.measured_ry_urad, record.measured_rz_urad = (
                rotation_urad(drift)
            )
            record.rotation_error_urad = angle_urad(drift)
        if zero:
            return  # no residual measured yet
        tally = self.tally
        residual_mm = np.asarray(drift.translation_mm, dtype=np.float64)
        uncompensated_mm = residual_mm - (applied - reference.applied_mm)
        residual_um = float(np.linalg.norm(residual_mm)) * UM_PER_MM
        tally.measurements += 1
        tally.poses[pose_name] = tally.poses.get(pose_name, 0) + 1
        tally.residual_um2 += residual_um**2
        tally.uncompensated_um2 += (float(np.linalg.norm(uncompensated_mm)) * UM_PER_MM) ** 2
        tally.worst_residual_um = max(tally.worst_residual_um, residual_um)
        tally.sigma_um_sum += sigma_mm * UM_PER_MM
        if truth is not None and reference.truth_mm is not None:
            difference_um = float(
                np.linalg.norm(residual_mm - (truth - reference.truth_mm)) * UM_PER_MM
            )
            tally.truth_difference_um.append(difference_um)
            tally.truth_difference_sigmas.append(difference_um / max(sigma_mm * UM_PER_MM, 1e-9))


def _still(state: OffsetRobotState) -> bool:
    return max((abs(v) for v in state.joint_speeds_rad_s), default=0.0) < STILL_RAD_S
