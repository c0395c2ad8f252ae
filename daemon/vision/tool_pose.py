"""The tool's pose from its markers' centroids in several cameras (issue 20): every marker seen by
two or more cameras is triangulated (:func:`daemon.vision.multiview.triangulate`, weighted by
the centroids' own sigmas), and the located markers give the pose
(:func:`daemon.vision.multiview.rigid_pose_from_markers`, weighted by their covariances).

With fewer than three markers triangulated (one camera watching the tool, or markers each seen
by one camera only) the pose comes from the pixels directly: perspective-n-point over every
view (:func:`daemon.vision.pnp.pose_from_views`; one camera seeing four markers is enough, its
depth along the line of sight poorer, as its covariance says).

The markers are treated as independent: their pixel noise is. What the cameras' calibrated
poses get wrong is common to every measurement with the same cameras, so it cancels in the
difference of two poses (the drift from a reference), which is what the compensation uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from daemon.vision.cameras import CameraModel
from daemon.vision.multiview import MultiviewError, rigid_pose_from_markers, triangulate
from daemon.vision.pnp import pose_from_views

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class ToolMeasurement:
    """One measured tool pose: ``pose`` (4x4, tool -> world) and its 6x6 ``covariance``
    (translation mm, rotation vector rad; world frame), the markers' triangulated positions
    (M x 3, NaN for a marker seen by fewer than two cameras) and covariances, and how many
    cameras saw each marker. A pose from the views (fewer than three markers triangulated) has
    the PnP fit's covariance."""

    pose: FloatArray
    covariance: FloatArray
    points_mm: FloatArray
    point_covariances_mm2: FloatArray
    views: tuple[int, ...]


def measure_tool_pose(
    cameras: list[CameraModel] | tuple[CameraModel, ...],
    model_mm: ArrayLike,
    pixels: ArrayLike,
    sigmas_px: ArrayLike | None = None,
) -> ToolMeasurement:
    """The tool pose from ``pixels`` (cameras x markers x 2; NaN where a camera does not see a
    marker) of the markers whose tool-frame positions are ``model_mm`` (markers x 3).
    ``sigmas_px`` (cameras x markers x 2): each centroid's 1-sigma, default each camera's
    ``pixel_sigma_px``. Three or more markers seen by two or more cameras each: triangulated and
    fitted; fewer: the pose from the views by perspective-n-point (module docstring)."""
    model = np.asarray(model_mm, dtype=np.float64)
    observed = np.asarray(pixels, dtype=np.float64)
    count = model.shape[0] if model.ndim == 2 else 0
    if model.ndim != 2 or model.shape[1] != 3:
        raise MultiviewError(f"the markers' model must be M x 3, got shape {model.shape}")
    if observed.shape != (len(cameras), count, 2):
        raise MultiviewError(
            f"expected pixels of shape ({len(cameras)} cameras, {count} markers, 2), got "
            f"{observed.shape}"
        )
    if sigmas_px is None:
        sigmas = np.array(
            [np.full((count, 2), camera.pixel_sigma_px) for camera in cameras], dtype=np.float64
        ).reshape(len(cameras), count, 2)
    else:
        sigmas = np.asarray(sigmas_px, dtype=np.float64)
        if sigmas.shape != observed.shape:
            raise MultiviewError(f"sigmas of shape {sigmas.shape} for pixels {observed.shape}")
    points = np.full((count, 3), np.nan)
    covariances = np.full((count, 3, 3), np.nan)
    views = []
    for marker in range(count):
        seen = [c for c in range(len(cameras)) if np.all(np.isfinite(observed[c, marker]))]
        views.append(len(seen))
        if len(seen) < 2:
            continue
        point, covariance = triangulate(
            [cameras[c] for c in seen],
            observed[seen, marker],
            [(float(sigmas[c, marker, 0]), float(sigmas[c, marker, 1])) for c in seen],
        )
        points[marker], covariances[marker] = point, covariance
    located = [m for m in range(count) if views[m] >= 2]
    if len(located) < 3:
        try:
            fit = pose_from_views(cameras, model, observed, sigmas)
        except MultiviewError as err:
            raise MultiviewError(
                f"{len(located)} marker(s) seen by two or more cameras and no pose from the "
                f"views (views per marker: {views}): {err}"
            ) from err
        return ToolMeasurement(
            pose=fit.pose,
            covariance=fit.covariance,
            points_mm=points,
            point_covariances_mm2=covariances,
            views=tuple(views),
        )
    pose, covariance = rigid_pose_from_markers(
        model[located], points[located], covariances[located]
    )
    return ToolMeasurement(
        pose=pose,
        covariance=covariance,
        points_mm=points,
        point_covariances_mm2=covariances,
        views=tuple(views),
    )
