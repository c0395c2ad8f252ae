"""GenICam cameras (GigE Vision, USB3 Vision) through pypylon: the transport under the spot
camera (drivers/genicam/camera.py) and the radiometric IR reader (drivers/genicam/radiometric.py).

pypylon is the optional extra ``genicam`` (``pip install 'thermocomp[genicam]'``); it needs no
vendor SDK, reaches every GigE Vision / USB3 Vision camera through pylon's transport layers,
and its camera emulation (``PYLON_CAMEMU=N``: N emulated cameras, Mono8..Mono16, headless) is
what the test suite drives.

- Blocking: every pylon call runs on the device's OWN single worker thread (pylon objects are
  used from one thread; the event loop never waits on one). A grab is bounded by the wait the
  settings allow (``grab_timeout_s``) inside pylon itself, so a cancelled grab's thread returns
  by then; until it has, the next grab is refused rather than queued behind it.
- Frame time (Frame.timestamp_s: when the exposure ENDED, on the run clock): from the camera's
  own clock when it stamps its frames (GigE ``GevTimestamp*``, SFNC ``Timestamp*``: the stamp is
  the frame start, mapped to the run clock by latching the camera's counter between two reads
  of the run clock, re-latched every CLOCK_RESYNC_S), plus the exposure time; else, with a
  software trigger, the run clock just before the trigger plus the exposure; else the dequeue
  time, which is late by the readout and transfer. ``Frame.timestamp_source`` says which.
- Unplug: a failed grab on a removed device drops it (state RECONNECTING, the error kept) and
  reconnects in the background (drivers/reconnect.py, as the robot links), first after
  RECONNECT_FIRST_BACKOFF_S, doubling up to ``reconnect_max_backoff_s``; grabs meanwhile fail
  at once with NotConnectedError.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.base import LinkState
from drivers.clock import Clock
from drivers.errors import DeviceError, DeviceTimeoutError, NotConnectedError, ProtocolError
from drivers.genicam.nodes import (
    INSTALL_HINT,
    MONO_FORMATS,
    choose_pixel_format,
    find_node,
    has_node,
    load_feature_file,
    node_value,
    pylon_module,
    set_node,
)
from drivers.reconnect import RECONNECT_FIRST_BACKOFF_S, Reconnector

# pylon's module and node helpers are drivers/genicam/nodes.py; the drivers import them here
# with the transport
__all__ = [
    "CLOCK_RESYNC_S",
    "INSTALL_HINT",
    "MONO_FORMATS",
    "CameraClockMap",
    "GenICamSelection",
    "GenICamTransport",
    "RawImage",
    "choose_pixel_format",
    "has_node",
    "load_feature_file",
    "node_value",
    "pylon_module",
    "set_node",
]

logger = logging.getLogger(__name__)

#: Re-latch the camera's counter against the run clock this often (s): two crystals drift
#: apart by tens of ppm, i.e. under 1 ms in this time.
CLOCK_RESYNC_S = 30.0
#: SFNC's Timestamp counts nanoseconds when the camera names no tick frequency.
SFNC_TICKS_PER_S = 1e9
MS_PER_S = 1000.0
US_PER_S = 1e6


@dataclass
class CameraClockMap:
    """The camera's tick counter on the run clock: a latch read between two run-clock reads
    gives the pair (run time, ticks) that anchors the mapping; ticks per second from the
    camera (GevTimestampTickFrequency) or SFNC's nanoseconds."""

    ticks_per_s: float
    anchor_run_s: float = 0.0
    anchor_ticks: int = 0
    uncertainty_s: float = float("inf")  # half the time the latch took

    def sync(self, run_before_s: float, ticks: int, run_after_s: float) -> None:
        self.anchor_run_s = (run_before_s + run_after_s) / 2.0
        self.anchor_ticks = ticks
        self.uncertainty_s = (run_after_s - run_before_s) / 2.0

    def to_run_s(self, ticks: int) -> float:
        return self.anchor_run_s + (ticks - self.anchor_ticks) / self.ticks_per_s


@dataclass(frozen=True, slots=True)
class GenICamSelection:
    """Which camera, how to grab: the part of the settings the transport needs."""

    device: str  # "camera" or "ir": the error messages' device name
    serial: str | None
    user_id: str | None
    grab_timeout_s: float
    reconnect_max_backoff_s: float
    trigger: str = "software"  # software | hardware | off
    trigger_source: str = "Line1"


