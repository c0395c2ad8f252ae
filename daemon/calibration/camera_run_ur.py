"""The robot side of ``thermocomp calibrate cameras --robot`` on a Universal Robots arm (issue 31):
the pattern rides on the robot's own program.

The PC does not move a UR: the robot plays its taught program and the PC only shifts its path
through the offset program (controller/ur/thermocomp_offset.script: at most MAX_OFFSET_M, 2 mm,
and MAX_ROTATION_RAD, changing by at most 1 mm/s and 1 mrad/s, frozen by the hold flag and by
its watchdog). So the A465's pattern of absolute moves (daemon/calibration/camera_run.py) becomes
a pattern of *offsets*, and its poses are visited where the program itself stands still: at its
measured poses, whose dwells the program announces in its at-pose register (the followed run's
rule, daemon/run/followed/measure.py). Every station (``--station``, default every measured
pose of arm.duty_cycle) gets the whole pattern, its offsets in order, and one loop over the
state packages does it:

1. the PC writes the offset it needs next as the correction (drivers/ur/robot.py
   ``set_correction``: refused before any byte beyond robot.correction_limit_*, or after a
   hold): while the program dwells at a station, that station's next offset; while it moves,
   the next offset of the station it comes to next (cycle order), so that the program walks
   its applied offset there at its rate limit on the way and the dwell is spent on frames;
2. the pose of the pattern is confirmed when a state package shows the dwell (at-pose
   register k of that station, the program's instance unchanged) with the joints at rest, the
   applied offset (the program's output registers) equal to the written one, and the actual
   TCP pose (RTDE ``actual_TCP_pose``: the controller's kinematics at the encoders' joints)
   steady to STEADY_MM since the package before;
3. the program is asked to hold its dwell for the frames (``hold_dwell``: the frames register
   and the program's ``tc_wait_for_frames``, controller/ur/README.md; the followed run's rule,
   so a loaded PC still takes its frames inside the dwell) and the read-back must still show
   the dwell; every camera grabs a frame; a state package after the frames must show the same
   dwell, the same applied offset and the same TCP pose, else the frames are thrown away and
   the pose is tried again (counted: ``retried``); then the program is let go;
4. each marker found is one observation row at its nominal position ``R m + p``, (R, p) the
   actual TCP pose: the cameras are calibrated in the controller's frame, the frame every
   correction is written in, exactly as the A465's from its ``w2`` read-back. That frame
   differs from the true one by the arm's kinematic error *at the station*, so each camera is
   fitted from its own station's rows only (:func:`own_station_rows`).

The TCP pose also checks the program: at one measured pose, the TCP's translation less the
applied offset (the program's path there) must stay within PATH_TOLERANCE_MM over the pattern,
else the tool is not where the program's offset puts it and the calibration stops.

At the end, whatever happened, the correction goes back to the one the program applied at the
start, as far as the driver lets it: after a hold it refuses every correction before its bytes
are written (the program's offset stays frozen where the hold found it), so the return is
refused too and the error says so.

How many offsets fit in one dwell is the program's business: one step of the pattern takes its
length over the rate limit (0.5 mm: 0.5 s) plus the frames; a production program's short dwell
takes one offset (the program walks to the next one while it plays the rest of its cycle), a
calibration program that dwells longer takes several.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from daemon.arm.duty import DutyCycle
from daemon.arm.types import FloatArray
from daemon.calibration.camera_observations import Observation
from daemon.calibration.camera_pattern import Shift
from daemon.calibration.camera_run import (
    SEARCH_HALF_PX,
    Recording,
    add_rows,
    find_markers,
    grab,
)
from daemon.run.arm.measure import SensorNoise
from daemon.run.followed.measure import STILL_RAD_S
from daemon.vision.multiview import CameraModel
from drivers.base import Camera, OffsetRobot, OffsetRobotState, Vector3
from drivers.errors import DeviceError, MotionHeldError

logger = logging.getLogger(__name__)

#: The applied offset (the program's output registers) within this of the written one: the
#: program reaches a target exactly (its last rate-limited step lands on it), so the tolerance
#: only covers the registers' doubles (mm; rad).
APPLIED_TOLERANCE_MM = 1e-4
APPLIED_TOLERANCE_RAD = 1e-7
#: The actual TCP pose of two successive state packages (8 ms apart at 125 Hz) within this (mm):
#: at rest, the offset reached. The program moves its offset by 2 um a cycle at its rate limit,
#: so a pose still being shifted differs by more.
STEADY_MM = 5e-4
#: At one measured pose, the TCP's translation less the applied offset (the program's own path)
#: may differ from its first value over the pattern by this much (mm): a 2 mm offset turned into
#: joints through the Jacobian is exact to its second order (~1 um); more means the program did
#: not shift the tool by the offset it reports.
PATH_TOLERANCE_MM = 0.02
#: How long the return to the starting correction may take (s): 2 mm at the 1 mm/s rate limit,
#: with a margin.
RETURN_WAIT_S = 5.0


class CalibrationStopped(DeviceError):
    """The pattern cannot go on (the program never dwells, or does not apply the offset)."""

    def __init__(self, message: str) -> None:
        super().__init__("robot", message)


class DwellRobot(OffsetRobot, Protocol):
    """What the pattern needs of a UR (drivers/ur/robot.py URRobot): its state read back, and
    the program's dwell held while the cameras take their frames."""

    async def read_state(self) -> OffsetRobotState: ...

    async def hold_dwell(self, pose: int) -> OffsetRobotState: ...

    def release_dwell(self) -> None: ...


