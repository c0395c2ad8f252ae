"""Laser-spot measurement (thesis 3.2.3, 4.7, A.1): sub-pixel centroid and synthetic spots.

Pure core: arrays in, results out; no I/O (the ``centroid`` command in ``cli`` reads files).
"""

from daemon.vision.centroid import (
    METHODS,
    CentroidError,
    CentroidResult,
    Method,
    measure_centroid,
    measure_with_camera_settings,
    threshold_counts,
)
from daemon.vision.synthetic import cramer_rao_bound, expected_spot, full_scale, render_spot

__all__ = [
    "METHODS",
    "CentroidError",
    "CentroidResult",
    "Method",
    "cramer_rao_bound",
    "expected_spot",
    "full_scale",
    "measure_centroid",
    "measure_with_camera_settings",
    "render_spot",
    "threshold_counts",
]
