"""The bring-up preview (issue 18): the spot camera's frame with the centroid marked, beside the
thermal image with every IR region drawn and labelled, as one 8-bit BGR image (OpenCV drawing).

Pure: arrays in, an array out. The camera frame is stretched between its darkest and brightest
pixel (a dim spot is still seen); the thermal image is false-coloured between its coldest and
hottest pixel and enlarged by a whole factor to about the camera's height, pixels kept square.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

#: Colours (BGR) of the marks.
SPOT_COLOUR = (0, 0, 255)
REGION_COLOUR = (255, 255, 0)
TEXT_COLOUR = (255, 255, 255)
FONT = cv2.FONT_HERSHEY_SIMPLEX
FONT_SCALE = 0.5
HEADER_PX = 24
GAP_PX = 8
#: Radius of the ring drawn around the centroid (px of the preview).
SPOT_RING_PX = 12
#: Fixed-point bits of OpenCV's sub-pixel drawing (the centroid is drawn where it is, not
#: rounded to a pixel).
DRAW_SHIFT = 4


@dataclass(frozen=True, slots=True)
class RegionBox:
    """An IR region as drawn: its rectangle (thermal pixels) and its label."""

    name: str
    x: int
    y: int
    width: int
    height: int
    label: str


def _stretch(image: NDArray[np.generic]) -> NDArray[np.uint8]:
    data = image.astype(np.float64)
    low, high = float(data.min()), float(data.max())
    scale = 255.0 / (high - low) if high > low else 0.0
    return np.clip((data - low) * scale, 0, 255).astype(np.uint8)


def _label(
    canvas: NDArray[np.uint8], text: str, origin: tuple[int, int], colour: tuple[int, int, int]
) -> None:
    cv2.putText(canvas, text, origin, FONT, FONT_SCALE, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(canvas, text, origin, FONT, FONT_SCALE, colour, 1, cv2.LINE_AA)


def camera_panel(
    image: NDArray[np.generic], centroid_xy: tuple[float, float] | None, caption: str
) -> NDArray[np.uint8]:
    """The camera frame in grey with the centroid ringed and crossed, and a caption."""
    panel = np.asarray(cv2.cvtColor(_stretch(image), cv2.COLOR_GRAY2BGR), dtype=np.uint8)
    if centroid_xy is not None:
        factor = 1 << DRAW_SHIFT
        x, y = (round(c * factor) for c in centroid_xy)
        ring = SPOT_RING_PX * factor
        cv2.circle(panel, (x, y), ring, SPOT_COLOUR, 1, cv2.LINE_AA, DRAW_SHIFT)
        cv2.line(
            panel, (x - 2 * ring, y), (x + 2 * ring, y), SPOT_COLOUR, 1, cv2.LINE_AA, DRAW_SHIFT
        )
        cv2.line(
            panel, (x, y - 2 * ring), (x, y + 2 * ring), SPOT_COLOUR, 1, cv2.LINE_AA, DRAW_SHIFT
        )
    return _with_header(panel, caption)


def ir_panel(
    frame_c: NDArray[np.floating], regions: Sequence[RegionBox], caption: str, height_px: int
) -> NDArray[np.uint8]:
    """The thermal image false-coloured, enlarged to about ``height_px``, regions labelled."""
    factor = max(1, height_px // frame_c.shape[0])
    coloured = cv2.applyColorMap(_stretch(frame_c), cv2.COLORMAP_INFERNO)
    enlarged = cv2.resize(coloured, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST)
    panel = np.asarray(enlarged, dtype=np.uint8)
    for region in regions:
        top_left = (region.x * factor, region.y * factor)
        bottom_right = (
            (region.x + region.width) * factor - 1,
            (region.y + region.height) * factor - 1,
        )
        cv2.rectangle(panel, top_left, bottom_right, REGION_COLOUR, 1)
        (text_w, _), _ = cv2.getTextSize(region.label, FONT, FONT_SCALE, 1)
        x = min(top_left[0], max(panel.shape[1] - text_w - 2, 0))  # keep it on the image
        _label(panel, region.label, (x, max(top_left[1] - 4, 12)), REGION_COLOUR)
    return _with_header(panel, caption)


def _with_header(panel: NDArray[np.uint8], caption: str) -> NDArray[np.uint8]:
    header = np.zeros((HEADER_PX, panel.shape[1], 3), np.uint8)
    _label(header, caption, (4, HEADER_PX - 7), TEXT_COLOUR)
    return np.vstack([header, panel])


def side_by_side(panels: Sequence[NDArray[np.uint8]]) -> NDArray[np.uint8]:
    """Panels in a row, top-aligned on a black background."""
    height = max(p.shape[0] for p in panels)
    width = sum(p.shape[1] for p in panels) + GAP_PX * (len(panels) - 1)
    canvas = np.zeros((height, width, 3), np.uint8)
    x = 0
    for panel in panels:
        canvas[: panel.shape[0], x : x + panel.shape[1]] = panel
        x += panel.shape[1] + GAP_PX
    return canvas


def encode_png(image: NDArray[np.uint8]) -> bytes:
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise ValueError("the preview could not be encoded as PNG")
    return bytes(data.tobytes())