@dataclass(frozen=True, slots=True)
class Station:
    """A measured pose of the program (arm.duty_cycle): its name, the at-pose register's
    values that mean it (the 1-based index of every visit of the pose in the cycle: a
    calibration program may visit a station several times), its index among the cycle's
    measured poses (the bench stands its cameras by that order) and its taught joints."""

    name: str
    at_poses: frozenset[int]
    index: int
    q_rad: tuple[float, ...]

    @property
    def label(self) -> str:
        return f"measured pose {self.name!r} (at-pose {', '.join(map(str, sorted(self.at_poses)))})"


def _applied(state: OffsetRobotState) -> tuple[FloatArray, FloatArray]:
    return (
        np.asarray(state.applied_offset_mm, dtype=np.float64),
        np.asarray(state.applied_rotation_rad, dtype=np.float64),
    )


def reached(state: OffsetRobotState, shift: Shift) -> bool:
    """The program applies the pattern's offset ``shift`` now."""
    offset, rotation = _applied(state)
    return bool(
        np.max(np.abs(offset - np.asarray(shift.translation_mm))) <= APPLIED_TOLERANCE_MM
        and np.max(np.abs(rotation - np.asarray(shift.rotation_rad))) <= APPLIED_TOLERANCE_RAD
    )


def still(state: OffsetRobotState) -> bool:
    return max((abs(v) for v in state.joint_speeds_rad_s), default=0.0) < STILL_RAD_S


def steady(before: OffsetRobotState, after: OffsetRobotState) -> bool:
    """The TCP did not move between the two packages (translation, and rotation at the
    markers' lever arm of ~100 mm: 5 urad)."""
    a, b = np.asarray(before.tcp_pose), np.asarray(after.tcp_pose)
    turn = Rotation.from_rotvec(b[3:]) * Rotation.from_rotvec(a[3:]).inv()
    return bool(
        np.max(np.abs(b[:3] - a[:3])) <= STEADY_MM and turn.magnitude() <= STEADY_MM / 100.0
    )


def tool_matrix(state: OffsetRobotState) -> FloatArray:
    """The actual TCP pose (mm, rotation vector) as a 4x4 transform, base frame."""
    pose = np.asarray(state.tcp_pose, dtype=np.float64)
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_rotvec(pose[3:]).as_matrix()
    matrix[:3, 3] = pose[:3]
    return matrix


@dataclass
class URRecording(Recording):
    """A Recording (camera_run.py) with what only the UR's pattern has: the frames thrown away
    because the program left its dwell (or moved) during them, the correction the program
    applied at the start."""

    retried: int = 0
    start_offset_mm: Vector3 = (0.0, 0.0, 0.0)
    start_rotation_rad: Vector3 = (0.0, 0.0, 0.0)
    #: the station of each row (same order as ``rows``)
    row_stations: list[str] = field(default_factory=list)


def _stopped(
    robot: DwellRobot, state: OffsetRobotState, instance: int, waited_s: float, wait_s: float
) -> None:
    """Why the pattern cannot go on at this package, raised: a hold (MotionHeldError), the
    program restarted, or no pose recorded for ``wait_s`` (CalibrationStopped)."""
    if robot.permit.held:
        raise MotionHeldError(
            "robot", f"held during the pattern ({robot.permit.reason}): nothing moves"
        )
    if state.program_instance != instance:
        raise CalibrationStopped(
            "the offset program restarted during the pattern (its instance changed): start "
            "the calibration again"
        )
    if waited_s > wait_s:
        offset, _ = _applied(state)
        raise CalibrationStopped(
            f"the robot was not at a measured pose with the pattern's offset applied within "
            f"{wait_s:g} s: at-pose register {state.at_pose}, runtime state "
            f"{state.runtime_state}, applied offset ({', '.join(f'{v:.4f}' for v in offset)}) "
            "mm: is the program playing, does it set tc_at_pose at its measured poses "
            "(controller/ur/README.md)?"
        )


