"""Every camera's pose and the marker's offset on the tool, together, from the robot's tool poses
(issue 20): the calibration of :mod:`daemon.vision.camera_pose` when the marker's position on
the tool is not known well enough.

The robot visits tool poses ``T_k = (R_k, p_k)`` (4x4, tool -> world, from its kinematics); the
marker sits at the unknown ``m`` in the tool frame, so it is at ``R_k m + p_k`` in the world,
and every camera sees it there. The unknowns — six per camera (rvec, tvec) and three for ``m``
— are fitted together to the weighted reprojection error (a small bundle adjustment;
``scipy.optimize.least_squares`` with the analytic Jacobian from ``cv2.projectPoints``),
starting from each camera's :func:`~daemon.vision.camera_pose.fit_camera_pose` at the guessed
offset. The covariance of all unknowns is ``s² (J^T W J)^-1`` (``s²`` as in camera_pose).

The tool must turn between poses: with its orientation fixed, ``R m`` is the same vector at
every pose, and shifting it shifts every camera the same way (``R_c (p + R m) + t_c``): the
offset is then not observable and the fit is refused. Cameras see a subset of the poses (NaN
pixels elsewhere); each needs four or more.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

from daemon.vision.camera_pose import MIN_POSE_POINTS, CameraPoseFit, fit_camera_pose
from daemon.vision.cameras import CameraModel
from daemon.vision.multiview import MultiviewError

FloatArray = NDArray[np.float64]

#: Beyond this condition number of the normal matrix, some unknown is not determined.
MAX_CONDITION = 1e12


@dataclass(frozen=True, eq=False)
class RigFit:
    """The fitted cameras (each a :class:`CameraPoseFit` whose standard errors come from the
    joint fit), the marker's offset in the tool frame with its standard errors, the covariance
    of every unknown (per camera rvec, tvec; then the offset) and the reduced chi²."""

    fits: tuple[CameraPoseFit, ...]
    marker_mm: FloatArray
    marker_se_mm: FloatArray
    covariance: FloatArray
    reduced_chi2: float


def _centre(values: FloatArray) -> FloatArray:
    rotation, _ = cv2.Rodrigues(values[:3])
    return np.asarray(-rotation.T @ values[3:], dtype=np.float64)


def fit_cameras_and_marker(
    cameras: Sequence[CameraModel],
    tool_poses: ArrayLike,
    pixels: ArrayLike,
    sigmas_px: ArrayLike | None = None,
    marker_guess_mm: Sequence[float] = (0.0, 0.0, 0.0),
) -> RigFit:
    """Camera poses and the marker's tool-frame offset from ``tool_poses`` (K x 4 x 4) and the
    marker's ``pixels`` in each camera (cameras x K x 2, NaN where unseen); ``sigmas_px`` the
    same shape (the centroids' own 1-sigma) or None (each camera's ``pixel_sigma_px`` weighs,
    the residuals give the noise)."""
    poses = np.asarray(tool_poses, dtype=np.float64)
    observed = np.asarray(pixels, dtype=np.float64)
    count = poses.shape[0] if poses.ndim == 3 else 0
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not np.all(np.isfinite(poses)):
        raise MultiviewError(f"expected finite tool poses K x 4 x 4, got shape {poses.shape}")
    if observed.shape != (len(cameras), count, 2):
        raise MultiviewError(
            f"expected pixels of shape ({len(cameras)} cameras, {count} poses, 2), got "
            f"{observed.shape}"
        )
    if sigmas_px is None:
        sigmas = np.stack([np.full((count, 2), c.pixel_sigma_px) for c in cameras])
    else:
        sigmas = np.asarray(sigmas_px, dtype=np.float64)
        if sigmas.shape != observed.shape:
            raise MultiviewError(f"sigmas of shape {sigmas.shape} for pixels {observed.shape}")
    visible = np.all(np.isfinite(observed), axis=2)
    if not np.all(sigmas[visible] > 0) or not np.all(np.isfinite(sigmas[visible])):
        raise MultiviewError("pixel sigmas must be positive and finite")
    seen = [np.flatnonzero(np.all(np.isfinite(observed[c]), axis=1)) for c in range(len(cameras))]
    for camera, rows in zip(cameras, seen, strict=True):
        if rows.size < MIN_POSE_POINTS:
            raise MultiviewError(
                f"camera {camera.name} sees the marker at {rows.size} pose(s): at least "
                f"{MIN_POSE_POINTS} are needed"
            )
    rotations, translations = poses[:, :3, :3], poses[:, :3, 3]
    guess = np.asarray(marker_guess_mm, dtype=np.float64).reshape(3)
    start_points = rotations @ guess + translations
    start = []
    for c, camera in enumerate(cameras):
        first = fit_camera_pose(camera, start_points[seen[c]], observed[c, seen[c]])
        start.append(np.concatenate([first.camera.rotation_rad, first.camera.translation_mm]))
    start.append(guess)
    x0 = np.concatenate(start)
    unknowns = x0.size

    def system(values: FloatArray, with_jacobian: bool) -> tuple[FloatArray, FloatArray]:
        marker = values[-3:]
        points = rotations @ marker + translations
        residual_blocks, jacobian_blocks = [], []
        for c, camera in enumerate(cameras):
            rows = seen[c]
            pose = values[6 * c : 6 * c + 6]
            projected, full = cv2.projectPoints(
                points[rows].reshape(-1, 1, 3), pose[:3], pose[3:], camera.matrix, camera.distortion
            )
            weights = sigmas[c, rows].reshape(-1, 1)
            residual_blocks.append(
                ((projected.reshape(-1, 2) - observed[c, rows]) / sigmas[c, rows]).ravel()
            )
            if with_jacobian:
                block = np.zeros((2 * rows.size, unknowns))
                block[:, 6 * c : 6 * c + 6] = full[:, :6] / weights
                rotation_c, _ = cv2.Rodrigues(pose[:3])
                d_point = full[:, 3:6].reshape(-1, 2, 3) @ rotation_c  # d pixel / d world point
                d_marker = d_point @ rotations[rows]  # d world point / d m = R_k
                block[:, -3:] = d_marker.reshape(-1, 3) / weights
                jacobian_blocks.append(block)
        jacobian = np.vstack(jacobian_blocks) if with_jacobian else np.zeros((0, unknowns))
        return np.concatenate(residual_blocks), jacobian

    start_jacobian = system(x0, True)[1]
    information = start_jacobian.T @ start_jacobian
    scale = 1.0 / np.sqrt(np.diag(information))  # units apart (rad, mm): compare like with like
    if np.linalg.cond(information * np.outer(scale, scale)) > MAX_CONDITION:
        raise MultiviewError(
            "the tool poses do not determine the marker's offset (the tool never turns?): turn "
            "the tool between poses, or give the marker's position and use fit_camera_pose"
        )
    fit = least_squares(
        lambda v: system(v, False)[0],
        x0,
        jac=lambda v: system(v, True)[1],
        method="lm",
        xtol=1e-14,
        ftol=1e-14,
    )
    values = np.asarray(fit.x, dtype=np.float64)
    residual, jacobian = system(values, True)
    dof = residual.size - unknowns
    if dof <= 0:
        raise MultiviewError(f"{residual.size // 2} observations for {unknowns} unknowns: too few")
    reduced_chi2 = float(residual @ residual) / dof
    covariance = np.linalg.inv(jacobian.T @ jacobian) * (reduced_chi2 if sigmas_px is None else 1.0)
    covariance = 0.5 * (covariance + covariance.T)
    standard = np.sqrt(np.diag(covariance))
    fits = []
    offset = 0
    for c, camera in enumerate(cameras):
        pose = values[6 * c : 6 * c + 6]
        block = covariance[6 * c : 6 * c + 6, 6 * c : 6 * c + 6]
        step = 1e-7
        centre_jacobian = np.column_stack(
            [(_centre(pose + step * e) - _centre(pose - step * e)) / (2 * step) for e in np.eye(6)]
        )
        mine = residual[offset : offset + 2 * seen[c].size].reshape(-1, 2) * sigmas[c, seen[c]]
        offset += 2 * seen[c].size
        fits.append(
            CameraPoseFit(
                camera=camera.with_pose(
                    pose[:3],
                    pose[3:],
                    rotation_se_rad=standard[6 * c : 6 * c + 3],
                    translation_se_mm=standard[6 * c + 3 : 6 * c + 6],
                ),
                covariance=block,
                centre_mm=_centre(pose),
                centre_se_mm=np.sqrt(np.diag(centre_jacobian @ block @ centre_jacobian.T)),
                residual_px=math.sqrt(float(np.mean(mine**2))),
                reduced_chi2=reduced_chi2,
                points=int(seen[c].size),
            )
        )
    return RigFit(
        fits=tuple(fits),
        marker_mm=values[-3:],
        marker_se_mm=standard[-3:],
        covariance=covariance,
        reduced_chi2=reduced_chi2,
    )
