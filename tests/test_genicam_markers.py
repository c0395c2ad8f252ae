"""The arm's tool measured on real GenICam frames (issue 20): pylon's emulated cameras
(PYLON_CAMEMU) serve image files of the markers rendered as each camera of a camera file sees
them at a known tool pose (drivers/sim/camemu.py: the files, and the feature file the driver
loads to point each camera at its own), grabbed through the real driver
(drivers/genicam/camera.py) and measured by the arm run's measurement (daemon/run/arm/measure.py).

The oracle is the pose the images were rendered at: the measured pose must match it within the
measurement's own predicted uncertainty, and a second frame rendered with the tool moved by a
known 6-DOF offset must give that offset back (the drift an arm run records)."""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

# pylon reads the number of emulated cameras when its transport layers start: before any import
# (the same two as tests/test_arm_cameras.py and tests/test_genicam.py, whichever loads first).
os.environ.setdefault("PYLON_CAMEMU", "2")

from config import Settings
from config.settings import CameraSettings
from daemon.arm.run import MeasurementError, ToolMeasurement
from daemon.arm.types import Pose6
from daemon.run.arm.measure import MultiCameraMeter
from daemon.run.workers import Workers
from daemon.vision.cameras import write_cameras
from daemon.vision.markers import marker_pixels, render_markers
from daemon.vision.multiview import CameraModel, pose_difference
from drivers.base import Frame
from drivers.clock import ScaledClock
from drivers.errors import DeviceError, DeviceTimeoutError, ProtocolError
from drivers.genicam.camera import GenICamCamera
from drivers.sim.arm_markers import CameraRig
from drivers.sim.camemu import (
    emulation_image,
    write_emulation_frames,
    write_emulation_image,
    write_feature_file,
)

EMULATED = ("0815-0000", "0815-0001")  # the emulation's serial numbers
WIDTH_PX, HEIGHT_PX = 640, 480
needs_pylon = pytest.mark.skipif(
    importlib.util.find_spec("pypylon") is None,
    reason="pypylon (the genicam extra) is not installed: pip install 'thermocomp[genicam]'",
)
#: The tool pose the frames are rendered at (mm, rotation vector): any pose the cameras see.
TOOL_MM = (420.0, 80.0, 360.0)
TOOL_ROTATION_RAD = (0.3, -2.6, 0.2)
#: The known 6-DOF drift of the second frame: 45 um, 340 urad.
OFFSET_MM = (0.030, -0.025, 0.020)
OFFSET_RAD = (2.0e-4, -1.5e-4, 2.5e-4)
#: The sensor (the arm bench's, drivers/sim/arm_markers.py CameraRig, in a 640 x 480 ROI).
GAIN_E_PER_COUNT = 2.5
READ_NOISE_E = 6.0
SPOT_SIGMA_PX = 2.0
PEAK_FRACTION = 0.6


def pose(translation_mm: Any, rotation_rad: Any) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_rotvec(rotation_rad).as_matrix()
    matrix[:3, 3] = translation_mm
    return matrix


def moved(base: np.ndarray, translation_mm: Any, rotation_rad: Any) -> np.ndarray:
    """``base`` moved by the drift (t, r) as daemon.vision.multiview.pose_difference reads it:
    t_cur = t_ref + t, R_cur = R(r) R_ref."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(rotation_rad).as_matrix() @ base[:3, :3]
    out[:3, 3] = base[:3, 3] + np.asarray(translation_mm)
    return out


def rig(count: int, target_mm: Any = TOOL_MM) -> tuple[CameraModel, ...]:
    """``count`` cameras 700 mm from the tool (at ``target_mm``), 30 deg above it, 120 deg
    apart; f = 2000 px; the camera file's pixel floor low enough that the centroids' own
    noise rules."""
    cameras = CameraRig(
        count=count,
        focal_px=2000.0,
        width_px=WIDTH_PX,
        height_px=HEIGHT_PX,
        pixel_sigma_px=1e-4,
        spread_rad=math.radians(120.0),
        azimuth_rad=math.radians(-60.0),
    ).cameras(target_mm)
    return tuple(cameras)


def markers_world(tool_pose: np.ndarray, settings: Settings) -> np.ndarray:
    markers = np.array(settings.arm.markers_mm, dtype=np.float64)
    world: np.ndarray = markers @ tool_pose[:3, :3].T + tool_pose[:3, 3]
    return world


def frame_of(
    camera: CameraModel, points: np.ndarray, bit_depth: int, rng: np.random.Generator
) -> np.ndarray:
    """The markers as ``camera`` sees them, with the sensor's noise, in ``bit_depth`` bits."""
    gain = GAIN_E_PER_COUNT * 2 ** (12 - bit_depth)  # the same electrons at any depth
    image = render_markers(
        camera,
        points,
        rng=rng,
        sigma_px=SPOT_SIGMA_PX,
        peak_fraction=PEAK_FRACTION,
        bit_depth=bit_depth,
        read_noise_counts=READ_NOISE_E / gain,
        gain_e_per_count=gain,
    )
    return np.asarray(image)


