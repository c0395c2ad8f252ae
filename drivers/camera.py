"""Cameras that watch the laser spot (thesis 3.2.2): OpenCV VideoCapture and folder replay.

Both give 2-D grey frames (uint8 or uint16) stamped on the run clock. OpenCV calls block, so
they run in a worker thread (``asyncio.to_thread``), one at a time per camera.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import cv2
import numpy as np
from numpy.typing import NDArray

from config.settings import CameraSettings
from drivers.base import Frame
from drivers.clock import Clock
from drivers.errors import DeviceError, NotConnectedError, ProtocolError
from drivers.replay import ReplayFolder

logger = logging.getLogger(__name__)

DEVICE = "camera"
#: V4L2's manual exposure mode and exposure unit, as OpenCV's V4L2 backend passes them on.
V4L2_EXPOSURE_MANUAL = 1
V4L2_EXPOSURE_UNIT_US = 100.0
MS_PER_S = 1000.0
#: Image files the replay reads (16-bit PNG and TIFF keep their depth).
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".bmp", ".pgm", ".pnm", ".jpg", ".jpeg")


def to_grey(image: NDArray[Any], device: str = DEVICE) -> NDArray[np.integer]:
    """A 2-D uint8/uint16 frame from what OpenCV returns (grey, BGR or BGRA)."""
    if image.dtype not in (np.uint8, np.uint16):
        raise ProtocolError(device, f"unsupported pixel type {image.dtype}")
    if image.ndim == 3 and image.shape[2] in (1, 2):
        image = image[:, :, 0]  # grey, or the luma plane of raw YUYV (CONVERT_RGB off)
    elif image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        image = cv2.cvtColor(image, code)
    if image.ndim != 2:
        raise ProtocolError(device, f"unsupported frame shape {image.shape}")
    return np.ascontiguousarray(image)


def significant_bits(image: NDArray[np.integer], configured: int) -> int:
    """8 for 8-bit frames; the configured depth (12 or 16) for 16-bit containers, 16 when the
    settings say 8 but the device delivers 16-bit frames."""
    if image.dtype == np.uint8:
        return 8
    return configured if configured > 8 else 16


def open_video_capture(source: int | str, device: str) -> Any:
    """An opened ``cv2.VideoCapture``: a device index, a device path, a URL, or an image
    sequence pattern such as ``frames/img_%04d.png`` (read by OpenCV's image backend, which
    keeps 16-bit frames; the default backend would choose FFmpeg and cut them to 8 bits)."""
    if isinstance(source, str) and "%" in source:
        capture = cv2.VideoCapture(source, cv2.CAP_IMAGES)
    else:
        capture = cv2.VideoCapture(source)
    if not capture.isOpened():
        capture.release()
        raise NotConnectedError(device, f"cannot open video source {source!r}")
    return capture


class VideoSource:
    """An OpenCV VideoCapture whose blocking calls (open, read, release) run in a thread, so
    the event loop never waits on a device; ``configure`` sets what the device needs once open.
    Shared by the camera and the IR reader.

    A read blocked in OpenCV cannot be cancelled: when the caller gives up (the daemon's
    camera.grab_timeout_s), the thread goes on. Until it returns, ``read`` refuses to start a
    second one (DeviceError), which would pile threads onto a hung device, and ``close``
    leaves the capture to be released once the read has returned."""

    def __init__(self, source: int | str, device: str, configure: Callable[[Any], None]) -> None:
        self.source = source
        self.device = device
        self._configure = configure
        self._capture: Any = None
        self._pending: asyncio.Future[tuple[bool, Any]] | None = None  # the read in its thread
        self._backend_offset_s: float | None = None  # run clock - backend stamp
        # a file or image sequence's POS_MSEC is its position in the file, not a capture time
        self._is_file = isinstance(source, str) and ("%" in source or Path(source).is_file())

    def _open(self) -> Any:
        capture = open_video_capture(self.source, self.device)
        self._configure(capture)
        return capture

    async def open(self) -> None:
        self._capture = await asyncio.to_thread(self._open)

    @property
    def read_pending(self) -> bool:
        """A read's thread has not returned yet (its caller may have given up)."""
        return self._pending is not None and not self._pending.done()

    async def close(self) -> None:
        capture, self._capture = self._capture, None
        if capture is None:
            return
        if self._pending is not None and self.read_pending:
            # releasing under a read in another thread is a use-after-free in OpenCV
            logger.warning("%s: a read is still blocked: release once it returns", self.device)
            self._pending.add_done_callback(lambda _: _release_later(capture))
            return
        await asyncio.to_thread(capture.release)

    async def read(self) -> NDArray[Any]:
        capture = self._capture
        if capture is None:
            raise NotConnectedError(self.device, f"{self.device} is not open")
        if self.read_pending:
            raise DeviceError(
                self.device,
                f"the previous read from {self.source!r} has not returned (it timed out and "
                "cannot be cancelled): no second read is started",
            )
        pending = asyncio.get_running_loop().run_in_executor(None, capture.read)
        pending.add_done_callback(_retrieve)  # an abandoned read's error is not an error
        self._pending = pending
        ok, image = await asyncio.shield(pending)  # a timeout abandons the read, not the thread
        if not ok or image is None:
            raise DeviceError(self.device, f"no frame from {self.source!r}")
        image_array: NDArray[Any] = image
        return image_array

    async def read_stamped(self, clock: Clock) -> tuple[NDArray[Any], float, str]:
        """A frame and when it was taken on the run clock: from the backend's own stamp when
        it gives one (CAP_PROP_POS_MSEC; V4L2 reports the driver's buffer timestamp, taken
        at the end of the frame's capture), mapped to the run clock with the offset of the
        quickest delivery seen so far (so the backend's frame spacing is kept and no stamp
        lies after its receipt; the quickest delivery's own latency is unknown and taken as
        0); else the time the read returned ("host": late by the transfer)."""
        image = await self.read()
        received_s = clock.now()
        stamp_ms = float(self._capture.get(cv2.CAP_PROP_POS_MSEC)) if self._capture else 0.0
        if not (math.isfinite(stamp_ms) and stamp_ms > 0) or self._is_file:
            return image, received_s, "host"
        backend_s = stamp_ms / MS_PER_S
        if self._backend_offset_s is None or backend_s + self._backend_offset_s > received_s:
            # a backend stamp cannot lie after its own receipt: re-anchor when it would
            self._backend_offset_s = received_s - backend_s
        return image, backend_s + self._backend_offset_s, "backend"


