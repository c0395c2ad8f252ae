"""The tool's pose from its markers (issue 20): M >= 3 markers of known tool-frame positions
measured in the world give the rigid pose by weighted Kabsch / Wahba
(``scipy.spatial.transform.Rotation.align_vectors``), refined with each marker's full
covariance (Gauss-Newton), and its covariance by linearisation; :func:`pose_difference` and
:func:`pose_covariance_difference` compare two such poses. Pure core; the conventions of
:mod:`daemon.arm.types` (mm, rad, 4x4 poses in the world)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from daemon.arm.types import Pose6
from daemon.arm.types import pose_difference as arm_pose_difference
from daemon.vision.points import FloatArray, MultiviewError, on_one_line, points_array, skew

#: Gauss-Newton of the marker pose: at most this many steps, done when a step is below the
#: tolerance (mm and rad alike: far below any marker noise).
_MAX_POSE_ITERATIONS = 20
_POSE_STEP_TOLERANCE = 1e-12


def rigid_pose_from_markers(
    model_mm: ArrayLike, measured_mm: ArrayLike, covariances: ArrayLike | None = None
) -> tuple[FloatArray, FloatArray]:
    """The rigid pose T (4x4, tool -> world) that carries the markers' tool-frame positions
    ``model_mm`` (M x 3) onto their measured world positions ``measured_mm`` (M x 3), M >= 3
    not on one line, and its 6x6 covariance.

    ``covariances`` (M x 3 x 3, mm²) weigh each marker (e.g. :func:`triangulate`'s); None
    weighs them equally at 1 mm² (the covariance then scales with the real variance). The
    covariance is of ``[dt (mm), dr (rad)]`` where the true pose is ``t + dt`` and
    ``exp([dr]x) R``: translation and rotation vector in the world frame, the order of
    :meth:`Pose6.as_array`.
    """
    model = points_array(model_mm)
    measured = points_array(measured_mm)
    count = model.shape[0]
    if measured.shape != model.shape:
        raise MultiviewError(
            f"{count} model markers but {measured.shape[0]} measured ones: they must pair up"
        )
    if count < 3:
        raise MultiviewError(f"{count} marker(s): an orientation needs three or more")
    if covariances is None:
        cov = np.broadcast_to(np.eye(3), (count, 3, 3)).copy()
    else:
        cov = np.asarray(covariances, dtype=np.float64)
        if cov.shape != (count, 3, 3) or not np.all(np.isfinite(cov)):
            raise MultiviewError(f"expected {count} finite 3x3 covariances, got {cov.shape}")
    for name, points in (("model", model), ("measured", measured)):
        if on_one_line(points):
            raise MultiviewError(
                f"the {name} markers lie on one line (or one point): the rotation about it is "
                "undetermined; use three or more markers not in a line"
            )
    try:
        information = np.linalg.inv(cov)
        whiten = np.linalg.cholesky(information)  # information = L L^T; r^T info r = |L^T r|²
    except np.linalg.LinAlgError as err:
        raise MultiviewError("a marker's covariance is not positive definite") from err
    # weighted Kabsch for the start: scalar weights 1 / mean variance of each marker
    weights = 3.0 / np.trace(cov, axis1=1, axis2=2)
    model_centre = weights @ model / weights.sum()
    measured_centre = weights @ measured / weights.sum()
    start = Rotation.align_vectors(measured - measured_centre, model - model_centre, weights)[0]
    rotation0 = start.as_matrix()
    translation0 = measured_centre - rotation0 @ model_centre

    def whitened_system(
        rotation: FloatArray, translation: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Whitened residuals and their Jacobian in (dt, dr) at a pose (the perturbation
        ``R -> exp([dr]x) R``, ``t -> t + dt``: d(R m + t) = dt - [R m]x dr)."""
        rotated = model @ rotation.T
        errors = rotated + translation - measured
        residual = np.einsum("mji,mj->mi", whiten, errors).ravel()
        blocks = [
            chol.T @ np.hstack([np.eye(3), -skew(arm)])
            for arm, chol in zip(rotated, whiten, strict=True)
        ]
        return np.asarray(residual, dtype=np.float64), np.vstack(blocks)

    # Gauss-Newton from the Kabsch start: the problem is nearly linear there (small residuals
    # of well-measured markers), so a few steps reach machine precision
    rotation, translation = rotation0, translation0
    for _ in range(_MAX_POSE_ITERATIONS):
        residual, jacobian = whitened_system(rotation, translation)
        step = np.linalg.lstsq(jacobian, -residual, rcond=None)[0]
        rotation = Rotation.from_rotvec(step[3:]).as_matrix() @ rotation
        translation = translation + step[:3]
        if np.linalg.norm(step) < _POSE_STEP_TOLERANCE:
            break
    _, jacobian = whitened_system(rotation, translation)
    covariance = np.linalg.inv(jacobian.T @ jacobian)
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = translation
    return transform, 0.5 * (covariance + covariance.T)


def _pose_parts(pose: ArrayLike) -> tuple[FloatArray, FloatArray]:
    transform = np.asarray(pose, dtype=np.float64)
    if transform.shape != (4, 4) or not np.all(np.isfinite(transform)):
        raise MultiviewError(f"expected a finite 4x4 pose, got shape {transform.shape}")
    return transform[:3, :3], transform[:3, 3]


def pose_difference(reference: ArrayLike, current: ArrayLike) -> Pose6:
    """``current`` relative to ``reference`` in the world frame
    (:func:`daemon.arm.types.pose_difference`, the one implementation, reference first);
    a malformed pose is a :class:`MultiviewError`."""
    _pose_parts(reference)
    _pose_parts(current)
    return arm_pose_difference(reference, current)


def pose_covariance_difference(
    reference: ArrayLike,
    current: ArrayLike,
    reference_covariance: ArrayLike,
    current_covariance: ArrayLike,
) -> FloatArray:
    """6x6 covariance of :func:`pose_difference` for two independent poses with the
    covariances of :func:`rigid_pose_from_markers`, by first-order propagation (central
    differences of the difference under each pose's perturbation)."""
    poses = [np.asarray(reference, dtype=np.float64), np.asarray(current, dtype=np.float64)]
    covs = [np.asarray(reference_covariance, dtype=np.float64)]
    covs.append(np.asarray(current_covariance, dtype=np.float64))
    for cov in covs:
        if cov.shape != (6, 6):
            raise MultiviewError(f"expected 6x6 pose covariances, got {cov.shape}")

    def perturbed(pose: FloatArray, delta: FloatArray) -> FloatArray:
        moved = pose.copy()
        moved[:3, :3] = Rotation.from_rotvec(delta[3:]).as_matrix() @ pose[:3, :3]
        moved[:3, 3] = pose[:3, 3] + delta[:3]
        return moved

    step = 1e-7
    total = np.zeros((6, 6))
    for which in range(2):
        jacobian = np.zeros((6, 6))
        for k in range(6):
            delta = np.zeros(6)
            delta[k] = step
            plus, minus = list(poses), list(poses)
            plus[which] = perturbed(poses[which], delta)
            minus[which] = perturbed(poses[which], -delta)
            jacobian[:, k] = (
                pose_difference(*plus).as_array() - pose_difference(*minus).as_array()
            ) / (2 * step)
        total += jacobian @ covs[which] @ jacobian.T
    return 0.5 * (total + total.T)
