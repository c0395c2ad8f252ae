"""From the daemon's events to the WebSocket hub and the metrics.

One task per application reads the daemon's event subscription and hands each event on:
steps feed the metrics and the ``steps`` topic, errors the error counter and ``errors``, state
changes ``state``. Frames (the daemon's ``frame`` events, the image in memory) become small
8-bit PNG thumbnails, made in a worker thread only when a client subscribed to ``frames`` and
at most every ``api.ws_frame_interval_s``.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import logging
import math
import time
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from api.deps import ApiContext
from daemon.service import Daemon

logger = logging.getLogger(__name__)

#: Events the relay may have pending; it only appends to queues, so it never falls behind
#: in practice, and if it did the daemon drops the oldest (it never waits for the relay).
RELAY_QUEUE_EVENTS = 4096
THUMBNAIL_MAX_WIDTH_PX = 240


def thumbnail(
    image: NDArray[np.integer], max_width_px: int = THUMBNAIL_MAX_WIDTH_PX
) -> dict[str, Any]:
    """A small 8-bit PNG of ``image``: each thumbnail pixel is the brightest of a ``scale`` x
    ``scale`` block (so a laser spot a few pixels wide survives the reduction), stretched
    between the thumbnail's minimum and maximum so a faint spot stays visible. Thumbnail pixel
    (r, c) covers frame rows r*scale .. (r+1)*scale-1 and the same columns; a frame point x
    lies at thumbnail coordinate (x + 0.5) / scale (pixel centres at integers, DESIGN.md)."""
    frame = np.asarray(image)
    scale = max(1, math.ceil(frame.shape[1] / max_width_px))
    rows, cols = frame.shape[0] // scale, frame.shape[1] // scale
    blocks = frame[: rows * scale, : cols * scale].reshape(rows, scale, cols, scale)
    small = blocks.max(axis=(1, 3)).astype(np.float32)
    low, high = float(small.min()), float(small.max())
    span = high - low if high > low else 1.0
    eight_bit = np.clip(np.rint((small - low) * (255.0 / span)), 0, 255).astype(np.uint8)
    ok, png = cv2.imencode(".png", eight_bit)
    if not ok:
        raise ValueError("PNG encoding failed")
    return {
        "scale": scale,
        "width": int(eight_bit.shape[1]),
        "height": int(eight_bit.shape[0]),
        "png_base64": base64.b64encode(png.tobytes()).decode("ascii"),
    }


#: Frame pixels each side of the full-resolution crop sent with a thumbnail (issue 21: the
#: dashboard's zoom around the spot, sharper than a crop of the 1:4 thumbnail).
CROP_FRAME_PX = 48


def spot_crop(image: NDArray[np.integer], centre_px: tuple[float, float]) -> dict[str, Any]:
    """The ``CROP_FRAME_PX`` square of ``image`` around the spot at full resolution, stretched
    between its own minimum and maximum (auto-contrast), as a PNG; ``crop_x0_px`` /
    ``crop_y0_px`` place it in the frame and ``crop_low``/``crop_high`` are the stretch in
    counts."""
    frame = np.asarray(image)
    size = min(CROP_FRAME_PX, frame.shape[0], frame.shape[1])

    def origin(centre: float, extent: int) -> int:
        return int(min(max(round(centre - size / 2), 0), extent - size))

    x0, y0 = origin(centre_px[0], frame.shape[1]), origin(centre_px[1], frame.shape[0])
    crop = frame[y0 : y0 + size, x0 : x0 + size].astype(np.float32)
    low, high = float(crop.min()), float(crop.max())
    span = high - low if high > low else 1.0
    eight_bit = np.clip(np.rint((crop - low) * (255.0 / span)), 0, 255).astype(np.uint8)
    ok, png = cv2.imencode(".png", eight_bit)
    if not ok:
        raise ValueError("PNG encoding failed")
    return {
        "crop_png_base64": base64.b64encode(png.tobytes()).decode("ascii"),
        "crop_x0_px": x0,
        "crop_y0_px": y0,
        "crop_size_px": size,
        "crop_low": low,
        "crop_high": high,
    }


def frame_pictures(
    image: NDArray[np.integer], centre_px: tuple[float, float] | None
) -> dict[str, Any]:
    """The thumbnail, and the spot's crop when the centroid is known."""
    pictures = thumbnail(image)
    if centre_px is not None:
        pictures.update(spot_crop(image, centre_px))
    return pictures


class Relay:
    """Runs :meth:`run` as a task for the application's lifetime."""

    def __init__(self, daemon: Daemon, context: ApiContext) -> None:
        self._daemon = daemon
        self._context = context
        # per camera (None: the two-link bench's one camera; an arm's tool cameras by name)
        self._last_frame_s: dict[str | None, float] = {}
        self._thumbnail_tasks: dict[str | None, asyncio.Task[None]] = {}
        self._overruns_seen: tuple[int, int] = (-1, 0)  # (run id, scheduler overruns)

    async def run(self) -> None:
        with self._daemon.subscribe(maxsize=RELAY_QUEUE_EVENTS) as subscription:
            try:
                while True:
                    event = await subscription.get()
                    self._context.event_count += 1
                    self.handle(event.kind, event.data)
            finally:
                for task in self._thumbnail_tasks.values():
                    task.cancel()
                    with contextlib.suppress(asyncio.CancelledError):
                        await task

    def handle(self, kind: str, data: dict[str, Any]) -> None:
        context = self._context
        hub, metrics = context.hub, context.metrics
        if kind == "step":
            metrics.observe_step(data, self._new_overruns())
            hub.publish("steps", data)
        elif kind == "state":
            hub.publish("state", data)
        elif kind == "error":
            metrics.observe_error(data)
            hub.publish("errors", data)
        elif kind == "frame":
            self._frame(data)

    def _new_overruns(self) -> int:
        run = self._daemon.run
        if run is None:
            return 0
        last_run, last_count = self._overruns_seen
        previous = last_count if last_run == run.id else 0
        self._overruns_seen = (run.id, run.overruns)
        return max(run.overruns - previous, 0)

    def _frame(self, data: dict[str, Any]) -> None:
        """A frame event of the daemon: the image is the daemon's array (never modified)."""
        image = data.get("image")
        camera = data.get("camera")
        camera = camera if isinstance(camera, str) else None
        if isinstance(image, np.ndarray) and image.ndim == 2 and self._frame_wanted(camera):
            meta = {k: v for k, v in data.items() if not isinstance(v, np.ndarray)}
            self._last_frame_s[camera] = time.monotonic()
            self._thumbnail_tasks[camera] = asyncio.create_task(
                self._publish_thumbnail(image, meta)
            )

    def _frame_wanted(self, camera: str | None) -> bool:
        """Someone listens to frames, none of this camera is being made, and its interval
        has passed (each tool camera of an arm has its own)."""
        task = self._thumbnail_tasks.get(camera)
        busy = task is not None and not task.done()
        interval = self._context.settings.api.ws_frame_interval_s
        due = time.monotonic() - self._last_frame_s.get(camera, -math.inf) >= interval
        return not busy and due and self._context.hub.subscribed("frames")

    async def _publish_thumbnail(self, image: NDArray[np.integer], meta: dict[str, Any]) -> None:
        x, y = meta.get("centroid_x_px"), meta.get("centroid_y_px")
        centre = (float(x), float(y)) if x is not None and y is not None else None
        try:
            picture = await self._daemon.read(frame_pictures, image, centre)
        except (ValueError, cv2.error):
            logger.warning("cannot make a thumbnail of a frame", exc_info=True)
            return
        self._context.hub.publish("frames", {**meta, **picture})
