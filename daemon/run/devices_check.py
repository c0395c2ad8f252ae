"""What the devices give right now (issue 18): one frame, one IR image and the robot's pose,
described and drawn, for ``thermocomp devices check`` and ``GET /devices/preview``.

Every device is asked on its own: one that fails is reported (its error, one line) while the
others are still described, so a user bringing up a lab sees everything that is wrong at once.
"""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from config import Settings
from config.settings import IrRegion
from daemon.vision import CentroidError
from daemon.vision.centroid import measure_with_camera_settings
from daemon.vision.preview import (
    RegionBox,
    camera_panel,
    encode_png,
    ir_panel,
    side_by_side,
)
from drivers.base import (
    Camera,
    DescribedRobot,
    Frame,
    IrReader,
    IrReading,
    Pose,
    Robot,
    RoomReading,
    RoomThermometer,
)
from drivers.deadline import bounded
from drivers.errors import DeviceError

#: The robot's pose is read within this time (s), like a console command.
POSE_TIMEOUT_S = 10.0


class Devices(Protocol):
    """The open devices: drivers.factory.Devices, or the daemon's ``devices``."""

    @property
    def camera(self) -> Camera: ...

    @property
    def ir(self) -> IrReader: ...

    @property
    def robot(self) -> Robot: ...


@dataclass
class DeviceCheck:
    """One grab of each device and what was found in it; ``errors`` per failed device."""

    frame: Frame | None = None
    centroid: dict[str, Any] | None = None
    centroid_error: str | None = None
    reading: IrReading | None = None
    regions: tuple[IrRegion, ...] = ()
    pose: Pose | None = None
    robot_link: str | None = None
    errors: dict[str, str] = field(default_factory=dict)
    #: the arm bench's tool cameras (issue 28): one frame each, by camera name
    tool_frames: list[tuple[str, Frame]] = field(default_factory=list)
    #: what a robot that describes itself reported (a UR: drivers/ur/describe.py)
    robot_facts: tuple[tuple[str, str], ...] = ()
    #: the room thermometer's reading (room.driver; issue 29): None when none or it failed
    room: RoomReading | None = None
    #: what was not checked and why (one line each; not a failure)
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.errors

    def as_dict(self) -> dict[str, Any]:
        frame, reading = self.frame, self.reading
        return {
            "camera": None
            if frame is None
            else {
                "width_px": int(frame.image.shape[1]),
                "height_px": int(frame.image.shape[0]),
                "dtype": str(frame.image.dtype),
                "bit_depth": frame.bit_depth,
                "min_counts": int(frame.image.min()),
                "max_counts": int(frame.image.max()),
                "timestamp_source": frame.timestamp_source,
                "spot": self.centroid,
                "spot_error": self.centroid_error,
            },
            "ir": None
            if reading is None
            else {
                "width_px": None if reading.frame_c is None else int(reading.frame_c.shape[1]),
                "height_px": None if reading.frame_c is None else int(reading.frame_c.shape[0]),
                "min_c": None if reading.frame_c is None else float(reading.frame_c.min()),
                "max_c": None if reading.frame_c is None else float(reading.frame_c.max()),
                "regions": {
                    name: {"mean_c": r.mean_c, "max_c": r.max_c, "node": r.node}
                    for name, r in reading.regions.items()
                },
            },
            "robot": self._robot_dict(),
            "room": None
            if self.room is None
            else {"temperature_c": self.room.temperature_c, "sensor": self.room.sensor},
            "notes": list(self.notes),
            "errors": dict(self.errors),
        }

    def _robot_dict(self) -> dict[str, Any] | None:
        if self.pose is None and not self.robot_facts:
            return None
        robot: dict[str, Any] = {
            "link": self.robot_link,
            "pose": None if self.pose is None else list(_pose_values(self.pose)),
        }
        if self.robot_facts:
            robot["facts"] = dict(self.robot_facts)
        return robot


def _pose_values(pose: Pose) -> tuple[float, ...]:
    return (pose.x, pose.y, pose.z, pose.z_rot, pose.y_rot, pose.x_rot)


def ir_regions(devices: Devices, settings: Settings) -> tuple[IrRegion, ...]:
    """The regions the IR reader measures: the configured ones, or the sim's defaults (its
    ``regions`` attribute, one per model node) when none are configured."""
    regions = getattr(devices.ir, "regions", None)
    if isinstance(regions, tuple) and regions:
        return regions
    return settings.ir.regions


