"""The GenICam camera driver (issue 18) against pylon's emulated cameras (PYLON_CAMEMU): frames,
formats, ROI, exposure, selection, frame times, bounded and cancel-safe grabs, unplug/re-plug."""

from __future__ import annotations

import asyncio
import importlib.util
import os
import threading
from typing import Any

import numpy as np
import pytest

# pylon reads the number of emulated cameras when its transport layers start: before any import.
os.environ.setdefault("PYLON_CAMEMU", "2")

from config.settings import CameraSettings
from drivers.base import LinkState
from drivers.clock import ScaledClock
from drivers.errors import (
    DeviceError,
    DeviceTimeoutError,
    NotConnectedError,
    ProtocolError,
)
from drivers.genicam.camera import GenICamCamera
from drivers.genicam.transport import CameraClockMap, choose_pixel_format

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("pypylon") is None,
    reason="pypylon (the genicam extra) is not installed: pip install 'thermocomp[genicam]'",
)

SECOND_CAMERA = "0815-0001"  # the emulation numbers its cameras 0815-0000, 0815-0001 ...


def settings(**overrides: Any) -> CameraSettings:
    values: dict[str, Any] = {
        "driver": "genicam",
        "serial": SECOND_CAMERA,
        "width_px": 320,
        "height_px": 240,
        "bit_depth": 12,
        "exposure_us": 2000.0,
        "gain": 1.5,
        "grab_timeout_s": 2.0,
    }
    return CameraSettings(**{**values, **overrides})


async def test_grabs_frames_of_the_configured_format_roi_and_time() -> None:
    clock = ScaledClock()
    async with GenICamCamera(settings(offset_x_px=8, offset_y_px=4), clock) as camera:
        exposure = await camera.transport.call(lambda cam: cam.ExposureTime.Value)
        gain = await camera.transport.call(lambda cam: cam.Gain.Value)
        offsets = await camera.transport.call(lambda cam: (cam.OffsetX.Value, cam.OffsetY.Value))
        frames = []
        for _ in range(3):
            before = clock.now()
            frame = await camera.grab()
            after = clock.now()
            frames.append(frame)
            # software trigger: the run clock at the trigger plus the exposure, within the grab
            assert frame.timestamp_source == "trigger"
            assert before + 0.002 <= frame.timestamp_s <= after + 0.002
    assert exposure == pytest.approx(2000.0)
    assert gain == pytest.approx(1.5, abs=0.05)
    assert offsets == (8, 4)
    assert [f.sequence for f in frames] == [0, 1, 2]
    for frame in frames:
        assert frame.image.shape == (240, 320)
        assert frame.image.dtype == np.uint16 and frame.bit_depth == 12
        assert 0 < int(frame.image.max()) < 4096  # 12 significant bits in a 16-bit container
    assert frames[0].timestamp_s < frames[1].timestamp_s < frames[2].timestamp_s
    assert camera.link == LinkState.DISCONNECTED
    assert not [t for t in threading.enumerate() if t.name.startswith("genicam-camera")]


async def test_mono8_free_running_gives_the_newest_frame_stamped_on_receipt() -> None:
    async with GenICamCamera(settings(bit_depth=8, trigger="off"), ScaledClock()) as camera:
        frame = await camera.grab()
    assert frame.image.dtype == np.uint8 and frame.bit_depth == 8
    assert frame.timestamp_source == "host"  # the emulation has no clock to latch


async def test_a_missing_camera_is_one_line_naming_what_was_found() -> None:
    with pytest.raises(NotConnectedError) as caught:
        async with GenICamCamera(settings(serial="9999-0000"), ScaledClock()):
            pass
    message = str(caught.value)
    assert "\n" not in message
    assert "no GenICam camera with serial '9999-0000'" in message
    # a failed open leaves no worker thread behind (no __aexit__ follows it)
    assert not [t for t in threading.enumerate() if t.name.startswith("genicam-camera")]
    assert "0815-0000" in message and SECOND_CAMERA in message


async def test_a_roi_larger_than_the_sensor_is_refused_before_any_grab() -> None:
    camera = GenICamCamera(settings(width_px=4000, height_px=100, offset_x_px=200), ScaledClock())
    with pytest.raises(ProtocolError, match=r"ROI 4000x100 at \(200, 0\) does not fit"):
        async with camera:
            pass
    assert camera.link == LinkState.DISCONNECTED


