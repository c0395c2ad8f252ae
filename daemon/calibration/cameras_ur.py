"""``thermocomp calibrate cameras --robot`` on a Universal Robots arm (robot.driver ``ur-rtde``,
issue 31): the checks before anything opens, the pattern of offsets at the program's dwells
(:mod:`daemon.calibration.camera_run_ur`), the same fits and camera file as the A465's
(:mod:`daemon.calibration.cameras_robot`).

Why this way. The PC cannot move a UR to a goal: the robot plays its own program, and the PC
shifts it through the offset program by at most robot.correction_limit_mm (the program's own
MAX_OFFSET_M, 2 mm, beyond) at 1 mm/s. That is enough: the A465's pattern is ±1 mm too, since
what fixes a camera's pose is the markers' spread on the tool (arm.markers_mm: four markers
120 mm apart at ~700 mm, a perspective-n-point problem at every pose); the pattern's
millimetres add views and average the centroids' noise. The cameras' intrinsics come from the
camera file (a checkerboard calibration, OpenCV's): a full model (focal length, principal
point, distortion) is not fitted, because a planar-ish marker plate moved by millimetres at a
fixed orientation (the program turns the tool by at most 2 mrad) cannot separate the focal
length from the distance (benchmarks/bench_ur_cameras.py measures the conditioning). For the
same reason ``--fit-marker`` is refused: turns of a milliradian leave the markers' common offset
unobservable.

Exit statuses as the A465's: 0 at least one camera calibrated; 1 the pattern stopped (a device
error, a hold, the program not dwelling with the offset applied: saying how many poses were
done and whether the correction is back where it started), no camera fitted or a failed fit;
2 bad usage, before anything opens (no [arm], no camera file, no arm.duty_cycle, a station
that is not a measured pose, ``--here``/``--joints``/``--fit-marker``, a pattern beyond the
correction limits).
"""

from __future__ import annotations

import argparse
import asyncio
import math
from collections.abc import Sequence
from typing import cast

import numpy as np

from config import Settings, load_settings
from daemon.arm.duty import DutyCycleError, load_duty_cycle
from daemon.arm.kinematics import forward
from daemon.calibration.camera_pattern import PatternError, Shift, robot_pattern
from daemon.calibration.camera_run import RobotRun, controller_frame_truth
from daemon.calibration.camera_run_ur import (
    DwellRobot,
    Station,
    URRecording,
    own_station_rows,
    record_ur_pattern,
    stations_of,
)
from daemon.calibration.cameras_robot import fit_and_report, pattern_stopped, robot_guess, usage
from daemon.run.arm.measure import device_sensors
from daemon.vision.multiview import CameraModel
from drivers.clock import make_clock
from drivers.errors import DeviceError
from drivers.factory import Devices, open_devices

#: How long one pose of the pattern may wait for its dwell: this many of the program's cycles
#: (arm.duty_cycle's period), plus WAIT_MARGIN_S (the first offset may be a millimetre away).
WAIT_CYCLES = 3.0
WAIT_MARGIN_S = 10.0


def default_size(settings: Settings) -> float:
    """``--size`` on a UR: half robot.correction_limit_mm (a cube's corner at 0.87 of it)."""
    return 0.5 * settings.robot.correction_limit_mm


def check_ur_pattern(settings: Settings, shifts: Sequence[Shift]) -> None:
    """PatternError (one line) unless every offset of the pattern is within the correction
    limits the driver refuses beyond (robot.correction_limit_mm / _rad; the program's own are
    2 mm and 2 mrad)."""
    robot = settings.robot
    farthest = max(math.dist((0.0, 0.0, 0.0), s.translation_mm) for s in shifts)
    if farthest > robot.correction_limit_mm:
        raise PatternError(
            f"the pattern shifts the program's path by up to {farthest:.3f} mm, beyond "
            f"robot.correction_limit_mm = {robot.correction_limit_mm:g} mm: choose a smaller "
            "--size"
        )
    widest = max(math.dist((0.0, 0.0, 0.0), s.rotation_rad) for s in shifts)
    if widest > robot.correction_limit_rad:
        raise PatternError(
            f"the pattern turns the tool by up to {widest:.5f} rad, beyond "
            f"robot.correction_limit_rad = {robot.correction_limit_rad:g} rad: choose a "
            "smaller --turn"
        )


def _checked_args(args: argparse.Namespace) -> str | None:
    """The options a UR cannot honour, as the one line refusing them."""
    if args.here or args.joints is not None:
        option = "--here" if args.here else "--joints"
        return (
            f"{option}: the PC does not move a UR (robot.driver ur-rtde); the pattern is "
            "recorded at its own program's measured poses (--station NAME for one of them)"
        )
    if args.fit_marker:
        return (
            "--fit-marker: a UR's offset program turns the tool by at most 2 mrad, too little "
            "to observe the markers' offset; the cameras are fitted with arm.markers_mm as given"
        )
    return None