async def _tool_frames(devices: Devices, settings: Settings, check: DeviceCheck) -> bool:
    """One frame of every tool camera of an arm (drivers.factory.Devices.cameras), all at
    once; False when there are none (the two-link bench's spot camera is checked instead)."""
    cameras = tuple(getattr(devices, "cameras", ()) or ())
    if not cameras:
        return False
    models = tuple(getattr(devices, "camera_models", ()) or ())
    names = (
        [model.name for model in models]
        if len(models) == len(cameras)
        else [f"camera {k}" for k in range(len(cameras))]
    )
    timeout_s = settings.camera.grab_timeout_s
    grabbed = await asyncio.gather(
        *(bounded(camera.grab(), "camera", "frame", timeout_s) for camera in cameras),
        return_exceptions=True,
    )
    for name, result in zip(names, grabbed, strict=True):
        if isinstance(result, Frame):
            check.tool_frames.append((name, result))
        elif isinstance(result, DeviceError | TimeoutError):
            check.errors[name] = str(result) or "no frame within camera.grab_timeout_s"
        else:
            raise result
    return True


async def check_devices(devices: Devices, settings: Settings) -> DeviceCheck:
    """Grab one frame (of every tool camera on an arm), read one IR image and the robot's
    pose; measure the spot."""
    check = DeviceCheck(regions=ir_regions(devices, settings))
    await probe_room(getattr(devices, "room", None), settings, check)
    # a robot that describes itself (a UR, the only one today) plays its own program: a
    # followed run's devices, no spot camera or IR camera to probe
    if isinstance(devices.robot, DescribedRobot):
        await probe_described(devices.robot, check)
        if not await _tool_frames(devices, settings, check):
            check.notes.append(FOLLOWED_CAMERAS_NOTE)
        return check
    if not await _tool_frames(devices, settings, check):
        await probe_camera(devices.camera, settings, check)
    await probe_ir(devices.ir, settings, check)
    await probe_robot(devices.robot, check)
    return check


#: What the check says when no room thermometer is configured (room.driver none).
NO_ROOM_NOTE = (
    "room: no thermometer (room.driver none): the model holds model.ambient_c, and a room "
    "that warms during a run is read as the robot heating (docs/how-to/identify-arm-model.md)"
)


async def probe_room(room: RoomThermometer | None, settings: Settings, check: DeviceCheck) -> None:
    """One reading of the room thermometer (room.driver), into ``check``: a thermometer that
    does not answer fails the check as any device does (a run would flag every step
    room-error and hold the last room), none configured is a note."""
    if room is None:
        if settings.room.driver == "none" and settings.arm.enabled:  # the two-link has no room
            check.notes.append(NO_ROOM_NOTE)
        return
    try:
        check.room = await bounded(room.read(), "room", "reading", settings.room.read_timeout_s)
    except (DeviceError, TimeoutError) as err:
        check.errors["room"] = str(err) or "no reading within room.read_timeout_s"


async def probe_camera(camera: Camera, settings: Settings, check: DeviceCheck) -> None:
    """One frame of the spot camera and the spot measured in it, into ``check``."""
    try:
        check.frame = await bounded(
            camera.grab(), "camera", "frame", settings.camera.grab_timeout_s
        )
    except (DeviceError, TimeoutError) as err:
        check.errors["camera"] = str(err) or "no frame within camera.grab_timeout_s"
    if check.frame is not None:
        try:
            # off the event loop: a full-frame centroid is tens of milliseconds of CPU
            result = await asyncio.to_thread(
                measure_with_camera_settings,
                check.frame.image,
                settings.camera,
                camera_gain_e_per_count=check.frame.gain_e_per_count,
            )
            check.centroid = {
                "x_px": result.x_px,
                "y_px": result.y_px,
                "peak_fraction": result.peak_fraction,
                "snr": result.snr,
                "flags": list(result.flags),
                "gain_e_per_count": result.gain_e_per_count,
                "gain_source": result.gain_source,
            }
        except CentroidError as err:
            check.centroid_error = str(err)