def test_pixel_formats_the_camera_lacks_or_the_drivers_cannot_read_are_one_line() -> None:
    offered = ("Mono8", "Mono12p", "BayerRG8")
    assert choose_pixel_format("Mono8", offered, "camera") == "Mono8"
    with pytest.raises(ProtocolError, match=r"not offer pixel format Mono16 \(it offers Mono8\)"):
        choose_pixel_format("Mono16", offered, "camera")
    with pytest.raises(ProtocolError, match="unsupported pixel format Mono12p"):
        choose_pixel_format("Mono12p", offered, "camera")


def test_pixel_format_must_match_the_bit_depth() -> None:
    with pytest.raises(ValueError, match="Mono8 delivers 8-bit pixels but bit_depth is 16"):
        CameraSettings(pixel_format="Mono8", bit_depth=16)


def test_the_camera_clock_maps_ticks_to_the_run_clock() -> None:
    mapping = CameraClockMap(ticks_per_s=125e6)  # a GigE camera's 125 MHz counter
    mapping.sync(100.000, 5_000_000_000, 100.002)
    assert mapping.anchor_run_s == pytest.approx(100.001)
    assert mapping.uncertainty_s == pytest.approx(0.001)
    assert mapping.to_run_s(5_000_000_000 + 250_000_000) == pytest.approx(102.001)


async def test_a_grab_is_bounded_and_a_cancelled_one_blocks_neither_loop_nor_camera() -> None:
    # a hardware trigger that never comes: the grab must end by itself after grab_timeout_s
    # (1 s: long enough that the abandoned grab is surely still pending when checked)
    config = settings(trigger="hardware", trigger_source="Line1", grab_timeout_s=1.0)
    async with GenICamCamera(config, ScaledClock()) as camera:
        with pytest.raises(DeviceTimeoutError, match=r"no frame within 1 s"):
            await camera.grab()
        waiter = asyncio.create_task(camera.grab())
        await asyncio.sleep(0)  # the loop runs while the grab waits in its thread
        waiter.cancel()
        with pytest.raises(asyncio.CancelledError):
            await waiter
        assert camera.transport.grab_pending  # the thread goes on, bounded by pylon
        with pytest.raises(DeviceError, match="previous grab has not returned"):
            await camera.grab()
        pending = camera.transport._pending
        assert pending is not None
        with pytest.raises(DeviceTimeoutError):
            await pending
        assert not camera.transport.grab_pending
    assert camera.link == LinkState.DISCONNECTED  # closed behind the abandoned grab


async def test_unplug_then_replug_reconnects_with_backoff() -> None:
    camera = GenICamCamera(settings(grab_timeout_s=0.5), ScaledClock(), first_backoff_s=0.01)
    transport = camera.transport
    real_open = transport._open_blocking
    attempts: list[int] = []

    def still_unplugged_twice() -> None:
        attempts.append(len(attempts))
        if len(attempts) <= 2:
            raise NotConnectedError("camera", "no GenICam camera (found: none)")
        real_open()

    async with camera:
        first = await camera.grab()
        transport._open_blocking = still_unplugged_twice  # type: ignore[method-assign]
        # pull the plug: pylon detaches the device under the driver
        await transport.call(lambda cam: cam.DestroyDevice())
        with pytest.raises(NotConnectedError, match="was removed"):
            await camera.grab()
        assert camera.link == LinkState.RECONNECTING
        task = transport._reconnect_task
        assert task is not None
        # no await since the loss: still reconnecting, so refused at once
        with pytest.raises(NotConnectedError, match=r"reconnecting \(attempt 0\)"):
            await camera.grab()
        await asyncio.wait_for(asyncio.shield(task), timeout=10)
        assert camera.link == LinkState.CONNECTED
        assert transport.reconnect_attempts == 3 and len(attempts) == 3
        assert transport.last_error is not None and "found: none" in transport.last_error
        again = await camera.grab()
    assert again.sequence == first.sequence + 1
    assert again.image.shape == first.image.shape
