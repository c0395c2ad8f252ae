"""Camera poses calibrated from robot moves (issue 20; extends issue 18's ``calibrate camera``).

The robot carries a marker through known world positions (its commanded poses times the
marker's offset on the tool); each camera with known intrinsics and distortion sees the marker's
image at each. The camera's pose world -> camera is then a perspective-n-point problem:
``cv2.solvePnP`` (SQPnP, Terzakis & Lourakis, ECCV 2020: globally optimal, any number of points
>= 3, planar or not) gives the start and ``scipy.optimize.least_squares`` refines the weighted
reprojection error with OpenCV's analytic Jacobian (d pixel / d(rvec, tvec) from
``cv2.projectPoints``).

Standard errors: the covariance of (rvec, tvec) is ``s² (J^T W J)^-1`` of the weighted problem.
With each observation's own 1-sigma given (the centroids' ``sigma_x_px``/``sigma_y_px``),
``s² = 1``; without, the camera's nominal ``pixel_sigma_px`` only weighs the points and the
noise is estimated from the residuals, ``s² = chi² / (2M - 6)``, as calibration.py does for the
single camera. The camera centre's standard errors follow by first-order propagation.

What the positions must be: at least four (six unknowns, one spare for the noise), not on one
line; points spread in depth as well as across the image determine the distance best.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from daemon.vision.cameras import CameraModel
from daemon.vision.multiview import (
    MultiviewError,
    PixelSigma,
    depths_mm,
    points_array,
)
from daemon.vision.points import on_one_line

FloatArray = NDArray[np.float64]

#: Fewest positions: six unknowns and at least one residual to estimate the noise from.
MIN_POSE_POINTS = 4


@dataclass(frozen=True, eq=False)
class CameraPoseFit:
    """A fitted camera pose: ``camera`` is the input camera at the fitted pose with its
    standard errors set; ``covariance`` is of (rvec (rad), tvec (mm)); ``centre_mm`` /
    ``centre_se_mm`` the projection centre in the world; ``residual_px`` the RMS reprojection
    residual; ``reduced_chi2`` the residuals over the given sigmas (about 1 when they are
    right)."""

    camera: CameraModel
    covariance: FloatArray
    centre_mm: FloatArray
    centre_se_mm: FloatArray
    residual_px: float
    reduced_chi2: float
    points: int


def grid_positions(centre_mm: ArrayLike, half_size_mm: float, per_axis: int = 3) -> FloatArray:
    """A cube of ``per_axis``³ marker positions, ±``half_size_mm`` about ``centre_mm``, visited
    in a serpentine (short moves): the robot's moves for a pose calibration."""
    if per_axis < 2 or half_size_mm <= 0:
        raise MultiviewError("the calibration cube needs 2 or more positions per axis and a size")
    ticks = np.linspace(-half_size_mm, half_size_mm, per_axis)
    rows: list[tuple[float, float, float]] = []
    for i, x in enumerate(ticks):
        ys = ticks if i % 2 == 0 else ticks[::-1]
        for j, y in enumerate(ys):
            zs = ticks if (i * per_axis + j) % 2 == 0 else ticks[::-1]
            rows.extend((float(x), float(y), float(z)) for z in zs)
    return np.asarray(rows, dtype=np.float64) + np.asarray(centre_mm, dtype=np.float64)