def device(serial: str, feature_file: Path, bit_depth: int) -> CameraSettings:
    return CameraSettings(
        driver="genicam",
        serial=serial,
        width_px=WIDTH_PX,
        height_px=HEIGHT_PX,
        bit_depth=bit_depth,
        gain_e_per_count=GAIN_E_PER_COUNT * 2 ** (12 - bit_depth),
        read_noise_e=READ_NOISE_E,
        feature_file=feature_file,
    )


def arm_settings(devices: list[CameraSettings], cameras_file: Path) -> Settings:
    """Hardware arm settings; the laser-spot camera 8-bit on purpose: the tool's cameras must
    be measured at their own depth, not the spot camera's."""
    return Settings.model_validate(
        {
            "camera": {"bit_depth": 8},
            "arm": {
                "enabled": True,
                "cameras_file": str(cameras_file),
                "camera_devices": [d.model_dump(mode="json") for d in devices],
            },
        }
    )


def marker_radius_mm(settings: Settings) -> float:
    """RMS distance of the markers from their centre: a position error sigma of the tool
    turns it by about sigma / this (first order, rigid_pose_from_markers' fit)."""
    markers = np.array(settings.arm.markers_mm, dtype=np.float64)
    return float(np.sqrt(np.mean(np.sum((markers - markers.mean(axis=0)) ** 2, axis=1))))


def check_within(
    found: Pose6, truth: Pose6, sigma_mm: float, radius_mm: float, sigmas: float = 4.0
) -> None:
    """``found`` matches ``truth`` within ``sigmas`` times the predicted 1-sigma: the 3-D
    translation's (sigma_mm is the norm's) and the rotation's (sigma_mm / radius_mm)."""
    translation_mm = float(np.linalg.norm(found.translation_mm - truth.translation_mm))
    rotation_rad = float(np.linalg.norm(found.rotation_rad - truth.rotation_rad))
    assert translation_mm < sigmas * sigma_mm, (translation_mm * 1e3, sigma_mm * 1e3)
    assert rotation_rad < sigmas * sigma_mm / radius_mm, (rotation_rad * 1e6, sigma_mm)