def _release_later(capture: Any) -> None:
    """Release ``capture`` in a worker thread, from a callback on the event loop."""
    asyncio.get_running_loop().run_in_executor(None, capture.release).add_done_callback(_retrieve)


def _retrieve(future: asyncio.Future[Any]) -> None:
    """Mark an abandoned read's outcome as seen (asyncio logs unretrieved exceptions)."""
    if not future.cancelled():
        future.exception()


class OpenCvCamera:
    """A camera through OpenCV's VideoCapture: device index, device path, file or URL."""

    def __init__(self, settings: CameraSettings, clock: Clock) -> None:
        self.settings = settings
        self.clock = clock
        self._source = VideoSource(settings.device, DEVICE, self._configure)
        self._sequence = 0
        self._lock = asyncio.Lock()  # one grab at a time: sequence numbers follow the reads

    def _configure(self, capture: Any) -> None:
        capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.settings.width_px)
        capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.settings.height_px)
        if self.settings.bit_depth > 8:
            # Ask for the raw (16-bit) stream; backends that cannot keep their 8-bit frames,
            # and the frame's dtype then tells the truth.
            capture.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        if self.settings.exposure_us is not None:
            # V4L2 through OpenCV: manual exposure is auto-exposure mode 1 (V4L2_EXPOSURE_MANUAL)
            # and exposure_absolute counts 100 us; a backend that ignores either says so here.
            capture.set(cv2.CAP_PROP_AUTO_EXPOSURE, V4L2_EXPOSURE_MANUAL)
            units = self.settings.exposure_us / V4L2_EXPOSURE_UNIT_US
            if not capture.set(cv2.CAP_PROP_EXPOSURE, units):
                logger.warning("camera: the backend refused exposure %g us", units * 100)
        if self.settings.gain is not None and not capture.set(
            cv2.CAP_PROP_GAIN, self.settings.gain
        ):
            logger.warning("camera: the backend refused gain %g", self.settings.gain)

    async def __aenter__(self) -> Self:
        await self._source.open()
        logger.info("camera %r opened", self.settings.device)
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        await self._source.close()

    async def grab(self) -> Frame:
        async with self._lock:
            image, stamp_s, source = await self._source.read_stamped(self.clock)
            grey = to_grey(image)
            frame = Frame(
                image=grey,
                bit_depth=significant_bits(grey, self.settings.bit_depth),
                timestamp_s=stamp_s,
                sequence=self._sequence,
                timestamp_source=source,
            )
            self._sequence += 1
        return frame


class ReplayCamera:
    """Frames from a folder of images in natural order, on a time base (drivers/replay.py)."""

    def __init__(self, settings: CameraSettings, clock: Clock) -> None:
        if settings.replay_dir is None:
            raise NotConnectedError(DEVICE, "camera.replay_dir is not set")
        self.settings = settings
        self.folder = settings.replay_dir
        self.clock = clock
        self._replay = ReplayFolder(
            settings.replay_dir,
            IMAGE_SUFFIXES,
            clock,
            period_s=settings.replay_period_s,
            loop=settings.replay_loop,
            device=DEVICE,
        )
        self._sequence = 0

    async def __aenter__(self) -> Self:
        await self._replay.open()
        logger.info("replaying %d frames from %s", len(self._replay.files), self.folder)
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._replay.close()

    async def grab(self) -> Frame:
        path, stamp = self._replay.next()
        image = await asyncio.to_thread(cv2.imread, str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ProtocolError(DEVICE, f"cannot read image {path}")
        grey = to_grey(image)
        frame = Frame(
            image=grey,
            bit_depth=significant_bits(grey, self.settings.bit_depth),
            timestamp_s=stamp,
            sequence=self._sequence,
        )
        self._sequence += 1
        return frame
