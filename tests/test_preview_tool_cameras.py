"""The device preview of an arm's tool cameras (issue 28: it showed one black frame): every
camera gets a panel, reduced by the brightest pixel of each block so a marker a few pixels
wide on a 5 MP frame stays visible, captioned with its peak and whether it is dark."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass

import cv2
import numpy as np

from config import Settings
from daemon.run.devices_check import (
    TOOL_PANEL_WIDTH_PX,
    DeviceCheck,
    block_max,
    check_devices,
    preview_png,
    tool_caption,
)
from drivers.base import Frame, IrReading
from drivers.errors import DeviceError
from tests.fakes import FakeRobot, Gate

WIDTH, HEIGHT = 2448, 2048
MARKER_AT = (1201, 777)  # (x, y): a 3 x 3 marker


def frame(lit: bool) -> Frame:
    image = np.full((HEIGHT, WIDTH), 12, np.uint16)
    if lit:
        x, y = MARKER_AT
        image[y - 1 : y + 2, x - 1 : x + 2] = 4000
    return Frame(image, 12, 0.0, 0)


def test_a_small_marker_survives_the_reduction() -> None:
    reduced = block_max(frame(True).image, TOOL_PANEL_WIDTH_PX)
    scale = -(-WIDTH // TOOL_PANEL_WIDTH_PX)
    assert reduced.shape == (HEIGHT // scale, WIDTH // scale)
    x, y = MARKER_AT
    assert reduced[y // scale, x // scale] == 4000
    # averaging down to the ~270 px the dashboard's column gave it (what the browser did)
    # leaves a tenth of it: a black frame
    browser = cv2.resize(frame(True).image, (272, 227), interpolation=cv2.INTER_AREA)
    assert browser.max() < 0.15 * 4000


def test_every_tool_camera_is_a_panel_with_a_caption_that_says_dark() -> None:
    check = DeviceCheck(tool_frames=[(f"s0-arm-{k}", frame(k != 1)) for k in range(4)])
    image = cv2.imdecode(np.frombuffer(preview_png(check), np.uint8), cv2.IMREAD_COLOR)
    assert image is not None
    # three panels to a row, two rows; each panel at most TOOL_PANEL_WIDTH_PX wide
    assert image.shape[1] <= 3 * TOOL_PANEL_WIDTH_PX + 2 * 8
    assert image.shape[0] > 2 * (HEIGHT // -(-WIDTH // TOOL_PANEL_WIDTH_PX))
    assert tool_caption("s0-arm-1", frame(False)) == (
        "s0-arm-1: 2448 x 2048 px, peak 12 of 4095; dark: nothing in view"
    )
    assert tool_caption("s0-arm-0", frame(True)).endswith("peak 4000 of 4095")


@dataclass
class _Camera:
    lit: bool

    async def grab(self) -> Frame:
        if not self.lit:
            raise DeviceError("camera", "unplugged")
        return frame(True)


@dataclass
class _Model:
    name: str


class _Ir:
    async def read(self) -> IrReading:
        raise DeviceError("ir", "no reading")


def _poseless_robot() -> FakeRobot:
    """The suite's fake robot (it passes the Robot contract) whose pose read fails."""
    robot = FakeRobot()
    robot.pose_gate = gate = Gate()
    gate.open(DeviceError("robot", "no pose"))
    return robot


@dataclass
class _ArmDevices:
    cameras: tuple[_Camera, ...]
    camera_models: tuple[_Model, ...]
    camera: object = None
    ir: object = None
    robot: object = None


def test_every_tool_camera_is_checked_and_a_failing_one_is_named() -> None:
    devices = _ArmDevices(
        cameras=(_Camera(True), _Camera(False), _Camera(True)),
        camera_models=(_Model("a"), _Model("b"), _Model("c")),
        ir=_Ir(),
        robot=_poseless_robot(),
    )
    check = asyncio.run(check_devices(devices, Settings()))  # type: ignore[arg-type]
    assert [name for name, _ in check.tool_frames] == ["a", "c"]
    assert check.errors["b"] == "camera: unplugged"
    assert set(check.errors) == {"b", "ir", "robot"}  # the others checked all the same
    assert check.frame is None  # no spot camera on an arm