async def probe_ir(ir: IrReader, settings: Settings, check: DeviceCheck) -> None:
    """One IR image and its regions, into ``check``."""
    try:
        check.reading = await bounded(ir.read(), "ir", "reading", settings.ir.read_timeout_s)
    except (DeviceError, TimeoutError) as err:
        check.errors["ir"] = str(err) or "no reading within ir.read_timeout_s"


async def probe_robot(robot: Robot, check: DeviceCheck) -> None:
    """The robot's pose and link state, into ``check``."""
    try:
        check.pose = await asyncio.wait_for(robot.actual_pose(), POSE_TIMEOUT_S)
        check.robot_link = robot.status().link.value
    except (DeviceError, TimeoutError) as err:
        check.errors["robot"] = str(err) or "no pose"


#: What a followed run's check says when it has no tool camera (a UR without
#: arm.camera_devices, the UR bench without arm.bench_cameras).
FOLLOWED_CAMERAS_NOTE = (
    "cameras: none checked: a followed run (robot.driver ur-rtde) with no tool camera "
    "(arm.camera_devices; on the bench arm.bench_cameras) measures nothing, its thermal input "
    "is the joint temperatures (docs/how-to/universal-robots.md)"
)


async def probe_described(robot: object, check: DeviceCheck) -> None:
    """A robot that describes itself (a UR): its facts, and each problem that would stop a run
    as its own failure (``robot <topic>``); its link failing is the one ``robot`` failure."""
    if not isinstance(robot, DescribedRobot):
        check.errors["robot"] = "this robot cannot describe itself"
        return
    try:
        description = await asyncio.wait_for(robot.describe(), POSE_TIMEOUT_S)
    except (DeviceError, TimeoutError) as err:
        check.errors["robot"] = str(err) or "no description"
        return
    status = getattr(robot, "status", None)
    check.robot_link = status().link.value if callable(status) else None
    check.robot_facts = description.facts
    for topic, problem in description.problems:
        check.errors[f"robot {topic}"] = problem


def describe(check: DeviceCheck) -> list[str]:
    """The check as lines for people."""
    data = check.as_dict()
    lines = [
        f"camera {name}: {frame.image.shape[1]}x{frame.image.shape[0]} px, "
        f"counts {int(frame.image.min())}..{int(frame.image.max())}"
        for name, frame in check.tool_frames
    ]
    camera = data["camera"]
    if camera is not None:
        lines.append(
            f"camera: {camera['width_px']}x{camera['height_px']} px, {camera['dtype']}, "
            f"{camera['bit_depth']}-bit, counts {camera['min_counts']}..{camera['max_counts']}, "
            f"frame time from {camera['timestamp_source']}"
        )
        spot = camera["spot"]
        if spot is not None:
            flags = f" [{', '.join(spot['flags'])}]" if spot["flags"] else ""
            lines.append(
                f"camera: spot found at ({spot['x_px']:.2f}, {spot['y_px']:.2f}) px, peak "
                f"{100 * spot['peak_fraction']:.0f} % of full scale, SNR {spot['snr']:.0f}{flags}"
            )
        else:
            lines.append(f"camera: no spot: {camera['spot_error']}")
    ir = data["ir"]
    if ir is not None:
        if ir["width_px"] is not None:
            lines.append(
                f"ir: {ir['width_px']}x{ir['height_px']} px, "
                f"{ir['min_c']:.2f}..{ir['max_c']:.2f} degC"
            )
        for name, region in ir["regions"].items():
            node = f" (node {region['node']})" if region["node"] else ""
            lines.append(
                f"ir: region {name}{node}: mean {region['mean_c']:.2f} degC, max "
                f"{region['max_c']:.2f} degC"
            )
        if not ir["regions"]:
            lines.append("ir: no regions configured ([[ir.regions]]): place them on the preview")
    robot = data["robot"]
    if robot is not None and robot["pose"] is not None:
        x, y, z, z_rot, y_rot, x_rot = robot["pose"]
        lines.append(
            f"robot: {robot['link']}, pose x {x:.3f} y {y:.3f} z {z:.3f} mm, "
            f"rotations {z_rot:.3f} {y_rot:.3f} {x_rot:.3f} deg"
        )
    if robot is not None and "facts" in robot:
        lines.append(f"robot: {robot['link']}")
        lines.extend(f"robot: {name}: {fact}" for name, fact in robot["facts"].items())
    room = data["room"]
    if room is not None:
        lines.append(f"room: {room['temperature_c']:.2f} degC ({room['sensor']})")
    lines.extend(data["notes"])
    lines.extend(f"{device}: FAILED: {error}" for device, error in data["errors"].items())
    return lines