def run_with_ur(args: argparse.Namespace) -> int:
    settings = load_settings(args.config)
    refusal = _checked_args(args)
    if refusal is not None:
        return usage(refusal)
    guess = robot_guess(args, settings)
    if isinstance(guess, str):
        return usage(guess)
    if settings.arm.duty_cycle is None:
        return usage(
            "a UR's calibration needs arm.duty_cycle: the program's measured poses are where "
            "the pattern is recorded (its at-pose register)"
        )
    try:
        duty = load_duty_cycle(settings.arm.duty_cycle)
        stations = stations_of(duty, args.station)
        size = default_size(settings) if args.size is None else args.size
        shifts = robot_pattern(size, args.per_axis, args.turn or 0.0, args.seed)
        check_ur_pattern(settings, shifts)
    except (DutyCycleError, ValueError, PatternError) as err:
        return usage(str(err))
    models = guess.models
    recording = URRecording("")
    total = len(shifts) * len(stations)
    try:
        run = asyncio.run(
            calibrate_with_ur(
                settings,
                models,
                shifts,
                stations,
                wait_s=WAIT_CYCLES * duty.period_s + WAIT_MARGIN_S,
                search_half_px=guess.search_half_px,
                recording=recording,
            )
        )
    except PatternError as err:
        return usage(str(err))
    except DeviceError as err:
        back = "returned to" if recording.returned else "could NOT return to"
        start = ", ".join(f"{v:.4f}" for v in recording.start_offset_mm)
        where = f"the correction {back} where it started ({start}) mm"
        return pattern_stopped(err, recording.poses, total, where)
    rows, notes = own_station_rows(recording)
    return fit_and_report(
        args,
        run,
        rows,
        models=models,
        guess_path=guess.path,
        hint="are the cameras in front of the program's measured poses? is the camera "
        "file's guess near?",
        extra={
            "robot": "ur-rtde: offsets at the program's measured poses",
            "offsets": len(shifts),
            "retried_dwells": recording.retried,
            "start_offset_mm": list(recording.start_offset_mm),
            "views_left_out": notes,
        },
    )


async def calibrate_with_ur(
    settings: Settings,
    models: Sequence[CameraModel],
    shifts: Sequence[Shift],
    stations: Sequence[Station],
    *,
    wait_s: float,
    search_half_px: int,
    recording: URRecording,
) -> RobotRun:
    """Open the devices (drivers/factory.py), record the pattern at the stations, close."""
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    async with open_devices(settings, clock) as devices:
        robot = devices.robot
        if not all(
            callable(getattr(robot, name, None))
            for name in ("read_state", "hold_dwell", "release_dwell")
        ):
            raise PatternError(f"the robot driver {type(robot).__name__} follows no program")
        cameras = devices.cameras
        if len(cameras) != len(models):
            raise PatternError(
                f"{len(cameras)} cameras watch the tool but the camera file has {len(models)}: "
                "one camera per device, in the same order"
            )
        sensors, timeouts_s = device_sensors(settings, len(models))
        record = await record_ur_pattern(
            cast(DwellRobot, robot),  # checked just above (a Protocol)
            cameras,
            models,
            np.array(settings.arm.markers_mm, dtype=np.float64),
            shifts,
            stations=stations,
            wait_s=wait_s,
            grab_timeout_s=max(timeouts_s),
            search_half_px=search_half_px,
            recording=recording,
            sensors=sensors,
        )
        reference, kinematic = bench_reference(devices, stations)
    return RobotRun(record, reference, kinematic)


def bench_reference(
    devices: Devices, stations: Sequence[Station]
) -> tuple[tuple[CameraModel, ...] | None, tuple[float, float] | None]:
    """On the UR bench: its true cameras as the controller's frame sees them, each camera at
    its own station's taught joints (camera_run.controller_frame_truth), and the largest of the
    stations' kinematic errors (mm, mrad). None on hardware."""
    emulator = devices.ur_emulator
    if emulator is None or not devices.camera_models:
        return None, None
    controller = emulator.controller
    bench = controller.bench
    bench.advance_to(controller.time_s)
    truth = list(devices.camera_models)
    worst: tuple[float, float] = (0.0, 0.0)
    for station in stations:
        q = np.asarray(station.q_rad, dtype=np.float64)
        indices = list(bench.station_camera_indices(station.index))
        seen, error = controller_frame_truth(
            [truth[k] for k in indices],
            bench.tool_pose_true(q),
            np.asarray(forward(bench.nominal_arm, q), dtype=np.float64),
        )
        for k, camera in zip(indices, seen, strict=True):
            truth[k] = camera
        worst = max(worst, error)
    return tuple(truth), worst


__all__ = ["calibrate_with_ur", "check_ur_pattern", "run_with_ur"]