class _Plan:
    """Which offset each station needs next, and which to write now (module docstring): at a
    station's dwell its next offset, elsewhere the next offset of the station the program
    comes to next (its measured poses in the cycle's order), so that the program walks there
    while it plays the rest of its cycle and the dwell is spent on frames."""

    def __init__(self, stations: Sequence[Station], count: int) -> None:
        self.stations = sorted(stations, key=lambda s: min(s.at_poses))
        self.count = count
        self.done = {s.name: 0 for s in stations}
        self.last: Station | None = None

    def finished(self) -> bool:
        return all(n >= self.count for n in self.done.values())

    def at(self, at_pose: int) -> Station | None:
        """The station of this at-pose value, if it still needs an offset."""
        for station in self.stations:
            if at_pose in station.at_poses and self.done[station.name] < self.count:
                return station
        return None

    def coming(self) -> Station:
        """The next station in the cycle after the last one recorded that needs an offset."""
        start = 0 if self.last is None else self.stations.index(self.last) + 1
        ring = self.stations[start:] + self.stations[:start]
        return next(s for s in ring if self.done[s.name] < self.count)


async def record_ur_pattern(
    robot: DwellRobot,
    cameras: Sequence[Camera],
    models: Sequence[CameraModel],
    markers_tool_mm: FloatArray,
    shifts: Sequence[Shift],
    *,
    stations: Sequence[Station],
    wait_s: float,
    grab_timeout_s: float,
    search_half_px: int = SEARCH_HALF_PX,
    recording: URRecording | None = None,
    sensors: Sequence[SensorNoise] | None = None,
) -> URRecording:
    """Write the (checked) pattern's offsets and record each at every station's dwell (module
    docstring); back to the starting correction at the end whatever happened. ``wait_s``: how
    long the pattern may go without recording a pose (a few of the program's cycles).
    ``recording`` (filled as it goes) lets a caller see what was done when an error ends the
    pattern."""
    if len(cameras) != len(models):
        raise ValueError(f"{len(cameras)} cameras but {len(models)} camera models")
    record = recording if recording is not None else URRecording("")
    record.goal = ", ".join(s.name for s in stations)
    for model in models:
        record.seen_poses.setdefault(model.name, 0)
        record.missed.setdefault(model.name, 0)
    start = await robot.follow_program()  # a restart of the program from here holds
    offset, rotation = _applied(start)
    record.start_offset_mm = (float(offset[0]), float(offset[1]), float(offset[2]))
    record.start_rotation_rad = (float(rotation[0]), float(rotation[1]), float(rotation[2]))
    plan = _Plan(stations, len(shifts))
    paths: dict[str, FloatArray] = {}
    loop = asyncio.get_running_loop()
    progress_s = loop.time()
    written: Shift | None = None
    before: OffsetRobotState | None = None
    try:
        while not plan.finished():
            state = await robot.read_state()
            _stopped(robot, state, start.program_instance, loop.time() - progress_s, wait_s)
            here = plan.at(state.at_pose)
            shift = shifts[plan.done[(here or plan.coming()).name]]
            if shift != written:
                await robot.set_correction(shift.translation_mm, shift.rotation_rad)
                written, before = shift, None
                record.moves += 1
                continue
            confirmed = (
                here is not None
                and still(state)
                and reached(state, shift)
                and before is not None
                and before.at_pose == state.at_pose
                and steady(before, state)
            )
            before = state
            if here is None or not confirmed:
                continue
            try:
                held = await robot.hold_dwell(state.at_pose)
                if (held.at_pose, held.program_instance) == (
                    state.at_pose,
                    state.program_instance,
                ) and still(held):
                    frames = await asyncio.gather(
                        *(grab(camera, grab_timeout_s) for camera in cameras)
                    )
                    after: OffsetRobotState | None = await robot.read_state()
                else:
                    after = None  # the dwell ended before the hold: no frames
            finally:
                robot.release_dwell()
            if after is None or not (
                after.at_pose == state.at_pose
                and after.program_instance == state.program_instance
                and still(after)
                and reached(after, shift)
                and steady(state, after)
            ):
                record.retried += 1  # the dwell ended (or the tool moved) during the frames
                before = None
                continue
            _check_path(paths, here, state)
            tool = tool_matrix(state)
            world = markers_tool_mm @ tool[:3, :3].T + tool[:3, 3]
            found = await asyncio.to_thread(
                find_markers, models, frames, world, search_half_px=search_half_px, sensors=sensors
            )
            add_rows(record, models, found, world, tool)
            record.row_stations.extend([here.name] * (len(record.rows) - len(record.row_stations)))
            record.poses += 1
            plan.done[here.name] += 1
            plan.last = here
            progress_s = loop.time()
    finally:
        try:
            await robot.set_correction(record.start_offset_mm, record.start_rotation_rad)
            await _returned(robot, record)
            record.returned = True
        except DeviceError as err:
            # after a hold the driver refuses this too (nothing is written): say so, and let
            # the error that ended the pattern (if any) be the one reported
            logger.error("the correction could not return to where it started: %s", err)
    return record