def preview_image(check: DeviceCheck) -> NDArray[np.uint8]:
    """The preview: camera frame with the centroid, thermal image with the regions."""
    panels = []
    height = 480
    for name, frame in check.tool_frames:  # an arm: every tool camera, markers kept visible
        reduced = block_max(frame.image, TOOL_PANEL_WIDTH_PX)
        panels.append(camera_panel(reduced, None, tool_caption(name, frame)))
        height = reduced.shape[0]
    if check.frame is not None:
        centroid = check.centroid
        spot = None if centroid is None else (centroid["x_px"], centroid["y_px"])
        caption = (
            f"camera: spot at ({spot[0]:.1f}, {spot[1]:.1f}) px"
            if spot is not None
            else f"camera: no spot ({check.centroid_error})"
        )
        panels.append(camera_panel(check.frame.image, spot, caption))
        height = check.frame.image.shape[0]
    reading = check.reading
    if reading is not None and reading.frame_c is not None:
        boxes = [
            RegionBox(
                name=region.name,
                x=region.x,
                y=region.y,
                width=region.width,
                height=region.height,
                label=f"{region.name} {reading.regions[region.name].mean_c:.1f} C"
                if region.name in reading.regions
                else region.name,
            )
            for region in check.regions
        ]
        panels.append(ir_panel(reading.frame_c, boxes, "ir: regions (mean degC)", height))
    if not panels:
        raise DeviceError("devices", "neither a frame nor a thermal image to preview")
    rows = [
        side_by_side(panels[k : k + PANELS_PER_ROW]) for k in range(0, len(panels), PANELS_PER_ROW)
    ]
    return one_above_another(rows)


#: Below this fraction of full scale a tool camera's brightest pixel is no lit marker.
DARK_FRACTION = 0.1


def tool_caption(name: str, frame: Frame) -> str:
    """A tool camera's panel caption: its size, its brightest count, and whether anything
    bright is in view (at rest the tool is usually outside every camera's view)."""
    peak = int(frame.image.max())
    full = (1 << frame.bit_depth) - 1 if frame.bit_depth else peak or 1
    dark = "; dark: nothing in view" if peak < DARK_FRACTION * full else ""
    size = f"{frame.image.shape[1]} x {frame.image.shape[0]} px"
    return f"{name}: {size}, peak {peak} of {full}{dark}"


#: The preview's tool camera panels: this wide at most, three to a row.
TOOL_PANEL_WIDTH_PX = 480
PANELS_PER_ROW = 3


def block_max(image: NDArray[Any], max_width_px: int) -> NDArray[Any]:
    """``image`` reduced to at most ``max_width_px`` wide, each pixel the brightest of its
    block (then grown to 3 x 3): a marker a few pixels wide on a 5 MP frame survives (a
    plain resize loses it, and the browser's scaling did: the preview showed a black frame)."""
    scale = max(1, -(-image.shape[1] // max_width_px))
    rows, cols = image.shape[0] // scale, image.shape[1] // scale
    blocks = image[: rows * scale, : cols * scale].reshape(rows, scale, cols, scale)
    reduced: NDArray[Any] = blocks.max(axis=(1, 3))
    # then each pixel the brightest of its 3 x 3 neighbours: a marker of one reduced pixel
    # is a dot a person finds on a 480 px panel
    grown: NDArray[Any] = cv2.dilate(reduced, np.ones((3, 3), np.uint8))
    return grown


def one_above_another(rows: list[NDArray[np.uint8]]) -> NDArray[np.uint8]:
    """Rows of panels stacked, left-aligned on a black background."""
    if len(rows) == 1:
        return rows[0]
    width = max(row.shape[1] for row in rows)
    canvas = np.zeros((sum(row.shape[0] for row in rows) + 8 * (len(rows) - 1), width, 3), np.uint8)
    y = 0
    for row in rows:
        canvas[y : y + row.shape[0], : row.shape[1]] = row
        y += row.shape[0] + 8
    return canvas


def preview_png(check: DeviceCheck) -> bytes:
    return encode_png(preview_image(check))
