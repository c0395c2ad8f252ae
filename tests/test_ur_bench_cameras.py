"""The UR bench's tool cameras (issue 31; drivers/sim/ur/cameras.py): config/ur5e-sim.toml opens
the UR emulator (real TCP, the real UR driver) with ``arm.cameras`` cameras at each measured
pose of the program, rendering the markers on the emulator's *true* tool with the A465 bench's
renderer. While the program dwells at the camera station (its at-pose register, read over
RTDE), that station's cameras see every marker where the truth's warm arm at the actual joints
puts it, the other station's see nothing, and the arm run's meter (daemon/run/arm/measure.py)
measures the tool where the truth has it. Without ``arm.bench_cameras`` the bench has none."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest

from config import CONFIG_DIR, Settings
from config.settings import load_settings
from daemon.arm import kinematics
from daemon.arm.loading import load_arm
from daemon.arm.types import pose_difference
from daemon.run.arm.measure import MultiCameraMeter
from daemon.run.workers import Workers
from daemon.vision.centroid import measure_centroid
from daemon.vision.markers import marker_pixels
from drivers.base import OffsetRobot, Robot
from drivers.clock import make_clock
from drivers.errors import NotConnectedError
from drivers.factory import open_devices
from tests.loopback import loopback_host

WAIT_S = 60.0
#: half-width of the window a rendered spot's centroid is measured in (px)
HALF_PX = 12
#: the truth's arm made this much warmer than the room before the tool is measured (degC)
WARMER_C = 15.0


def ur_bench(tmp_path: Path, host: str, **arm: object) -> Settings:
    base = load_settings(CONFIG_DIR / "ur5e-sim.toml")
    return Settings.model_validate(
        {
            **base.model_dump(),
            # the emulator runs in this process: a loaded machine may starve it a while
            "robot": {**base.robot.model_dump(), "host": host, "ur_timeout_s": 10.0},
            "storage": {**base.storage.model_dump(), "data_dir": str(tmp_path)},
            "arm": {**base.arm.model_dump(), **arm},
        }
    )


def _ur(robot: Robot) -> OffsetRobot:
    assert isinstance(robot, OffsetRobot)
    return robot


async def _at_pose(robot: Robot, pose: int) -> None:
    """Until the program dwells at ``pose`` (1-based pose of its cycle) by its register."""
    async with asyncio.timeout(WAIT_S):
        while True:
            try:
                if _ur(robot).robot_state().at_pose == pose:
                    return
            except NotConnectedError:  # the first state package is not in yet
                pass
            await asyncio.sleep(0.02)


@pytest.mark.slow
async def test_the_ur_bench_cameras_see_the_markers_on_the_true_tool(tmp_path: Path) -> None:
    settings = ur_bench(tmp_path, loopback_host())
    assert settings.arm.bench_cameras and settings.arm.cameras == 3
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    workers = Workers()
    try:
        async with open_devices(settings, clock) as devices:
            emulator = devices.ur_emulator
            assert emulator is not None
            controller = emulator.controller
            # two measured poses (the camera station, the fixture), three cameras each
            assert len(devices.cameras) == len(devices.camera_models) == 6
            station = [m.name.startswith("s0-") for m in devices.camera_models]
            # the camera station, pose 1 of the cycle: frames taken within one dwell (on a loaded
            # machine the program may leave before the six renders are done: then the next one)
            async with asyncio.timeout(WAIT_S):
                while True:
                    await _at_pose(devices.robot, 1)
                    actual, _, _ = controller.joint_state(controller.time_s)
                    truth_markers = controller.bench.markers_world_mm(actual)
                    frames = await asyncio.gather(*(c.grab() for c in devices.cameras))
                    if _ur(devices.robot).robot_state().at_pose == 1:
                        break
            for model, frame, watching in zip(devices.camera_models, frames, station, strict=True):
                image = np.asarray(frame.image)
                if not watching:
                    assert image.max() == 0, model.name  # the tool is not in its view
                    continue
                pixels, visible = marker_pixels(model, truth_markers)
                assert visible.all(), model.name
                for x, y in pixels:  # each marker's spot where the truth projects it
                    c0, r0 = round(x) - HALF_PX, round(y) - HALF_PX
                    window = image[r0 : r0 + 2 * HALF_PX + 1, c0 : c0 + 2 * HALF_PX + 1]
                    spot = measure_centroid(window, bit_depth=frame.bit_depth)
                    assert abs(spot.x_px + c0 - x) < 0.3 and abs(spot.y_px + r0 - y) < 0.3
            # the arm run's meter on these cameras measures the true tool (the warm true arm
            # at the actual joints), starting from the nominal arm's pose as its guess
            meter = MultiCameraMeter(settings, devices.cameras, devices.camera_models, workers)
            # the truth's arm 15 degC warmer: the frames show its thermal deformation
            thermal = controller.bench.thermal
            thermal.set_temperatures(thermal.temperatures_c + WARMER_C)
            async with asyncio.timeout(WAIT_S):
                while True:
                    await _at_pose(devices.robot, 1)
                    expected = np.asarray(_ur(devices.robot).robot_state().joints_rad)
                    guess = kinematics.forward(load_arm(settings.arm.arm_file), expected)
                    measured = await meter.measure(guess)
                    true_pose = controller.bench.tool_pose_true(
                        controller.joint_state(controller.time_s)[0]
                    )
                    if _ur(devices.robot).robot_state().at_pose == 1:
                        break
            error = pose_difference(true_pose, measured.pose)
            assert measured.sigma_mm < 0.01  # a few micrometres
            assert error.translation_norm_mm < 4.0 * measured.sigma_mm, (error, measured.sigma_mm)
            # the nominal arm is not the true one, and the cold arm not the warm one: the guess
            # and the cold pose are off by far more than that
            assert pose_difference(true_pose, guess).translation_norm_mm > 0.05
            cold = controller.bench.tool_pose_cold(controller.joint_state(controller.time_s)[0])
            assert pose_difference(cold, true_pose).translation_norm_mm > 0.1
    finally:
        workers.shutdown()


async def test_a_ur_bench_without_bench_cameras_has_none(tmp_path: Path) -> None:
    settings = ur_bench(tmp_path, loopback_host(), bench_cameras=False)
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    async with open_devices(settings, clock) as devices:
        assert devices.cameras == () and devices.camera_models == ()
        assert devices.ur_emulator is not None
