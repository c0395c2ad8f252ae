"""An arm run on hardware (issue 20): the factory opens the real cameras that watch the tool
(arm.camera_devices) next to the robot, with their models from arm.cameras_file. Tested on
pylon's own emulated GenICam cameras (PYLON_CAMEMU), as tests/test_genicam.py does."""

from __future__ import annotations

import importlib.util
import json
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

# pylon reads the number of emulated cameras when its transport layers start: before any import.
os.environ.setdefault("PYLON_CAMEMU", "2")

from config import ConfigError, Settings, load_settings
from daemon.vision.cameras import CameraModel, intrinsic_matrix, look_at, write_cameras
from drivers.base import LinkState
from drivers.clock import ScaledClock
from drivers.factory import open_devices
from drivers.genicam.camera import GenICamCamera

SIM = str(Path(__file__).resolve().parents[1] / "config" / "sim.toml")
EMULATED = ("0815-0000", "0815-0001")  # the emulation's serial numbers
needs_pylon = pytest.mark.skipif(
    importlib.util.find_spec("pypylon") is None,
    reason="pypylon (the genicam extra) is not installed: pip install 'thermocomp[genicam]'",
)


def camera_file(path: Path, count: int) -> Path:
    """A camera file of ``count`` cameras around the tool's work volume."""
    models = []
    for i in range(count):
        angle = 2 * np.pi * i / count
        position = (1500.0 * np.cos(angle), 1500.0 * np.sin(angle), 800.0)
        rvec, tvec = look_at(position, (0.0, 0.0, 400.0))
        models.append(
            CameraModel(
                name=f"cam{i}",
                matrix=intrinsic_matrix((2400.0, 2400.0), (159.5, 119.5)),
                distortion=np.zeros(5),
                rotation_rad=rvec,
                translation_mm=tvec,
                image_size_px=(320, 240),
            )
        )
    write_cameras(path, models)
    return path


def devices(serials: tuple[str, ...]) -> list[dict[str, Any]]:
    return [
        {"driver": "genicam", "serial": s, "width_px": 320, "height_px": 240, "bit_depth": 8}
        for s in serials
    ]


def arm_on_hardware(
    monkeypatch: pytest.MonkeyPatch, cameras_file: Path, serials: tuple[str, ...]
) -> Settings:
    # not the arm bench: the robot is the fast path (its program emulated on a pty), so the
    # factory takes the hardware path and opens arm.camera_devices
    monkeypatch.setenv("THERMOCOMP_ROBOT__DRIVER", "c500c-server")
    monkeypatch.setenv("THERMOCOMP_ARM__ENABLED", "true")
    monkeypatch.setenv("THERMOCOMP_ARM__CAMERAS_FILE", str(cameras_file))
    monkeypatch.setenv("THERMOCOMP_ARM__CAMERA_DEVICES", json_list(devices(serials)))
    return load_settings(Path(SIM))


def json_list(value: list[dict[str, Any]]) -> str:
    return json.dumps(value)


@needs_pylon
async def test_the_factory_opens_each_arm_camera_and_each_grabs(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    settings = arm_on_hardware(monkeypatch, camera_file(tmp_path / "cams.toml", 2), EMULATED)
    async with open_devices(settings, ScaledClock()) as opened:
        assert opened.arm_bench is None  # the hardware path, not the arm bench
        assert len(opened.cameras) == 2
        arm_cameras = [cam for cam in opened.cameras if isinstance(cam, GenICamCamera)]
        assert len(arm_cameras) == 2
        opened_as = [cam.transport.description for cam in arm_cameras]
        frames = [await cam.grab() for cam in arm_cameras]
        assert [m.name for m in opened.camera_models] == ["cam0", "cam1"]
        single = await opened.camera.grab()  # the laser-spot camera stays as it was
    # in the order of arm.camera_devices ("<model> <serial>")
    assert [name.split()[-1] for name in opened_as] == list(EMULATED)
    for frame in frames:
        assert frame.image.shape == (240, 320) and frame.image.dtype == np.uint8
        assert int(frame.image.max()) > 0
    assert single.image.shape == (settings.camera.height_px, settings.camera.width_px)
    assert all(cam.link == LinkState.DISCONNECTED for cam in arm_cameras)  # closed on exit
    assert not [t for t in threading.enumerate() if t.name.startswith("genicam-camera")]


async def test_a_count_mismatch_names_both_counts(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # refused before any camera is opened: no pylon needed
    settings = arm_on_hardware(monkeypatch, camera_file(tmp_path / "cams.toml", 3), EMULATED)
    with pytest.raises(ConfigError) as caught:
        async with open_devices(settings, ScaledClock()):
            pass
    message = str(caught.value)
    assert "\n" not in message
    assert "arm.camera_devices lists 2 cameras" in message and "has 3" in message


def test_camera_devices_need_the_camera_file() -> None:
    with pytest.raises(ConfigError) as caught:
        load_settings(None, {"THERMOCOMP_ARM__CAMERA_DEVICES": json_list(devices(EMULATED))})
    message = str(caught.value)
    assert "\n" not in message
    assert "arm.camera_devices needs arm.cameras_file" in message


def test_camera_devices_are_real_cameras(tmp_path: Path) -> None:
    environ = {
        "THERMOCOMP_ARM__CAMERAS_FILE": str(tmp_path / "cams.toml"),
        "THERMOCOMP_ARM__CAMERA_DEVICES": json_list([{"driver": "sim"}]),
    }
    with pytest.raises(ConfigError, match=r"arm.camera_devices\[0\]: driver 'sim'"):
        load_settings(None, environ)


def test_without_camera_devices_the_settings_are_as_before() -> None:
    assert Settings().arm.camera_devices == ()
