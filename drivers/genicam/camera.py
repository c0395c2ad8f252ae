"""The spot camera over GenICam (``camera.driver = "genicam"``, and each of an arm's
``arm.camera_devices``): the settings' feature file, then pixel format, ROI, exposure and gain
applied after every open, frames from the transport of drivers/genicam/transport.py (its docstring:
threads, bounds, frame times, reconnection), each checked to be the ROI."""

from __future__ import annotations

import asyncio
from pathlib import Path
from types import TracebackType
from typing import Any, Self

from config.settings import CameraSettings
from drivers.base import Frame, LinkState
from drivers.clock import Clock
from drivers.errors import ProtocolError
from drivers.genicam.transport import (
    GenICamSelection,
    GenICamTransport,
    choose_pixel_format,
    has_node,
    load_feature_file,
    set_node,
)
from drivers.reconnect import RECONNECT_FIRST_BACKOFF_S


def configure_image(
    camera: Any,
    device: str,
    *,
    pixel_format: str,
    feature_file: Path | None = None,
    width_px: int | None = None,
    height_px: int | None = None,
    offset_x_px: int = 0,
    offset_y_px: int = 0,
    exposure_us: float | None = None,
    gain_db: float | None = None,
) -> None:
    """The feature file, then pixel format, ROI, exposure and gain (over the file's), on the
    worker thread after each open."""
    if feature_file is not None:
        load_feature_file(camera, feature_file, device)
    offered = tuple(camera.PixelFormat.Symbolics) if has_node(camera, "PixelFormat") else ()
    camera.PixelFormat.Value = choose_pixel_format(pixel_format, offered, device)
    if width_px is not None and height_px is not None:
        # offsets to 0 first: the size's maximum depends on them
        set_node(camera, "OffsetX", 0, device)
        set_node(camera, "OffsetY", 0, device)
        limit_w, limit_h = camera.Width.Max, camera.Height.Max
        if offset_x_px + width_px > limit_w or offset_y_px + height_px > limit_h:
            raise ProtocolError(
                device,
                f"the ROI {width_px}x{height_px} at ({offset_x_px}, {offset_y_px}) does not fit "
                f"the {limit_w}x{limit_h} sensor",
            )
        set_node(camera, "Width", width_px, device)
        set_node(camera, "Height", height_px, device)
        set_node(camera, "OffsetX", offset_x_px, device)
        set_node(camera, "OffsetY", offset_y_px, device)
    if exposure_us is not None:
        set_node(camera, "ExposureAuto", "Off", device)
        if not (
            set_node(camera, "ExposureTime", exposure_us, device)
            or set_node(camera, "ExposureTimeAbs", exposure_us, device)
        ):
            raise ProtocolError(device, "the camera has no writable ExposureTime")
    if gain_db is not None:
        set_node(camera, "GainAuto", "Off", device)
        if not set_node(camera, "Gain", gain_db, device):
            raise ProtocolError(device, "the camera has no writable Gain (dB)")


class GenICamCamera:
    """The spot camera over GenICam (``camera.driver = "genicam"``)."""

    def __init__(
        self,
        settings: CameraSettings,
        clock: Clock,
        *,
        first_backoff_s: float = RECONNECT_FIRST_BACKOFF_S,
    ) -> None:
        self.settings = settings
        self.clock = clock
        self.pixel_format = settings.pixel_format or f"Mono{settings.bit_depth}"
        self.transport = GenICamTransport(
            GenICamSelection(
                device="camera",
                serial=settings.serial,
                user_id=settings.user_id,
                grab_timeout_s=settings.grab_timeout_s,
                reconnect_max_backoff_s=settings.reconnect_max_backoff_s,
                trigger=settings.trigger,
                trigger_source=settings.trigger_source,
            ),
            clock,
            self._configure,
            first_backoff_s=first_backoff_s,
        )
        self._sequence = 0
        self._lock = asyncio.Lock()  # one grab at a time: sequence numbers follow the grabs
        self.last_grab_s = 0.0  # wall time of the last grab in the worker thread

    def _configure(self, camera: Any) -> None:
        settings = self.settings
        configure_image(
            camera,
            "camera",
            pixel_format=self.pixel_format,
            feature_file=settings.feature_file,
            width_px=settings.width_px,
            height_px=settings.height_px,
            offset_x_px=settings.offset_x_px,
            offset_y_px=settings.offset_y_px,
            exposure_us=settings.exposure_us,
            gain_db=settings.gain,
        )

    @property
    def link(self) -> LinkState:
        return self.transport.link

    async def __aenter__(self) -> Self:
        await self.transport.open()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        await self.transport.close()

    async def grab(self) -> Frame:
        async with self._lock:
            raw = await self.transport.grab()
            self.last_grab_s = raw.grab_s
            roi = (self.settings.height_px, self.settings.width_px)
            if raw.image.shape != roi:
                # a camera sends its ROI; pylon's emulation serves a smaller image file at
                # its own size (drivers/sim/camemu.py): pixels would no longer be where the
                # camera model puts them
                height, width = raw.image.shape[:2]
                raise ProtocolError(
                    "camera",
                    f"{self.transport.description} sent a {width}x{height} frame, its ROI is "
                    f"{roi[1]}x{roi[0]}",
                )
            frame = Frame(
                image=raw.image,
                bit_depth=self.settings.bit_depth,
                timestamp_s=raw.timestamp_s,
                sequence=self._sequence,
                timestamp_source=raw.timestamp_source,
            )
            self._sequence += 1
        return frame
