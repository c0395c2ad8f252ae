"""Sub-pixel laser-spot centroid: the thesis's algorithm and a robust, near-optimal one.

Coordinates: pixel (row r, column c) has its centre at (x = c, y = r), x to the right and y
down (DESIGN.md "Centroid"); micrometres are ``px * um_per_px`` per axis (the thesis measured
10.22 µm/px in x and 9.72 µm/px in y, A.1). Pure code: arrays in, results out, no I/O.

``method="thesis"`` replicates ``extract_centroid.m`` (thesis appendix A.1, 3.2.3, 4.7.2).
``method="robust"`` (default) is what the daemon measures with; see
:func:`daemon.vision.centroid_robust.robust_centroid`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray

from daemon.vision.centroid_result import (
    METHODS,
    CentroidError,
    CentroidResult,
    GainSource,
    Method,
)
from daemon.vision.centroid_robust import robust_centroid
from daemon.vision.centroid_thesis import thesis_centroid, threshold_counts

if TYPE_CHECKING:
    from config.settings import CameraSettings

__all__ = [
    "METHODS",
    "CentroidError",
    "CentroidResult",
    "Method",
    "measure_centroid",
    "measure_with_camera_settings",
    "threshold_counts",
]

_OPENCV_DTYPES = tuple(
    np.dtype(t) for t in (np.uint8, np.int8, np.uint16, np.int16, np.int32, np.float32, np.float64)
)


def _validated(
    image: NDArray[Any], bit_depth: int, expected_shape: tuple[int, int] | None
) -> NDArray[Any]:
    if bit_depth not in (8, 12, 16):
        raise ValueError(f"bit_depth must be 8, 12 or 16, got {bit_depth!r}")
    if image.ndim != 2:
        raise CentroidError(
            "dimensions", f"wrong dimensions: expected a 2-D grey image, got shape {image.shape}"
        )
    if expected_shape is not None and image.shape != tuple(expected_shape):
        raise CentroidError(
            "dimensions",
            f"wrong dimensions: expected {expected_shape[1]}x{expected_shape[0]} px, "
            f"got {image.shape[1]}x{image.shape[0]}",
        )
    if not (np.issubdtype(image.dtype, np.integer) or np.issubdtype(image.dtype, np.floating)):
        raise CentroidError("unreadable", f"not an image: pixel type {image.dtype}")
    if image.dtype in _OPENCV_DTYPES:
        lowest, highest, _, _ = cv2.minMaxLoc(image)  # one C pass, no copy
    else:
        lowest, highest = float(image.min()), float(image.max())
    if not (math.isfinite(lowest) and math.isfinite(highest)):
        raise CentroidError("unreadable", "not an image: pixel values are not finite")
    if highest == lowest:
        raise CentroidError("blank", f"blank frame: every pixel is {highest:g}")
    return image


def measure_centroid(
    image: NDArray[Any],
    bit_depth: int = 16,
    method: Method = "robust",
    um_per_px: tuple[float, float] = (10.22, 9.72),
    *,
    low: float = 0.8,
    high: float | None = None,
    box: int = 400,
    binary: bool = False,
    gain_e_per_count: float | None = None,
    read_noise_e: float = 5.0,
    gain_source: GainSource = "config",
    expected_shape: tuple[int, int] | None = None,
) -> CentroidResult:
    """Measure the laser spot of one frame; raise :class:`CentroidError` on a bad frame.

    ``low``, ``high``, ``box`` and ``binary`` configure the thesis method only (thresholds as
    fractions of full scale, or counts when above 1). The robust method's noise model (its
    1-sigma and fit weights) takes the sensor's ``gain_e_per_count`` and ``read_noise_e``
    when a gain is given (``gain_source`` says whose: "config" or "camera"), else measures it
    on the frame (photon transfer, daemon/vision/photon_transfer.py); the result says which.
    ``expected_shape`` (rows, columns), when given, rejects frames of other dimensions.
    """
    frame = _validated(image, bit_depth, expected_shape)
    if method == "thesis":
        return thesis_centroid(
            frame, bit_depth, um_per_px, low=low, high=high, box=box, binary=binary
        )
    if method == "robust":
        return robust_centroid(
            frame,
            bit_depth,
            um_per_px,
            gain_e_per_count=gain_e_per_count,
            read_noise_e=read_noise_e,
            gain_source=gain_source,
        )
    raise ValueError(f"unknown centroid method {method!r}; use one of {', '.join(METHODS)}")


def measure_with_camera_settings(
    image: NDArray[Any],
    camera: CameraSettings,
    *,
    check_dimensions: bool = False,
    camera_gain_e_per_count: float | None = None,
) -> CentroidResult:
    """:func:`measure_centroid` configured from the ``[camera]`` settings section; with
    ``check_dimensions`` a frame must be ``width_px`` x ``height_px``. The gain: the
    settings' ``gain_e_per_count`` when set, else the camera's (``camera_gain_e_per_count``,
    from the frame), else measured on the frame."""
    gain: float | None = camera.gain_e_per_count
    source: GainSource = "config"
    if gain is None:
        gain, source = camera_gain_e_per_count, "camera"
    return measure_centroid(
        image,
        bit_depth=camera.bit_depth,
        method=camera.centroid_method,
        um_per_px=camera.um_per_px,
        low=camera.centroid_low,
        high=camera.centroid_high,
        box=camera.centroid_box,
        binary=camera.centroid_binary,
        gain_e_per_count=gain,
        read_noise_e=camera.read_noise_e,
        gain_source=source,
        expected_shape=(camera.height_px, camera.width_px) if check_dimensions else None,
    )