def _check_path(paths: dict[str, FloatArray], station: Station, state: OffsetRobotState) -> None:
    """The program's path at the station (TCP less the applied offset) unchanged over the
    pattern (module docstring); CalibrationStopped when the tool is elsewhere."""
    offset, _ = _applied(state)
    path = np.asarray(state.tcp_pose[:3], dtype=np.float64) - offset
    first = paths.setdefault(station.name, path)
    moved = float(np.linalg.norm(path - first))
    if moved > PATH_TOLERANCE_MM:
        raise CalibrationStopped(
            f"at {station.label} the TCP less the applied offset moved by {moved:.4f} mm "
            f"over the pattern (more than {PATH_TOLERANCE_MM} mm): the program does not shift "
            "the tool by the offset it reports, or its measured pose changed"
        )


async def _returned(robot: DwellRobot, record: URRecording) -> None:
    """Wait until the program applies the starting correction again (RETURN_WAIT_S)."""
    back = Shift(record.start_offset_mm, record.start_rotation_rad)
    loop = asyncio.get_running_loop()
    deadline_s = loop.time() + RETURN_WAIT_S
    while not reached(await robot.read_state(), back):
        if robot.permit.held:
            raise MotionHeldError("robot", "held before the correction was back")
        if loop.time() > deadline_s:
            raise CalibrationStopped(
                f"the program did not apply the starting correction within {RETURN_WAIT_S} s"
            )


def own_station_rows(record: URRecording) -> tuple[list[Observation], dict[str, str]]:
    """Each camera's rows from the one station where it saw the most markers, and by camera
    name a note on the rows left out. The cameras are calibrated in the controller's frame,
    which differs from the true one by the arm's kinematic error *at the station* (camera_run.
    controller_frame_truth): hundreds of um, and not the same at two stations, so a camera
    that sees the tool at two stations (one at the edge of its view) would be fitted to two
    frames at once (on the UR bench: 0.18 mm off, reduced chi2 2.6, against 0.02 mm)."""
    counts: dict[str, dict[str, int]] = {}
    for row, station in zip(record.rows, record.row_stations, strict=True):
        mine = counts.setdefault(row.camera, {})
        mine[station] = mine.get(station, 0) + 1
    own = {camera: max(seen, key=lambda k: seen[k]) for camera, seen in counts.items()}
    notes = {
        camera: (
            f"fitted from its {seen[own[camera]]} marker views at {own[camera]!r}, not its "
            + ", ".join(f"{n} at {k!r}" for k, n in seen.items() if k != own[camera])
        )
        for camera, seen in counts.items()
        if len(seen) > 1
    }
    rows = [
        row
        for row, station in zip(record.rows, record.row_stations, strict=True)
        if own[row.camera] == station
    ]
    return rows, notes


def stations_of(duty: DutyCycle, station: str | None) -> list[Station]:
    """The stations the pattern is recorded at: every measured pose of the program (arm.
    duty_cycle), or the one named ``station``; ValueError naming them when it is not one."""
    measured = duty.measured_poses()
    stations = [
        Station(
            pose.name,
            frozenset(k + 1 for k, p in enumerate(duty.poses) if p.measure and p.name == pose.name),
            index,
            tuple(float(v) for v in pose.q_rad),
        )
        for index, pose in enumerate(measured)
    ]
    if not stations:
        raise ValueError(f"the program {duty.name} has no measured pose: nothing to calibrate at")
    if station is None:
        return stations
    chosen = [s for s in stations if s.name == station]
    if not chosen:
        raise ValueError(
            f"--station {station!r}: not a measured pose of the program {duty.name} "
            f"({', '.join(s.name for s in stations)})"
        )
    return chosen


__all__ = [
    "APPLIED_TOLERANCE_MM",
    "CalibrationStopped",
    "DwellRobot",
    "Station",
    "URRecording",
    "record_ur_pattern",
    "stations_of",
]