def fit_camera_pose(
    camera: CameraModel,
    points_mm: ArrayLike,
    pixels_px: ArrayLike,
    sigmas_px: Sequence[PixelSigma] | None = None,
) -> CameraPoseFit:
    """The pose of ``camera`` (its intrinsics and distortion known; its pose in the input is
    ignored) from marker world positions ``points_mm`` (M x 3) and their pixels (M x 2), with
    standard errors (module docstring)."""
    points = points_array(points_mm)
    pixels = np.asarray(pixels_px, dtype=np.float64)
    count = points.shape[0]
    if pixels.shape != (count, 2) or not np.all(np.isfinite(pixels)):
        raise MultiviewError(
            f"camera {camera.name}: {count} positions need {count} finite pixels (x, y), got "
            f"shape {pixels.shape}"
        )
    if count < MIN_POSE_POINTS:
        raise MultiviewError(
            f"camera {camera.name}: {count} positions: a pose needs at least {MIN_POSE_POINTS}"
        )
    if on_one_line(points):
        raise MultiviewError(
            f"camera {camera.name}: the positions lie on one line: the pose is undetermined; "
            "move the marker across a plane or a volume"
        )
    if sigmas_px is None:
        sigmas = np.full((count, 2), camera.pixel_sigma_px)
    else:
        if len(sigmas_px) != count:
            raise MultiviewError(f"{count} positions but {len(sigmas_px)} pixel sigmas")
        sigmas = np.array(
            [(s, s) if isinstance(s, int | float) else s for s in sigmas_px], dtype=np.float64
        )
        if not (np.all(np.isfinite(sigmas)) and np.all(sigmas > 0)):
            raise MultiviewError("pixel sigmas must be positive and finite")
    found, rvec, tvec = cv2.solvePnP(
        points.reshape(-1, 1, 3),
        pixels.reshape(-1, 1, 2),
        camera.matrix,
        camera.distortion,
        flags=cv2.SOLVEPNP_SQPNP,
    )
    if not found:
        raise MultiviewError(f"camera {camera.name}: solvePnP found no pose")

    def residuals(pose: FloatArray) -> FloatArray:
        predicted, _ = cv2.projectPoints(
            points.reshape(-1, 1, 3), pose[:3], pose[3:], camera.matrix, camera.distortion
        )
        return np.asarray(((predicted.reshape(-1, 2) - pixels) / sigmas).ravel())

    def jacobian(pose: FloatArray) -> FloatArray:
        _, full = cv2.projectPoints(
            points.reshape(-1, 1, 3), pose[:3], pose[3:], camera.matrix, camera.distortion
        )
        return np.asarray(full[:, :6] / sigmas.reshape(-1, 1), dtype=np.float64)

    start = np.concatenate([np.asarray(rvec).reshape(3), np.asarray(tvec).reshape(3)])
    fit = least_squares(residuals, start, jac=jacobian, method="lm", xtol=1e-14, ftol=1e-14)
    pose = np.asarray(fit.x, dtype=np.float64)
    fitted = camera.with_pose(pose[:3], pose[3:])
    behind = int(np.sum(depths_mm(fitted, points) <= 0))
    if behind:
        raise MultiviewError(
            f"camera {camera.name}: the fitted pose puts {behind} position(s) behind the camera"
        )
    weighted = residuals(pose)
    dof = 2 * count - 6
    reduced_chi2 = float(weighted @ weighted) / dof
    whitened = jacobian(pose)
    information = whitened.T @ whitened
    if np.linalg.cond(information) > 1e14:
        raise MultiviewError(f"camera {camera.name}: the positions do not determine the pose")
    covariance = np.linalg.inv(information) * (reduced_chi2 if sigmas_px is None else 1.0)
    covariance = 0.5 * (covariance + covariance.T)
    standard = np.sqrt(np.diag(covariance))

    def centre_of(values: FloatArray) -> FloatArray:
        rotation, _ = cv2.Rodrigues(values[:3])
        return np.asarray(-rotation.T @ values[3:], dtype=np.float64)

    step = 1e-7
    centre_jacobian = np.zeros((3, 6))
    for k in range(6):
        delta = np.zeros(6)
        delta[k] = step
        centre_jacobian[:, k] = (centre_of(pose + delta) - centre_of(pose - delta)) / (2 * step)
    centre_cov = centre_jacobian @ covariance @ centre_jacobian.T
    residual = weighted.reshape(-1, 2) * sigmas
    return CameraPoseFit(
        camera=camera.with_pose(
            pose[:3], pose[3:], rotation_se_rad=standard[:3], translation_se_mm=standard[3:]
        ),
        covariance=covariance,
        centre_mm=centre_of(pose),
        centre_se_mm=np.sqrt(np.diag(centre_cov)),
        residual_px=math.sqrt(float(np.mean(residual**2))),
        reduced_chi2=reduced_chi2,
        points=count,
    )