@dataclass(frozen=True, slots=True)
class RawImage:
    """One grabbed image and when its exposure ended, on the run clock."""

    image: NDArray[np.integer]
    timestamp_s: float
    timestamp_source: str  # camera | trigger | host
    grab_s: float  # wall time the grab took in the worker thread


class GenICamTransport:
    """One GenICam camera: open, configure, grab, close and reconnect, all on its own thread.

    ``configure(camera)`` runs on that thread after every open (first and reconnections) with
    the pylon InstantCamera, before grabbing starts; ``exposure_s(camera)`` gives the exposure
    time the frame times add."""

    def __init__(
        self,
        selection: GenICamSelection,
        clock: Clock,
        configure: Callable[[Any], None],
        *,
        first_backoff_s: float = RECONNECT_FIRST_BACKOFF_S,
    ) -> None:
        self.selection = selection
        self.device = selection.device
        self.clock = clock
        self._configure = configure
        self.first_backoff_s = first_backoff_s
        self._executor: concurrent.futures.ThreadPoolExecutor | None = None
        self._camera: Any = None
        self._pending: asyncio.Future[RawImage] | None = None
        self._clock_map: CameraClockMap | None = None
        self._exposure_s = 0.0
        self.link = LinkState.DISCONNECTED
        self.last_error: str | None = None
        # drivers/reconnect.py: close what is left, wait one back-off (a camera just pulled is
        # not back at once), then open again until it works
        self._reconnector = Reconnector(
            self.device,
            self._reopen,
            first_backoff_s=lambda: self.first_backoff_s,
            max_backoff_s=lambda: self.selection.reconnect_max_backoff_s,
            wait_first=True,
            before=lambda: self._run(self._close_blocking),
            on_failure=self._note_failure,
            on_fatal=self._reconnection_failed,
            task_name=f"genicam-{self.device}-reconnect",
        )
        self.description = ""  # model and serial of the opened camera

    # --- the worker thread's side --------------------------------------------------------

    def _select(self, pylon: Any) -> Any:
        factory = pylon.TlFactory.GetInstance()
        found = list(factory.EnumerateDevices())
        wanted = self.selection
        for info in found:
            if wanted.serial is not None and info.GetSerialNumber() != wanted.serial:
                continue
            if wanted.user_id is not None and info.GetUserDefinedName() != wanted.user_id:
                continue
            return factory.CreateDevice(info)
        listed = ", ".join(f"{i.GetModelName()} {i.GetSerialNumber()}" for i in found) or "none"
        criteria = [
            f"{key} {value!r}"
            for key, value in (("serial", wanted.serial), ("user id", wanted.user_id))
            if value is not None
        ]
        raise NotConnectedError(
            self.device,
            f"no GenICam camera{' with ' + ' and '.join(criteria) if criteria else ''} "
            f"(found: {listed})",
        )

    def _open_blocking(self) -> None:
        """Open and configure the camera; every failure a DeviceError of one line."""
        try:
            self._open_camera()
        except DeviceError:
            raise
        except Exception as err:  # pylon's own exceptions (enumeration, node access)
            first_line = (str(err).splitlines() or [""])[0]
            raise DeviceError(
                self.device,
                f"cannot open {self.description or 'the GenICam camera'}: "
                f"{type(err).__name__}: {first_line}",
            ) from err

    def _open_camera(self) -> None:
        pylon = pylon_module()
        camera = pylon.InstantCamera(self._select(pylon))
        info = camera.GetDeviceInfo()
        self.description = f"{info.GetModelName()} {info.GetSerialNumber()}"
        try:
            camera.Open()
        except Exception as err:  # pylon's RuntimeException: in use elsewhere, unreachable
            camera.DestroyDevice()
            raise DeviceError(
                self.device,
                f"cannot open {self.description}: busy (opened by another program) or "
                f"unreachable: {err}",
            ) from err
        try:
            self._configure(camera)
            self._set_trigger(camera)
            self._exposure_s = _exposure_s(camera)
            self._clock_map = self._latch_clock(camera, None)
            strategy = (
                pylon.GrabStrategy_LatestImageOnly
                if self.selection.trigger == "off"
                else pylon.GrabStrategy_OneByOne
            )
            camera.StartGrabbing(strategy)
        except BaseException:
            camera.Close()
            camera.DestroyDevice()
            raise
        self._camera = camera

    def _set_trigger(self, camera: Any) -> None:
        mode = self.selection.trigger
        set_node(camera, "TriggerSelector", "FrameStart", self.device)
        if mode == "off":
            set_node(camera, "TriggerMode", "Off", self.device)
            return
        source = "Software" if mode == "software" else self.selection.trigger_source
        if not (
            set_node(camera, "TriggerMode", "On", self.device)
            and set_node(camera, "TriggerSource", source, self.device)
        ):
            raise ProtocolError(
                self.device, f'the camera has no {source} frame trigger: set trigger = "off"'
            )

    def _latch_clock(self, camera: Any, current: CameraClockMap | None) -> CameraClockMap | None:
        """Anchor the camera's counter on the run clock, if the camera has one to latch."""
        for latch, value, frequency in (
            ("GevTimestampControlLatch", "GevTimestampValue", "GevTimestampTickFrequency"),
            ("TimestampLatch", "TimestampLatchValue", None),
        ):
            if find_node(camera, latch) is None or find_node(camera, value) is None:
                continue
            ticks_per_s = (
                float(node_value(camera, frequency) or 0.0) if frequency else SFNC_TICKS_PER_S
            )
            if ticks_per_s <= 0:
                continue
            before = self.clock.now()
            getattr(camera, latch).Execute()
            ticks = int(getattr(camera, value).Value)
            after = self.clock.now()
            mapping = current or CameraClockMap(ticks_per_s)
            mapping.sync(before, ticks, after)
            return mapping
        return None

    def _grab_blocking(self) -> RawImage:
        camera = self._camera
        if camera is None:
            raise NotConnectedError(self.device, f"{self.device} is not open")
        try:
            return self._grab_from(camera)
        except DeviceError:
            raise
        except Exception as err:  # pylon's own exceptions (RuntimeException, ...)
            raise self._failure(camera, f"{type(err).__name__}: {err}") from err

    def _grab_from(self, camera: Any) -> RawImage:
        pylon = pylon_module()
        started = time.perf_counter()
        timeout_ms = max(1, int(self.selection.grab_timeout_s * MS_PER_S))
        triggered_s: float | None = None
        if self.selection.trigger == "software":
            if not camera.WaitForFrameTriggerReady(timeout_ms, pylon.TimeoutHandling_Return):
                raise self._failure(camera, "the camera was not ready for a trigger")
            triggered_s = self.clock.now()
            camera.ExecuteSoftwareTrigger()
        result = camera.RetrieveResult(timeout_ms, pylon.TimeoutHandling_Return)
        dequeued_s = self.clock.now()
        if result is None or not result.IsValid():
            raise self._failure(
                camera, f"no frame within {self.selection.grab_timeout_s:g} s", timeout=True
            )
        try:
            if not result.GrabSucceeded():
                raise self._failure(
                    camera,
                    f"grab failed: {result.GetErrorDescription()} (0x{result.GetErrorCode():x})",
                )
            image = np.array(result.GetArray(), copy=True)
            ticks = int(result.GetTimeStamp())
        finally:
            result.Release()
        stamp_s, source = dequeued_s, "host"
        if self._clock_map is not None and ticks > 0:
            if dequeued_s - self._clock_map.anchor_run_s > CLOCK_RESYNC_S:
                self._latch_clock(camera, self._clock_map)
            stamp_s, source = self._clock_map.to_run_s(ticks) + self._exposure_s, "camera"
        elif triggered_s is not None:
            stamp_s, source = triggered_s + self._exposure_s, "trigger"
        if image.ndim != 2 or image.dtype not in (np.uint8, np.uint16):
            raise ProtocolError(
                self.device, f"unsupported frame {image.dtype} {image.shape}: not unpacked mono"
            )
        return RawImage(image, stamp_s, source, time.perf_counter() - started)

    def _failure(self, camera: Any, message: str, *, timeout: bool = False) -> DeviceError:
        message = message.splitlines()[0] if message else "unknown failure"
        if not camera.IsPylonDeviceAttached() or camera.IsCameraDeviceRemoved():
            return _Unplugged(self.device, f"{self.description} was removed: {message}")
        if timeout:
            return DeviceTimeoutError(self.device, message)
        return DeviceError(self.device, message)

    def _close_blocking(self) -> None:
        camera, self._camera = self._camera, None
        if camera is None:
            return
        with contextlib.suppress(Exception):  # a removed device fails these: it is gone anyway
            camera.StopGrabbing()
            camera.Close()
        camera.DestroyDevice()

    def _run(self, call: Callable[[], Any]) -> asyncio.Future[Any]:
        if self._executor is None:
            self._executor = concurrent.futures.ThreadPoolExecutor(
                max_workers=1, thread_name_prefix=f"genicam-{self.device}"
            )
        return asyncio.get_running_loop().run_in_executor(self._executor, call)

    def call(self, call: Callable[[Any], Any]) -> asyncio.Future[Any]:
        """Run ``call(camera)`` on the worker thread (for reads of camera registers)."""
        return self._run(lambda: call(self._camera))

    # --- the event loop's side -----------------------------------------------------------

    async def open(self) -> None:
        self.link = LinkState.CONNECTING
        try:
            await self._run(self._open_blocking)
        except DeviceError as err:
            self.link, self.last_error = LinkState.DISCONNECTED, str(err)
            await self.close()  # no __aexit__ follows a failed __aenter__: end the thread
            raise
        self.link = LinkState.CONNECTED
        logger.info(
            "%s: GenICam camera %s open (trigger %s, frame time from %s)",
            self.device,
            self.description,
            self.selection.trigger,
            "the camera's clock" if self._clock_map else "the run clock",
        )

    @property
    def reconnect_attempts(self) -> int:
        return self._reconnector.attempts

    @property
    def _reconnect_task(self) -> asyncio.Task[None] | None:
        return self._reconnector.task

    async def close(self) -> None:
        await self._reconnector.cancel()
        self.link = LinkState.DISCONNECTED
        executor, self._executor = self._executor, None
        if executor is None:
            return
        # queued behind a pending grab, which pylon ends within grab_timeout_s
        await asyncio.get_running_loop().run_in_executor(executor, self._close_blocking)
        await asyncio.to_thread(executor.shutdown, wait=True)  # idle now: ends at once

    @property
    def grab_pending(self) -> bool:
        return self._pending is not None and not self._pending.done()

    async def grab(self) -> RawImage:
        if self.link == LinkState.RECONNECTING:
            raise NotConnectedError(
                self.device,
                f"reconnecting (attempt {self.reconnect_attempts}) after: {self.last_error}",
            )
        if self.link != LinkState.CONNECTED:
            raise NotConnectedError(self.device, f"{self.device} is not open")
        if self.grab_pending:
            raise DeviceError(
                self.device,
                "the previous grab has not returned yet (it was cancelled): no second one",
            )
        pending: asyncio.Future[RawImage] = self._run(self._grab_blocking)
        pending.add_done_callback(_retrieve)
        self._pending = pending
        try:
            return await asyncio.shield(pending)  # cancelling abandons the wait, not the thread
        except _Unplugged as err:
            self._lost(str(err))
            raise NotConnectedError(self.device, err.message) from err

    def _lost(self, error: str) -> None:
        self.last_error = error
        logger.warning("%s: link lost (%s); reconnecting", self.device, error)
        self.link = LinkState.RECONNECTING
        self._reconnector.start()

    def _note_failure(self, error: DeviceError) -> None:
        self.last_error = str(error)

    def _reconnection_failed(self, error: BaseException) -> None:
        """An unexpected error ended the reconnection (logged with its traceback): failed,
        not reconnecting forever (issue 26)."""
        self.last_error = f"the reconnection failed: {error!r}"
        self.link = LinkState.FAULT

    async def _reopen(self) -> None:
        await self._run(self._open_blocking)
        self.link = LinkState.CONNECTED
        logger.info("%s: %s reconnected", self.device, self.description)


class _Unplugged(DeviceError):
    """The camera was removed under a grab (internal: surfaces as NotConnectedError)."""

    kind = "not-connected"


def _exposure_s(camera: Any) -> float:
    """The exposure time the camera uses now (s): SFNC ExposureTime, or Basler GigE's
    ExposureTimeAbs, both in microseconds; 0 when it names none."""
    for name in ("ExposureTime", "ExposureTimeAbs"):
        value = node_value(camera, name)
        if value is not None:
            return float(value) / US_PER_S
    return 0.0


def _retrieve(future: asyncio.Future[Any]) -> None:
    """Mark an abandoned grab's outcome as seen (asyncio logs unretrieved exceptions)."""
    if not future.cancelled():
        future.exception()
