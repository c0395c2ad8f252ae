"""Camera and infrared drivers reading real image folders written with cv2.imwrite."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from config.settings import CameraSettings, IrRegion, IrSettings
from drivers.camera import OpenCvCamera, ReplayCamera, to_grey
from drivers.clock import VirtualClock
from drivers.errors import DeviceError, NotConnectedError, ProtocolError
from drivers.ir import OpenCvIrReader, ReplayIrReader, region_temperatures
from drivers.replay import natural_key

KELVIN = 273.15


def write_frames(folder: Path, names_values: dict[str, int], dtype: type = np.uint16) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, value in names_values.items():
        image = np.full((6, 8), value, dtype=dtype)
        image[1, 2] = value // 2  # not uniform: catches transposed or resized frames
        assert cv2.imwrite(str(folder / name), image)


def test_natural_order() -> None:
    names = ["frame10.png", "Frame2.png", "frame1.png", "frame02b.png", "a.png"]
    assert sorted(names, key=natural_key) == [
        "a.png",
        "frame1.png",
        "Frame2.png",
        "frame02b.png",
        "frame10.png",
    ]


async def test_replay_camera_reads_a_folder_in_natural_order(tmp_path: Path) -> None:
    write_frames(tmp_path, {"img10.png": 1000, "img2.png": 200, "img1.png": 100})
    (tmp_path / "notes.txt").write_text("not a frame")
    settings = CameraSettings(driver="replay", replay_dir=tmp_path)
    clock = VirtualClock()
    async with ReplayCamera(settings, clock) as camera:
        frames = []
        for t in (0.5, 1.0, 7.0):
            await clock.sleep_until(t)
            frames.append(await camera.grab())
        with pytest.raises(DeviceError, match="exhausted"):
            await camera.grab()
    assert [int(f.image[0, 0]) for f in frames] == [100, 200, 1000]
    assert [int(f.image[1, 2]) for f in frames] == [50, 100, 500]
    assert [f.sequence for f in frames] == [0, 1, 2]
    assert [f.timestamp_s for f in frames] == [0.5, 1.0, 7.0]
    assert all(f.image.dtype == np.uint16 and f.image.shape == (6, 8) for f in frames)
    assert all(f.bit_depth == 16 for f in frames)


async def test_replay_time_base_follows_the_run_clock(tmp_path: Path) -> None:
    write_frames(tmp_path, {f"f{i}.tif": 100 * (i + 1) for i in range(4)})
    settings = CameraSettings(
        driver="replay", replay_dir=tmp_path, replay_period_s=2.0, replay_loop=True
    )
    clock = VirtualClock(start_s=10.0)
    async with ReplayCamera(settings, clock) as camera:
        seen = []
        for t in (10.0, 11.9, 12.0, 15.5, 18.1):
            await clock.sleep_until(t)
            frame = await camera.grab()
            seen.append((int(frame.image[0, 0]), frame.timestamp_s))
    # frame i belongs to 10 + 2 i; after the fourth it starts again (loop)
    assert seen == [(100, 10.0), (100, 10.0), (200, 12.0), (300, 14.0), (100, 18.0)]


async def test_replay_camera_turns_colour_into_grey_and_reports_8_bits(tmp_path: Path) -> None:
    image = np.zeros((4, 4, 3), np.uint8)
    image[..., 1] = 200  # pure green: grey = 0.587 * 200
    cv2.imwrite(str(tmp_path / "c.png"), image)
    async with ReplayCamera(CameraSettings(replay_dir=tmp_path), VirtualClock()) as camera:
        frame = await camera.grab()
    assert frame.bit_depth == 8 and frame.image.shape == (4, 4)
    assert int(frame.image[0, 0]) == round(0.587 * 200)


async def test_replay_of_a_missing_or_empty_folder(tmp_path: Path) -> None:
    with pytest.raises(NotConnectedError):
        async with ReplayCamera(CameraSettings(replay_dir=tmp_path / "none"), VirtualClock()):
            pass
    with pytest.raises(NotConnectedError, match="no"):
        async with ReplayCamera(CameraSettings(replay_dir=tmp_path), VirtualClock()):
            pass
    (tmp_path / "broken.png").write_bytes(b"not a png")
    async with ReplayCamera(CameraSettings(replay_dir=tmp_path), VirtualClock()) as camera:
        with pytest.raises(ProtocolError):
            await camera.grab()


async def test_opencv_camera_reads_an_image_sequence(tmp_path: Path) -> None:
    write_frames(tmp_path, {f"seq_{i:02d}.png": 30000 + i for i in range(3)})
    settings = CameraSettings(driver="opencv", device=str(tmp_path / "seq_%02d.png"))
    clock = VirtualClock()
    async with OpenCvCamera(settings, clock) as camera:
        frames = [await camera.grab() for _ in range(3)]
        with pytest.raises(DeviceError, match="no frame"):
            await camera.grab()
    assert [int(f.image[0, 0]) for f in frames] == [30000, 30001, 30002]
    assert all(f.image.dtype == np.uint16 and f.bit_depth == 16 for f in frames)
    with pytest.raises(NotConnectedError):
        async with OpenCvCamera(CameraSettings(device=str(tmp_path / "missing_%02d.png")), clock):
            pass


REGIONS = (
    IrRegion(name="shaft", x=1, y=1, width=2, height=2, node="2"),
    IrRegion(name="all", x=0, y=0, width=8, height=6),
)


def test_region_temperatures_are_mean_and_max() -> None:
    frame = np.arange(48, dtype=np.float64).reshape(6, 8)
    regions = region_temperatures(frame, REGIONS)
    assert regions["shaft"].mean_c == pytest.approx((9 + 10 + 17 + 18) / 4)
    assert regions["shaft"].max_c == 18 and regions["shaft"].node == "2"
    assert regions["all"].mean_c == pytest.approx(23.5) and regions["all"].max_c == 47
    outside = IrRegion(name="off", x=7, y=0, width=2, height=1)
    with pytest.raises(DeviceError, match="outside"):
        region_temperatures(frame, (outside,))


def centi_kelvin(temperature_c: np.ndarray) -> np.ndarray:
    return np.round((temperature_c + KELVIN) * 100).astype(np.uint16)


async def test_ir_replay_of_radiometric_images_and_csv(tmp_path: Path) -> None:
    hot = np.full((6, 8), 22.0)
    hot[1:3, 1:3] = [[30.0, 31.0], [32.0, 36.5]]
    cv2.imwrite(str(tmp_path / "t1.png"), centi_kelvin(hot))
    cv2.imwrite(str(tmp_path / "t2.tiff"), centi_kelvin(hot + 1.0))
    np.savetxt(tmp_path / "t10.csv", hot + 2.0, delimiter=",")
    settings = IrSettings(driver="replay", replay_dir=tmp_path, regions=REGIONS)
    async with ReplayIrReader(settings, VirtualClock()) as reader:
        readings = [await reader.read() for _ in range(3)]
    for extra, reading in zip((0.0, 1.0, 2.0), readings, strict=True):
        shaft = reading.regions["shaft"]
        assert shaft.mean_c == pytest.approx(32.375 + extra, abs=0.01)
        assert shaft.max_c == pytest.approx(36.5 + extra, abs=0.01)
        assert reading.frame_c is not None and reading.frame_c.shape == (6, 8)
    assert [r.sequence for r in readings] == [0, 1, 2]


async def test_ir_replay_rejects_8_bit_images_and_bad_csv(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((6, 8), np.uint8))
    (tmp_path / "b.csv").write_text("1,2\n3,oops\n")
    async with ReplayIrReader(IrSettings(replay_dir=tmp_path), VirtualClock()) as reader:
        with pytest.raises(ProtocolError, match="16-bit"):
            await reader.read()
        with pytest.raises(ProtocolError, match="CSV"):
            await reader.read()


async def test_opencv_ir_reader_calibrates_y16_counts(tmp_path: Path) -> None:
    frame_c = np.full((6, 8), 25.0)
    frame_c[1, 1] = 40.0
    cv2.imwrite(str(tmp_path / "y16_00.png"), centi_kelvin(frame_c))
    settings = IrSettings(driver="opencv", device=str(tmp_path / "y16_%02d.png"), regions=REGIONS)
    async with OpenCvIrReader(settings, VirtualClock()) as reader:
        reading = await reader.read()
    assert reading.regions["shaft"].max_c == pytest.approx(40.0, abs=0.006)
    assert reading.regions["all"].mean_c == pytest.approx(25.0 + 15.0 / 48, abs=0.006)


def test_raw_yuyv_keeps_its_luma_plane() -> None:
    yuyv = np.zeros((2, 3, 2), np.uint8)
    yuyv[..., 0] = [[10, 20, 30], [40, 50, 60]]  # Y
    yuyv[..., 1] = 128  # U/V
    assert to_grey(yuyv).tolist() == [[10, 20, 30], [40, 50, 60]]
    with pytest.raises(ProtocolError):
        to_grey(np.zeros((2, 2), np.float32))
