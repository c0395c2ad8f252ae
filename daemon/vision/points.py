"""Points and the error of the 3-D measurement (issue 20): shared by triangulation
(daemon/vision/multiview.py), the rigid pose of markers (rigid_pose.py), PnP (pnp.py) and the
camera poses (camera_pose.py). Pure core."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: Points whose spread's second principal extent is below this fraction of the first lie on a
#: line: a rotation about that line is undetermined.
MIN_MARKER_SPREAD = 1e-3


class MultiviewError(ValueError):
    """A 3-D measurement cannot be made (too few views, degenerate geometry, point behind a
    camera); ``str()`` is the one line for the user."""


def points_array(points_mm: ArrayLike) -> FloatArray:
    """Points as an N x 3 float array (one point of 3 -> 1 x 3); MultiviewError otherwise."""
    points = np.asarray(points_mm, dtype=np.float64)
    if points.ndim == 1:
        points = points.reshape(1, -1)
    if points.ndim != 2 or points.shape[1] != 3 or not np.all(np.isfinite(points)):
        raise MultiviewError(f"expected finite 3-D points (N x 3), got shape {points.shape}")
    return points


def on_one_line(points: FloatArray) -> bool:
    """Whether the points lie on one line (or are one point), by :data:`MIN_MARKER_SPREAD`."""
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return bool(spread[0] == 0.0 or spread[1] < MIN_MARKER_SPREAD * spread[0])


def skew(vector: FloatArray) -> FloatArray:
    """The cross-product matrix: ``skew(a) @ b == np.cross(a, b)``."""
    x, y, z = vector
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
