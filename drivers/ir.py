"""Infrared readers of the link temperatures (thesis 3.2.2): OpenCV radiometric Y16 and replay.

A reading is the mean and max temperature of each configured region of interest (rectangles of
the thermal image, each optionally tied to a model node) plus the thermal frame in degC.
Radiometric cameras such as FLIR Lepton boards stream 16-bit counts; a linear calibration
``T = scale * counts + offset`` turns them into degC (default: centi-kelvin).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import cv2
import numpy as np
from numpy.typing import NDArray

from config.settings import IrRegion, IrSettings
from drivers.base import IrReading, RegionTemperature
from drivers.camera import VideoSource
from drivers.clock import Clock
from drivers.errors import DeviceError, NotConnectedError, ProtocolError
from drivers.replay import ReplayFolder

logger = logging.getLogger(__name__)

DEVICE = "ir"
#: Thermal frames the replay reads: 16-bit radiometric images, or CSV matrices of degC.
RADIOMETRIC_SUFFIXES = (".png", ".tif", ".tiff")
CSV_SUFFIX = ".csv"


def region_temperatures(
    frame_c: NDArray[np.floating], regions: Sequence[IrRegion]
) -> dict[str, RegionTemperature]:
    """Mean and max temperature of each region; a region outside the frame is an error."""
    height, width = frame_c.shape
    result: dict[str, RegionTemperature] = {}
    for region in regions:
        if region.x + region.width > width or region.y + region.height > height:
            raise DeviceError(
                DEVICE,
                f"region {region.name!r} ({region.x},{region.y} {region.width}x{region.height}) "
                f"lies outside the {width}x{height} thermal frame",
            )
        patch = frame_c[region.y : region.y + region.height, region.x : region.x + region.width]
        result[region.name] = RegionTemperature(
            name=region.name,
            mean_c=float(patch.mean()),
            max_c=float(patch.max()),
            node=region.node,
        )
    return result


def counts_to_celsius(
    counts: NDArray[Any], calibration: tuple[float, float]
) -> NDArray[np.float64]:
    """``T = scale * counts + offset`` (IrSettings.counts_to_celsius)."""
    scale, offset = calibration
    celsius: NDArray[np.float64] = counts.astype(np.float64) * scale + offset
    return celsius


def finite_thermal_frame(frame_c: NDArray[Any], source: str) -> NDArray[np.float64]:
    """A thermal frame in degC that can be used: 2-D and finite everywhere; else the frame is
    unreadable (ProtocolError), never averaged into a region's temperature."""
    if frame_c.ndim != 2:
        raise ProtocolError(DEVICE, f"{source}: thermal frame of shape {frame_c.shape}, not 2-D")
    if not np.all(np.isfinite(frame_c)):
        raise ProtocolError(DEVICE, f"{source}: temperatures must be finite")
    return np.asarray(frame_c, dtype=np.float64)


def _radiometric(image: NDArray[Any] | None, source: str) -> NDArray[np.uint16]:
    if image is None:
        raise ProtocolError(DEVICE, f"no thermal frame from {source}")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.dtype != np.uint16 or image.ndim != 2:
        raise ProtocolError(
            DEVICE,
            f"{source}: expected 16-bit single-channel radiometric counts, got "
            f"{image.dtype} {image.shape}",
        )
    return np.ascontiguousarray(image)


class OpenCvIrReader:
    """A radiometric Y16 stream through OpenCV (e.g. a FLIR Lepton on a PureThermal board)."""

    def __init__(self, settings: IrSettings, clock: Clock) -> None:
        self.settings = settings
        self.clock = clock
        self._source = VideoSource(settings.device, DEVICE, self._configure)
        self._sequence = 0
        self._lock = asyncio.Lock()  # one read at a time: sequence numbers follow the reads

    @staticmethod
    def _configure(capture: Any) -> None:
        # Raw 16-bit counts, not a colour-mapped preview.
        capture.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter.fourcc("Y", "1", "6", " "))
        capture.set(cv2.CAP_PROP_CONVERT_RGB, 0)

    async def __aenter__(self) -> Self:
        await self._source.open()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        await self._source.close()

    async def read(self) -> IrReading:
        async with self._lock:
            image = await self._source.read()
            counts = _radiometric(image, repr(self.settings.device))
            frame_c = counts_to_celsius(counts, self.settings.counts_to_celsius)
            reading = IrReading(
                regions=region_temperatures(frame_c, self.settings.regions),
                timestamp_s=self.clock.now(),
                sequence=self._sequence,
                frame_c=frame_c,
            )
            self._sequence += 1
        return reading


def load_thermal_frame(path: Path, calibration: tuple[float, float]) -> NDArray[np.float64]:
    """A recorded thermal frame in degC: a CSV matrix of degC, or a 16-bit image of counts."""
    if path.suffix.lower() == CSV_SUFFIX:
        try:
            frame = np.loadtxt(path, delimiter=",", dtype=np.float64, ndmin=2)
        except ValueError as err:
            raise ProtocolError(DEVICE, f"{path}: not a CSV matrix of numbers: {err}") from err
        return finite_thermal_frame(frame, str(path))
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return counts_to_celsius(_radiometric(image, str(path)), calibration)


class ReplayIrReader:
    """Thermal frames from a folder (16-bit PNG/TIFF counts or CSV degC), in natural order."""

    def __init__(self, settings: IrSettings, clock: Clock) -> None:
        if settings.replay_dir is None:
            raise NotConnectedError(DEVICE, "ir.replay_dir is not set")
        self.settings = settings
        self.folder = settings.replay_dir
        self.clock = clock
        self._replay = ReplayFolder(
            settings.replay_dir,
            (*RADIOMETRIC_SUFFIXES, CSV_SUFFIX),
            clock,
            period_s=settings.replay_period_s,
            loop=settings.replay_loop,
            device=DEVICE,
        )
        self._sequence = 0

    async def __aenter__(self) -> Self:
        await self._replay.open()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._replay.close()

    async def read(self) -> IrReading:
        path, stamp = self._replay.next()
        frame_c = await asyncio.to_thread(load_thermal_frame, path, self.settings.counts_to_celsius)
        reading = IrReading(
            regions=region_temperatures(frame_c, self.settings.regions),
            timestamp_s=stamp,
            sequence=self._sequence,
            frame_c=frame_c,
        )
        self._sequence += 1
        return reading
