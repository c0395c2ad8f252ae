"""The robot side of ``thermocomp calibrate cameras --robot`` (issue 20): the arm moves the tool
through a pattern of poses around a taught goal, every camera grabs a frame at each, each
marker's centroid is found near where the initial guess of the camera puts it, and the rows are
the observations the fits of :mod:`daemon.commands.calibrate_cameras` take (the columns of
``moves.csv``).

Modelled on ``thermocomp calibrate camera`` (daemon/commands/calibrate.py): the pattern is declared
whole and checked against the limits before anything moves (``PatternError``: nothing moves);
a move whose change from the previous one exceeds the arm's step limits is split along the
straight line (which stays inside the pattern's convex hull, hence inside its limits); the robot
returns to the goal whatever happened, as far as the driver lets it: after a hold the driver
refuses every motion right before its bytes are written (drivers/c500c/robot.py), so the return is
refused too and the error says so.

Where the tool is: the controller's read-back after each move (`w2`: the pose its kinematics
compute from the joints' encoders). The cameras are calibrated in that frame, the controller's
world, which is the frame every later correction is commanded in: an error of the arm's
kinematics at the goal (a constant over a pattern of a few millimetres) becomes part of the
cameras' poses and cancels in the arm run's measurements.

Markers: each marker (arm.markers_mm, tool frame) seen at a pose is one observation row with
``x, y, z`` its nominal world position ``R m_k + p`` and the tool's rotation vector ``R``; the
fitted "marker offset" (``--fit-marker``) is then a common shift of every marker in the tool
frame (the tool point's error), 0 when the markers are where arm.markers_mm says.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np
from scipy.spatial.transform import Rotation

from config import Settings
from daemon.arm.duty import load_duty_cycle
from daemon.arm.kinematics import forward
from daemon.arm.loading import load_arm
from daemon.arm.run import MeasuredPose
from daemon.arm.types import FloatArray
from daemon.calibration.camera_observations import Observation
from daemon.calibration.camera_pattern import ZERO_SHIFT, PatternError, Shift, split_shift
from daemon.run.arm.measure import WINDOW_HALF_PX, SensorNoise, device_sensors
from daemon.run.arm.robot import GoalRobotArm, pose_matrix
from daemon.vision import CentroidError
from daemon.vision.centroid import measure_centroid
from daemon.vision.markers import marker_pixels
from daemon.vision.multiview import CameraModel, project
from drivers.base import Camera, Frame, GoalRobot
from drivers.clock import make_clock
from drivers.deadline import bounded
from drivers.errors import DeviceError
from drivers.factory import open_devices

logger = logging.getLogger(__name__)

#: Half-width (px) of the window a marker is first searched in around where the initial guess
#: of the camera puts it: a guess a few mm and mrad off (3 mm at 700 mm and f = 4,640 px is
#: 20 px) is still inside, and the arm bench's markers (120 mm apart, ~800 px) stay apart.
SEARCH_HALF_PX = 96
#: The centroid is then measured again in arm_measure's window centred on the spot found, so
#: that the robust centroid's background sees the spot's surroundings on every side.
MEASURE_HALF_PX = WINDOW_HALF_PX
#: The goal the pattern is relative to with ``--here`` (where the robot stands): the default
#: goal, as `calibrate camera` teaches it.
HERE_GOAL = "opgoal"


@dataclass(frozen=True, slots=True)
class MarkerFind:
    """One marker's centroid in one camera's frame (frame pixels) and its 1-sigma per axis."""

    camera: int
    marker: int
    x_px: float
    y_px: float
    sigma_px: tuple[float, float]


def _window(image: np.ndarray, x: float, y: float, half: int) -> tuple[np.ndarray, int, int] | None:
    height, width = image.shape[:2]
    c0, r0 = max(0, int(x) - half), max(0, int(y) - half)
    c1, r1 = min(width, int(x) + half + 1), min(height, int(y) + half + 1)
    if c1 - c0 < half or r1 - r0 < half:
        return None  # (mostly) off the chip
    return image[r0:r1, c0:c1], c0, r0


def _measure_marker(
    image: np.ndarray,
    x: float,
    y: float,
    *,
    bit_depth: int,
    search_half_px: int,
    noise: SensorNoise,
) -> tuple[float, float, float, float] | None:
    """The spot near (x, y): searched in the wide window, measured again in the window centred
    on it; (x, y, sigma_x, sigma_y) in frame pixels, or None (off the chip, not found, cut)."""
    if not (math.isfinite(x) and math.isfinite(y)):
        return None
    result = None
    for half in (search_half_px, MEASURE_HALF_PX):
        window = _window(image, x, y, half)
        if window is None:
            return None
        part, c0, r0 = window
        try:
            result = measure_centroid(
                part,
                bit_depth=bit_depth,
                gain_e_per_count=noise.gain_e_per_count,
                read_noise_e=noise.read_noise_e,
            )
        except CentroidError:
            return None
        x, y = result.x_px + c0, result.y_px + r0
    if result is None or "edge" in result.flags:
        return None
    return x, y, result.sigma_x_px, result.sigma_y_px


def find_markers(
    models: Sequence[CameraModel],
    frames: Sequence[Frame],
    markers_world: FloatArray,
    *,
    search_half_px: int = SEARCH_HALF_PX,
    sensors: Sequence[SensorNoise] | None = None,
) -> list[MarkerFind]:
    """Every marker found in every frame (blocking: call it off the loop): the robust centroid
    in a ``search_half_px`` window around where the camera's model puts it, then again in the
    measuring window centred on that; a marker off the chip, not found, or cut by the window's
    edge is left out. The 1-sigma is the centroid's own, at least the camera's
    ``pixel_sigma_px`` (as daemon/run/arm/measure.py marker_views), from each camera's sensor
    noise (``sensors``, same order; default: the centroid's defaults)."""
    found: list[MarkerFind] = []
    noises = tuple(sensors) if sensors is not None else (SensorNoise(),) * len(models)
    for index, (model, frame, noise) in enumerate(zip(models, frames, noises, strict=True)):
        image = np.asarray(frame.image)
        for marker, (x, y) in enumerate(project(model, markers_world)):
            spot = _measure_marker(
                image,
                float(x),
                float(y),
                bit_depth=frame.bit_depth,
                search_half_px=search_half_px,
                noise=noise,
            )
            if spot is None:
                continue
            floor = model.pixel_sigma_px
            sigma = (max(spot[2], floor), max(spot[3], floor))
            found.append(MarkerFind(index, marker, spot[0], spot[1], sigma))
    return found


@dataclass
class Recording:
    """What the pattern gave: the observation rows, the goal, how many poses were visited (and
    moves made), whether the robot is back at the goal, and per camera the poses at which it
    saw at least one marker and the markers it did not find where its guess put them on its
    chip."""

    goal: str
    rows: list[Observation] = field(default_factory=list)
    poses: int = 0
    moves: int = 0
    seen_poses: dict[str, int] = field(default_factory=dict)
    missed: dict[str, int] = field(default_factory=dict)
    returned: bool = False


async def grab(camera: Camera, timeout_s: float) -> Frame:
    """One frame within ``timeout_s`` (a DeviceTimeoutError beyond, as arm_measure's; the
    bench's render does not count: drivers/deadline.py)."""
    return await bounded(camera.grab(), "camera", "frame", timeout_s)


async def record_pattern(
    robot: GoalRobot,
    cameras: Sequence[Camera],
    models: Sequence[CameraModel],
    markers_tool_mm: FloatArray,
    shifts: Sequence[Shift],
    *,
    goal: str,
    max_step_mm: float,
    max_step_rad: float,
    grab_timeout_s: float,
    search_half_px: int = SEARCH_HALF_PX,
    recording: Recording | None = None,
    sensors: Sequence[SensorNoise] | None = None,
) -> Recording:
    """Visit every shift of the (checked) pattern from the taught ``goal``, grab a frame from
    every camera at each and find the markers; back to the goal at the end whatever happened
    (module docstring). ``recording`` (filled as it goes) lets a caller see what was done when
    a device error ends the pattern."""
    if len(cameras) != len(models):
        raise ValueError(f"{len(cameras)} cameras but {len(models)} camera models")
    record = recording if recording is not None else Recording(goal)
    record.goal = goal
    for model in models:
        record.seen_poses.setdefault(model.name, 0)
        record.missed.setdefault(model.name, 0)
    where = ZERO_SHIFT

    async def go(target: Shift) -> None:
        nonlocal where
        for step in split_shift(where, target, max_step_mm, max_step_rad):
            await robot.move_absolute(step.translation_mm, step.rotation_rad, goal=goal)
            where = step
            record.moves += 1

    try:
        for shift in shifts:
            await go(shift)
            tool = pose_matrix(await robot.actual_pose())
            frames = await asyncio.gather(*(grab(camera, grab_timeout_s) for camera in cameras))
            world = markers_tool_mm @ tool[:3, :3].T + tool[:3, 3]
            found = await asyncio.to_thread(
                find_markers, models, frames, world, search_half_px=search_half_px, sensors=sensors
            )
            add_rows(record, models, found, world, tool)
            record.poses += 1
    finally:
        try:
            await go(ZERO_SHIFT)
            record.returned = True
        except DeviceError as err:
            # after a hold the driver refuses this too (nothing is written): say so, and let
            # the error that ended the pattern (if any) be the one reported
            logger.error("could not return to the goal %r: %s", goal, err)
    return record


def add_rows(
    record: Recording,
    models: Sequence[CameraModel],
    found: Sequence[MarkerFind],
    world: FloatArray,
    tool: FloatArray,
) -> None:
    rotation = Rotation.from_matrix(tool[:3, :3]).as_rotvec()
    turn = (float(rotation[0]), float(rotation[1]), float(rotation[2]))
    for index, model in enumerate(models):
        mine = [f for f in found if f.camera == index]
        if mine:
            record.seen_poses[model.name] += 1
        expected = _visible(model, world)
        record.missed[model.name] += max(0, expected - len(mine))
        for find in mine:
            point = world[find.marker]
            record.rows.append(
                Observation(
                    model.name,
                    (float(point[0]), float(point[1]), float(point[2])),
                    (find.x_px, find.y_px),
                    find.sigma_px,
                    turn,
                )
            )


def _visible(model: CameraModel, world: FloatArray) -> int:
    """How many markers the camera's model puts on its chip, in front of it."""
    _, visible = marker_pixels(model, world)
    return int(np.count_nonzero(visible))


@dataclass(frozen=True, eq=False)
class RobotRun:
    """What ``calibrate_with_robot`` gives: the recording and, on the arm bench, the truth's
    cameras in the controller's frame at the goal (:func:`controller_frame_truth`)."""

    recording: Recording
    reference: tuple[CameraModel, ...] | None
    kinematic_error: tuple[float, float] | None  # the truth's tool at the goal: mm, mrad


def station_pose(settings: Settings, name: str) -> tuple[str, FloatArray, FloatArray]:
    """A pose of arm.duty_cycle by name: (name, joints rad, the controller's tool pose 4x4);
    PatternError when there is no duty cycle or no such pose."""
    if settings.arm.duty_cycle is None:
        raise PatternError("--station needs arm.duty_cycle (its poses are the stations)")
    duty = load_duty_cycle(settings.arm.duty_cycle)
    poses = {pose.name: pose for pose in duty.poses}
    if name not in poses:
        raise PatternError(
            f"--station {name!r}: not a pose of the duty cycle {duty.name} ({', '.join(poses)})"
        )
    q = np.asarray(poses[name].q_rad, dtype=np.float64)
    arm = load_arm(settings.arm.arm_file)
    return name, q, np.asarray(forward(arm, q), dtype=np.float64)


def controller_frame_truth(
    truth_cameras: Sequence[CameraModel], true_tool: FloatArray, believed_tool: FloatArray
) -> tuple[tuple[CameraModel, ...], tuple[float, float]]:
    """The arm bench's true cameras as a calibration from the controller's read-back sees them
    (module docstring): a marker the controller believes at ``X`` is truly at ``E X`` with
    ``E = T_true T_believed^-1`` at the goal, so the camera (R, t) is (R R_E, R t_E + t). Also
    the size of ``E``: its translation (mm) and angle (mrad)."""
    error = true_tool @ np.linalg.inv(believed_tool)
    r_e, t_e = error[:3, :3], error[:3, 3]
    cameras = []
    for camera in truth_cameras:
        r_c = Rotation.from_rotvec(np.array(camera.rotation_rad)).as_matrix()
        cameras.append(
            camera.with_pose(
                Rotation.from_matrix(r_c @ r_e).as_rotvec(), r_c @ t_e + camera.translation_mm
            )
        )
    angle = float(Rotation.from_matrix(r_e).magnitude())
    return tuple(cameras), (float(np.linalg.norm(t_e)), 1000.0 * angle)


#: The goal's name when it is given by ``--joints``.
JOINTS_GOAL = "camcal"


def joints_pose(
    settings: Settings, joints_deg: Sequence[float]
) -> tuple[str, FloatArray, FloatArray]:
    """A goal given by the arm's joint angles (deg): (JOINTS_GOAL, joints rad, the controller's
    tool pose 4x4); PatternError when the count or a joint's limits do not fit the arm."""
    arm = load_arm(settings.arm.arm_file)
    q = np.radians(np.asarray(joints_deg, dtype=np.float64))
    if q.size != arm.dof:
        raise PatternError(f"--joints: {q.size} angles for the {arm.dof} joints of {arm.name}")
    outside = np.flatnonzero((q < arm.lower_rad) | (q > arm.upper_rad))
    if outside.size:
        k = int(outside[0])
        raise PatternError(
            f"--joints: joint {k + 1} at {math.degrees(q[k]):g} deg is beyond its limits "
            f"[{math.degrees(arm.lower_rad[k]):g}, {math.degrees(arm.upper_rad[k]):g}] deg"
        )
    return JOINTS_GOAL, q, np.asarray(forward(arm, q), dtype=np.float64)


async def calibrate_with_robot(
    settings: Settings,
    models: Sequence[CameraModel],
    shifts: Sequence[Shift],
    *,
    station: str | None,
    joints_deg: Sequence[float] | None = None,
    search_half_px: int = SEARCH_HALF_PX,
    recording: Recording | None = None,
) -> RobotRun:
    """Open the devices (drivers/factory.py), teach the goal — where the robot stands, or the
    duty cycle's pose ``station`` or the joint angles ``joints_deg``, reached by one absolute
    move as an arm run teaches its poses (daemon/run/arm/robot.py) — record the pattern around it
    and close the devices."""
    target = station_pose(settings, station) if station is not None else None
    if joints_deg is not None:
        target = joints_pose(settings, joints_deg)
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    async with open_devices(settings, clock) as devices:
        robot = devices.robot
        if not callable(getattr(robot, "taught_goals", None)):
            raise PatternError(
                f"the robot driver {type(robot).__name__} has no named goals and rotated moves"
            )
        cameras = devices.cameras
        if len(cameras) != len(models):
            raise PatternError(
                f"{len(cameras)} cameras watch the tool but the camera file has {len(models)}: "
                "one camera per device, in the same order"
            )
        goal_robot = cast(GoalRobot, robot)  # checked just above (a Protocol)
        if target is None:
            goal = HERE_GOAL
            await goal_robot.teach_goal(goal)
        else:
            goal = target[0]
            await GoalRobotArm(goal_robot).teach_pose(MeasuredPose(*target))
        arm = settings.arm
        sensors, timeouts_s = device_sensors(settings, len(models))
        record = await record_pattern(
            goal_robot,
            cameras,
            models,
            np.array(arm.markers_mm, dtype=np.float64),
            shifts,
            goal=goal,
            max_step_mm=arm.max_step_translation_mm,
            max_step_rad=math.radians(arm.max_step_rotation_deg),
            grab_timeout_s=max(timeouts_s),
            search_half_px=search_half_px,
            recording=recording,
            sensors=sensors,
        )
        reference = kinematic = None
        bench = devices.arm_bench
        if bench is not None and record.returned:
            truth = bench.truth
            q = bench.joints()  # at the goal again
            reference, kinematic = controller_frame_truth(
                devices.camera_models,
                truth.tool_pose_true(q),
                np.asarray(forward(truth.nominal_arm, q), dtype=np.float64),
            )
    return RobotRun(record, reference, kinematic)