@needs_pylon
@pytest.mark.parametrize("bit_depth", [8, 12, 16])
async def test_markers_on_emulated_genicam_frames_give_the_pose_and_its_drift(
    tmp_path: Path, bit_depth: int
) -> None:
    probe = Settings()
    models = rig(len(EMULATED))
    write_cameras(tmp_path / "cameras.toml", models)
    at_rest = pose(TOOL_MM, TOOL_ROTATION_RAD)
    drifted = moved(at_rest, OFFSET_MM, OFFSET_RAD)
    rng = np.random.default_rng(20 + bit_depth)
    devices = []
    for serial, model in zip(EMULATED, models, strict=True):
        points = markers_world(at_rest, probe)
        _, visible = marker_pixels(model, points)
        assert visible.all()  # every marker on every chip
        frames = [
            frame_of(model, markers_world(p, probe), bit_depth, rng) for p in (at_rest, drifted)
        ]
        folder = write_emulation_frames(tmp_path / serial, frames, bit_depth)
        devices.append(
            device(serial, write_feature_file(tmp_path / f"{serial}.pfs", folder), bit_depth)
        )
    settings = arm_settings(devices, tmp_path / "cameras.toml")
    workers = Workers()
    try:
        async with contextlib.AsyncExitStack() as stack:
            clock = ScaledClock()
            cameras = [await stack.enter_async_context(GenICamCamera(d, clock)) for d in devices]
            meter = MultiCameraMeter(settings, cameras, models, workers)
            first = await meter.measure(at_rest)  # the folders' first frames
            # the next ones, measured where the first pose puts the markers (as an arm run
            # measures around the taught pose)
            second = await meter.measure(at_rest)
    finally:
        workers.shutdown()
    assert first.oriented and second.oriented
    assert set(first.centroids_px) == {m.name for m in models}
    assert all(len(c) == 4 for c in first.centroids_px.values())  # every marker, every camera
    radius_mm = marker_radius_mm(probe)
    zero = Pose6(np.zeros(3), np.zeros(3))
    # the poses the frames were rendered at
    check_within(pose_difference(at_rest, first.pose), zero, first.sigma_mm, radius_mm)
    check_within(pose_difference(drifted, second.pose), zero, second.sigma_mm, radius_mm)
    # the drift an arm run records: the known offset
    drift = pose_difference(first.pose, second.pose)
    known = Pose6(np.array(OFFSET_MM), np.array(OFFSET_RAD))
    check_within(drift, known, math.hypot(first.sigma_mm, second.sigma_mm), radius_mm)
    # the measurement's 1-sigma: 1.5-1.7 um for these spots at any depth (the same electrons)
    assert first.sigma_mm < 0.003


@needs_pylon
@pytest.mark.parametrize("bit_depth", [8, 12, 16])
async def test_the_emulation_serves_a_file_count_for_count_in_each_depth(
    tmp_path: Path, bit_depth: int
) -> None:
    """The file convention of drivers/sim/camemu.py: counts of ``bit_depth`` bits written to
    the file arrive through the driver unchanged, in Mono<bit_depth>."""
    rng = np.random.default_rng(bit_depth)
    counts = rng.integers(0, 1 << bit_depth, size=(HEIGHT_PX, WIDTH_PX))
    path = write_emulation_image(tmp_path / "frame.png", counts, bit_depth)
    settings = device(EMULATED[1], write_feature_file(tmp_path / "f.pfs", path), bit_depth)
    async with GenICamCamera(settings, ScaledClock()) as camera:
        frame = await camera.grab()
    assert frame.bit_depth == bit_depth
    assert frame.image.dtype == (np.uint8 if bit_depth == 8 else np.uint16)
    np.testing.assert_array_equal(frame.image, counts)
    # the file holds the most significant bits (12 -> 16 bits: x16)
    assert int(emulation_image(np.array([[1]]), bit_depth)[0, 0]) == 2 ** (
        0 if bit_depth == 8 else 16 - bit_depth
    )


