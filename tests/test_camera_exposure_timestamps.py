"""The OpenCV camera's exposure and gain settings and its frame times (issue 18): the backend's
own stamp mapped to the run clock when it gives one, the receipt time ("host") otherwise."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from config.settings import CameraSettings
from drivers.camera import OpenCvCamera, VideoSource
from drivers.clock import VirtualClock


class FakeCapture:
    """Stands in for cv2.VideoCapture: records what is set, gives frames and POS_MSEC."""

    def __init__(self, stamps_ms: list[float]) -> None:
        self.settings: dict[int, float] = {}
        self.stamps_ms = stamps_ms
        self.position_ms = 0.0

    def set(self, prop: int, value: float) -> bool:
        self.settings[prop] = value
        return True

    def read(self) -> tuple[bool, Any]:
        self.position_ms = self.stamps_ms.pop(0)
        return True, np.full((4, 6), 7, np.uint8)

    def get(self, prop: int) -> float:
        assert prop == cv2.CAP_PROP_POS_MSEC
        return self.position_ms

    def release(self) -> None:
        pass


def test_exposure_and_gain_are_sent_to_the_backend() -> None:
    settings = CameraSettings(driver="opencv", exposure_us=5000.0, gain=3.0, bit_depth=8)
    camera = OpenCvCamera(settings, VirtualClock())
    capture = FakeCapture([])
    camera._configure(capture)
    assert capture.settings[cv2.CAP_PROP_AUTO_EXPOSURE] == 1  # V4L2 manual exposure
    assert capture.settings[cv2.CAP_PROP_EXPOSURE] == pytest.approx(50.0)  # 100 us units
    assert capture.settings[cv2.CAP_PROP_GAIN] == 3.0
    untouched = FakeCapture([])
    OpenCvCamera(CameraSettings(driver="opencv"), VirtualClock())._configure(untouched)
    assert cv2.CAP_PROP_EXPOSURE not in untouched.settings
    assert cv2.CAP_PROP_GAIN not in untouched.settings


async def test_backend_stamps_are_mapped_to_the_run_clock() -> None:
    clock = VirtualClock(100.0)
    source = VideoSource(0, "camera", lambda _: None)
    # backend stamps 1000, 1040, 1080 ms; received 5 ms, 12 ms and 2 ms after them
    source._capture = FakeCapture([1000.0, 1040.0, 1080.0])
    stamps = []
    for received_s in (100.005, 100.052, 100.082):
        clock._now = received_s
        _, stamp_s, origin = await source.read_stamped(clock)
        stamps.append(stamp_s)
        assert origin == "backend"
        assert stamp_s <= received_s + 1e-12  # never after the frame arrived
    # the backend's spacing (40 ms) on the run clock, the offset taken from the quickest
    # delivery seen so far: the first frame (5 ms) anchors the second; the third, delivered
    # quicker than the anchor allows (2 ms), re-anchors
    assert stamps[0] == pytest.approx(100.005)
    assert stamps[1] == pytest.approx(100.045)
    assert stamps[2] == pytest.approx(100.082)


async def test_without_a_backend_stamp_the_frame_time_is_the_receipt(tmp_path: Path) -> None:
    for index in range(2):
        cv2.imwrite(str(tmp_path / f"f_{index:02d}.png"), np.full((8, 8), 9 + index, np.uint8))
    settings = CameraSettings(
        driver="opencv", device=str(tmp_path / "f_%02d.png"), bit_depth=8, width_px=8, height_px=8
    )
    clock = VirtualClock(42.0)
    async with OpenCvCamera(settings, clock) as camera:
        frame = await camera.grab()
    # an image sequence's position is no capture time: said so, stamped when read
    assert frame.timestamp_source == "host"
    assert frame.timestamp_s == 42.0