@needs_pylon
async def test_a_frame_that_is_not_the_roi_is_refused_naming_both_sizes(tmp_path: Path) -> None:
    small = np.zeros((HEIGHT_PX // 2, WIDTH_PX // 2), dtype=np.uint16)
    small[10, 10] = 100
    path = write_emulation_image(tmp_path / "small.png", small, 12)
    settings = device(EMULATED[0], write_feature_file(tmp_path / "f.pfs", path), 12)
    async with GenICamCamera(settings, ScaledClock()) as camera:
        with pytest.raises(ProtocolError) as caught:
            await camera.grab()
    message = str(caught.value)
    assert "\n" not in message
    assert "320x240 frame" in message and "ROI is 640x480" in message
    assert EMULATED[0] in message


@needs_pylon
async def test_a_bad_feature_file_fails_the_open_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.pfs"
    bad.write_text(
        "# {05D8C294-F295-4dfb-9D01-096BD04049F4}\nTestImageSelector\tNoSuchImage\n",
        encoding="utf-8",
    )
    for path, reason in ((bad, "TestImageSelector"), (tmp_path / "none.pfs", "could not")):
        with pytest.raises(DeviceError) as caught:
            async with GenICamCamera(device(EMULATED[0], path, 12), ScaledClock()):
                pass
        message = str(caught.value)
        assert "\n" not in message
        assert f"feature file {path}" in message and reason in message


class _SilentCamera:
    """A camera whose grab never returns (a frame lost on the wire)."""

    async def __aenter__(self) -> _SilentCamera:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def grab(self) -> Frame:
        await asyncio.Event().wait()
        raise AssertionError("unreachable")


async def test_each_tool_camera_is_waited_for_its_own_grab_timeout(tmp_path: Path) -> None:
    """arm.camera_devices[i].grab_timeout_s bounds camera i's grab, not the laser-spot
    camera's (here 30 s): the measurement fails after the device's 0.05 s."""
    models = rig(2)
    write_cameras(tmp_path / "cameras.toml", models)
    devices = [
        device(serial, tmp_path / "unused.pfs", 12).model_copy(update={"grab_timeout_s": 0.05})
        for serial in EMULATED
    ]
    settings = arm_settings(devices, tmp_path / "cameras.toml")
    assert settings.camera.grab_timeout_s != 0.05
    settings = settings.model_copy(
        update={"camera": settings.camera.model_copy(update={"grab_timeout_s": 30.0})}
    )
    workers = Workers()
    try:
        meter = MultiCameraMeter(settings, [_SilentCamera(), _SilentCamera()], models, workers)
        async with asyncio.timeout(10.0):
            with pytest.raises(DeviceTimeoutError, match=r"no frame within 0.05 s"):
                await meter.measure(pose(TOOL_MM, TOOL_ROTATION_RAD))
    finally:
        workers.shutdown()


async def test_a_camera_that_times_out_ends_the_other_cameras_grabs(tmp_path: Path) -> None:
    """One camera's timeout fails the measurement, and the others' grabs end with it: none is
    left pending after the error (with a bare gather the 5-s camera's grab outlived the
    failed measurement)."""
    models = rig(2)
    write_cameras(tmp_path / "cameras.toml", models)
    devices = [
        device(serial, tmp_path / "unused.pfs", 12).model_copy(update={"grab_timeout_s": timeout})
        for serial, timeout in zip(EMULATED, (0.05, 5.0), strict=False)
    ]
    settings = arm_settings(devices, tmp_path / "cameras.toml")
    workers = Workers()
    try:
        meter = MultiCameraMeter(settings, [_SilentCamera(), _SilentCamera()], models, workers)
        before = asyncio.all_tasks()
        async with asyncio.timeout(4.0):
            with pytest.raises(DeviceTimeoutError, match=r"no frame within 0.05 s"):
                await meter.measure(pose(TOOL_MM, TOOL_ROTATION_RAD))
        pending = [task for task in asyncio.all_tasks() - before if not task.done()]
        assert pending == []
    finally:
        workers.shutdown()


@needs_pylon
async def test_devices_in_another_order_than_the_camera_file_do_not_measure_the_tool(
    tmp_path: Path,
) -> None:
    """arm.camera_devices[i] is the camera file's camera i: each emulated camera serves the
    view of its own model, so the same devices listed the other way round find no marker
    where the models put them (the serial decides the device, not the listing order)."""
    probe = Settings()
    models = rig(len(EMULATED))
    at_rest = pose(TOOL_MM, TOOL_ROTATION_RAD)
    rng = np.random.default_rng(3)
    devices = []
    for serial, model in zip(EMULATED, models, strict=True):
        frame = frame_of(model, markers_world(at_rest, probe), 12, rng)
        path = write_emulation_image(tmp_path / f"{serial}.png", frame, 12)
        devices.append(device(serial, write_feature_file(tmp_path / f"{serial}.pfs", path), 12))
    workers = Workers()
    results: list[ToolMeasurement | str] = []
    try:
        for listed in (devices, devices[::-1]):
            write_cameras(tmp_path / "cameras.toml", models)
            settings = arm_settings(listed, tmp_path / "cameras.toml")
            async with contextlib.AsyncExitStack() as stack:
                clock = ScaledClock()
                cameras = [await stack.enter_async_context(GenICamCamera(d, clock)) for d in listed]
                meter = MultiCameraMeter(settings, cameras, models, workers)
                try:
                    results.append(await meter.measure(at_rest))
                except MeasurementError as err:
                    results.append(str(err))
    finally:
        workers.shutdown()
    in_order, swapped = results
    assert isinstance(in_order, ToolMeasurement) and in_order.oriented
    # nor a pose from single views (daemon/vision/pnp.py): each camera found at most one
    # marker where its model looked
    assert isinstance(swapped, str) and swapped.startswith(
        "no marker seen by 2 cameras, and no pose"
    )
