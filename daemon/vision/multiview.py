"""3-D measurement with one or several cameras (issue 20; thesis 7.2.2, "several camera pairs").

Pure core. Conventions of :mod:`daemon.arm.types`: mm, rad, poses 4x4 in the world (the arm's
base frame), 6-DOF differences as :class:`~daemon.arm.types.Pose6`.

- :func:`project`: world points to pixels (``cv2.projectPoints``, OpenCV's camera model with
  distortion; :mod:`daemon.vision.cameras`).
- :func:`triangulate`: one marker seen by N >= 2 cameras -> its position and covariance. The
  pixels are undistorted (``cv2.undistortPoints``), a linear DLT on the normalised image
  coordinates (Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., 12.2) gives the start,
  and ``scipy.optimize.least_squares`` minimises the reprojection error weighted by each
  observation's 1-sigma (the maximum-likelihood estimate for Gaussian pixel noise, H&Z 12.3).
  The covariance is ``(J^T W J)^-1`` of the weighted problem at the solution (first order; the
  tests check it against Monte Carlo).
- One camera sees no depth: the thesis's setup (a camera looking along one axis, the spot moving
  in a plane at a known depth; thesis 3.2.3) is :func:`measure_in_plane`, the ray of the pixel
  intersected with the known plane; :func:`axis_camera` builds the CameraModel equivalent to
  the single camera's ``camera.um_per_px`` / ``camera.rotation_deg`` calibration, and
  ``triangulate([camera], [pixel], plane=...)`` does the same.
- :func:`rigid_pose_from_markers` (daemon/vision/rigid_pose.py, re-exported here): the tool's
  pose from M >= 3 markers of known tool-frame positions measured in the world, and its
  covariance; :func:`pose_difference` gives the 6-DOF difference of two poses.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares

from daemon.vision.cameras import (
    CameraFileError,
    CameraModel,
    cameras_toml,
    intrinsic_matrix,
    load_cameras,
    look_at,
    write_cameras,
)
from daemon.vision.points import MIN_MARKER_SPREAD, FloatArray, MultiviewError, points_array
from daemon.vision.rigid_pose import (
    pose_covariance_difference,
    pose_difference,
    rigid_pose_from_markers,
)

__all__ = [
    "MIN_MARKER_SPREAD",
    "CameraFileError",
    "CameraModel",
    "MultiviewError",
    "Plane",
    "Triangulation",
    "axis_camera",
    "cameras_toml",
    "depths_mm",
    "intrinsic_matrix",
    "load_cameras",
    "look_at",
    "measure_in_plane",
    "points_array",
    "pose_covariance_difference",
    "pose_difference",
    "project",
    "projection_jacobian",
    "rigid_pose_from_markers",
    "triangulate",
    "triangulate_detailed",
    "write_cameras",
]

PixelSigma = float | tuple[float, float]

#: Rays closer to parallel than this carry no depth: triangulation is refused (rad; 0.1°).
MIN_RAY_ANGLE_RAD = math.radians(0.1)
#: A ray meeting the plane at less than this angle (rad; ~0.6°) gives no usable point.
MIN_PLANE_INCIDENCE_RAD = 0.01
_UM_PER_MM = 1000.0
#: Newton steps of measure_in_plane after the ray's intersection (quadratic convergence).
_PLANE_NEWTON_STEPS = 3


@dataclass(frozen=True, slots=True)
class Plane:
    """A plane in the world: a point on it and its normal (any length)."""

    point_mm: tuple[float, float, float]
    normal: tuple[float, float, float]


@dataclass(frozen=True, eq=False)
class Triangulation:
    """A triangulated marker: position, covariance, the weighted residuals' chi² and the
    reprojection residuals (px, one row per camera)."""

    point_mm: FloatArray
    covariance_mm2: FloatArray
    residuals_px: FloatArray
    chi2: float
    dof: int


def project(camera: CameraModel, points_mm: ArrayLike) -> FloatArray:
    """Pixels (N x 2: x, y) of world points (N x 3 or one point of 3), ``cv2.projectPoints``."""
    pixels, _ = projection_jacobian(camera, points_mm)
    return pixels


def projection_jacobian(camera: CameraModel, points_mm: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Pixels (N x 2) and their derivative with respect to each world point (N x 2 x 3).

    OpenCV's Jacobian gives d(pixel)/d(tvec); a world point enters as ``R X + t``, so
    d(pixel)/dX = d(pixel)/d(tvec) R."""
    points = points_array(points_mm)
    pixels, jacobian = cv2.projectPoints(
        points.reshape(-1, 1, 3),
        camera.rotation_rad,
        camera.translation_mm,
        camera.matrix,
        camera.distortion,
    )
    d_tvec = np.asarray(jacobian, dtype=np.float64)[:, 3:6].reshape(-1, 2, 3)
    return (
        np.asarray(pixels, dtype=np.float64).reshape(-1, 2),
        np.asarray(d_tvec @ camera.rotation_matrix, dtype=np.float64),
    )


def depths_mm(camera: CameraModel, points: FloatArray) -> FloatArray:
    """Each point's depth along the camera's optical axis (mm; <= 0: behind the camera)."""
    return np.asarray((points @ camera.rotation_matrix.T + camera.translation_mm)[:, 2])


def _sigmas(cameras: Sequence[CameraModel], sigmas_px: Sequence[PixelSigma] | None) -> FloatArray:
    """Per camera, the 1-sigma (x, y) of its observation."""
    if sigmas_px is None:
        return np.array([[c.pixel_sigma_px, c.pixel_sigma_px] for c in cameras], dtype=np.float64)
    if len(sigmas_px) != len(cameras):
        raise MultiviewError(f"{len(cameras)} cameras but {len(sigmas_px)} pixel sigmas")
    rows = []
    for sigma in sigmas_px:
        sx, sy = (sigma, sigma) if isinstance(sigma, int | float) else sigma
        rows.append((float(sx), float(sy)))
    array = np.array(rows, dtype=np.float64)
    if not (np.all(np.isfinite(array)) and np.all(array > 0)):
        raise MultiviewError(f"pixel sigmas must be positive and finite, got {sigmas_px!r}")
    return array


def _normalised(camera: CameraModel, pixel: FloatArray) -> FloatArray:
    """Undistorted normalised image coordinates (x/z, y/z) of a pixel."""
    undistorted = cv2.undistortPoints(
        pixel.reshape(1, 1, 2), camera.matrix, camera.distortion
    ).reshape(2)
    return np.asarray(undistorted, dtype=np.float64)


def _ray(camera: CameraModel, pixel: FloatArray) -> FloatArray:
    """Unit direction (world) of the ray through a pixel."""
    x, y = _normalised(camera, pixel)
    direction = camera.rotation_matrix.T @ np.array([x, y, 1.0])
    return np.asarray(direction / np.linalg.norm(direction), dtype=np.float64)


def _linear(cameras: Sequence[CameraModel], pixels: FloatArray, sigmas: FloatArray) -> FloatArray:
    """The DLT: each view gives x P3 - P1 = 0 and y P3 - P2 = 0 on the normalised
    coordinates; rows are weighted by the focal length over the pixel sigma."""
    rows = []
    for camera, pixel, sigma in zip(cameras, pixels, sigmas, strict=True):
        x, y = _normalised(camera, pixel)
        pose = camera.world_to_camera[:3]
        rows.append((x * pose[2] - pose[0]) * camera.matrix[0, 0] / sigma[0])
        rows.append((y * pose[2] - pose[1]) * camera.matrix[1, 1] / sigma[1])
    _, _, vt = np.linalg.svd(np.array(rows))
    homogeneous = vt[-1]
    if abs(homogeneous[3]) < 1e-12 * np.linalg.norm(homogeneous):
        raise MultiviewError("the rays meet at infinity: no finite point")
    return np.asarray(homogeneous[:3] / homogeneous[3], dtype=np.float64)


def triangulate_detailed(
    cameras: Sequence[CameraModel],
    pixels: ArrayLike,
    sigmas_px: Sequence[PixelSigma] | None = None,
) -> Triangulation:
    """:func:`triangulate` with the residuals and chi² (N >= 2 cameras)."""
    if len(cameras) < 2:
        raise MultiviewError(
            f"{len(cameras)} camera(s): triangulation needs two or more (one camera: "
            "measure_in_plane with the plane the marker moves in)"
        )
    observed = np.asarray(pixels, dtype=np.float64)
    if observed.shape != (len(cameras), 2) or not np.all(np.isfinite(observed)):
        raise MultiviewError(
            f"expected one finite pixel (x, y) per camera ({len(cameras)} x 2), got shape "
            f"{observed.shape}"
        )
    sigmas = _sigmas(cameras, sigmas_px)
    rays = [_ray(camera, pixel) for camera, pixel in zip(cameras, observed, strict=True)]
    widest = max(math.acos(min(1.0, abs(float(a @ b)))) for a, b in itertools.combinations(rays, 2))
    if widest < MIN_RAY_ANGLE_RAD:
        raise MultiviewError(
            f"the cameras' rays are parallel (widest angle {math.degrees(widest):.3g} deg < "
            f"{math.degrees(MIN_RAY_ANGLE_RAD):g} deg): no depth; place the cameras apart"
        )
    start = _linear(cameras, observed, sigmas)

    def residuals(point: FloatArray) -> FloatArray:
        predicted = np.vstack([project(camera, point) for camera in cameras])
        return np.asarray(((predicted - observed) / sigmas).ravel(), dtype=np.float64)

    def jacobian(point: FloatArray) -> FloatArray:
        blocks = [projection_jacobian(camera, point)[1][0] for camera in cameras]
        return np.asarray(np.vstack(blocks) / sigmas.reshape(-1, 1), dtype=np.float64)

    fit = least_squares(residuals, start, jac=jacobian, method="lm", xtol=1e-12, ftol=1e-12)
    point = np.asarray(fit.x, dtype=np.float64)
    behind = [c.name for c in cameras if depths_mm(c, point.reshape(1, 3))[0] <= 0]
    if behind:
        raise MultiviewError(f"the point lies behind camera(s) {', '.join(behind)}")
    whitened = jacobian(point)
    covariance = np.linalg.inv(whitened.T @ whitened)
    covariance = 0.5 * (covariance + covariance.T)
    weighted = residuals(point)
    return Triangulation(
        point_mm=point,
        covariance_mm2=covariance,
        residuals_px=(weighted.reshape(-1, 2) * sigmas),
        chi2=float(weighted @ weighted),
        dof=2 * len(cameras) - 3,
    )


def triangulate(
    cameras: Sequence[CameraModel],
    pixels: ArrayLike,
    sigmas_px: Sequence[PixelSigma] | None = None,
    *,
    plane: Plane | None = None,
) -> tuple[FloatArray, FloatArray]:
    """One marker's world position (mm) and its 3x3 covariance (mm²) from its pixel (x, y) in
    each camera.

    ``sigmas_px`` per camera: the observation's 1-sigma (one value or (x, y); e.g. the
    centroid's ``sigma_x_px``, ``sigma_y_px``), default each camera's ``pixel_sigma_px``. With
    one camera the marker must move in a known ``plane`` (:func:`measure_in_plane`); with two
    or more ``plane`` is not used.
    """
    if len(cameras) == 1:
        if plane is None:
            raise MultiviewError(
                "one camera sees no depth: give the plane the marker moves in (the thesis's "
                "single camera along one axis) or use two or more cameras"
            )
        observed = np.asarray(pixels, dtype=np.float64).reshape(-1)
        sigma = None if sigmas_px is None else sigmas_px[0]
        return measure_in_plane(cameras[0], (float(observed[0]), float(observed[1])), plane, sigma)
    result = triangulate_detailed(cameras, pixels, sigmas_px)
    return result.point_mm, result.covariance_mm2


def _plane_basis(normal: FloatArray) -> FloatArray:
    """Two orthonormal vectors spanning the plane (3 x 2)."""
    _, _, vt = np.linalg.svd(normal.reshape(1, 3))
    return np.asarray(vt[1:].T, dtype=np.float64)


def measure_in_plane(
    camera: CameraModel,
    pixel: tuple[float, float],
    plane: Plane,
    sigma_px: PixelSigma | None = None,
) -> tuple[FloatArray, FloatArray]:
    """One camera: the world point (mm) where the pixel's ray meets ``plane``, and its 3x3
    covariance (mm², rank 2: nothing is measured along the normal, the plane is given).

    This is the thesis's single camera (3.2.3): for a camera looking square onto the plane the
    map is linear, ``um_per_px = depth / focal``; :func:`axis_camera` builds that camera from the
    single-camera calibration and the tests check it against ``calibration.camera_to_robot``.
    """
    normal = np.asarray(plane.normal, dtype=np.float64)
    if normal.shape != (3,) or not np.linalg.norm(normal) > 0:
        raise MultiviewError(f"the plane's normal must be a non-zero 3-vector, got {plane.normal}")
    normal = normal / np.linalg.norm(normal)
    on_plane = np.asarray(plane.point_mm, dtype=np.float64)
    observed = np.asarray(pixel, dtype=np.float64).reshape(2)
    direction = _ray(camera, observed)
    incidence = abs(float(direction @ normal))
    if incidence < math.sin(MIN_PLANE_INCIDENCE_RAD):
        raise MultiviewError(
            f"camera {camera.name}: the ray runs along the plane (it meets it at "
            f"{math.degrees(math.asin(incidence)):.2g} deg): no point"
        )
    centre = camera.centre_mm
    distance = float(normal @ (on_plane - centre)) / float(direction @ normal)
    if distance <= 0:
        raise MultiviewError(f"camera {camera.name}: the plane lies behind the camera")
    point = centre + distance * direction
    sigma = _sigmas([camera], None if sigma_px is None else [sigma_px])[0]
    basis = _plane_basis(normal)
    # cv2.undistortPoints inverts the distortion iteratively, to ~1e-3 px for strong
    # distortion: Newton steps in the plane make the point reproject onto the pixel exactly
    for _ in range(_PLANE_NEWTON_STEPS):
        projected, jacobian = projection_jacobian(camera, point)
        in_plane = jacobian[0] @ basis  # d pixel / d (plane coords)
        point = point + basis @ np.linalg.solve(in_plane, observed - projected[0])
    in_plane = projection_jacobian(camera, point)[1][0] @ basis
    inverse = np.linalg.inv(in_plane)
    covariance_plane = inverse @ np.diag(sigma**2) @ inverse.T
    covariance = basis @ covariance_plane @ basis.T
    return np.asarray(point, dtype=np.float64), 0.5 * (covariance + covariance.T)


def axis_camera(
    um_per_px: tuple[float, float],
    rotation_deg: float = 0.0,
    *,
    spot_mm: tuple[float, float, float] = (0.0, 0.0, 0.0),
    distance_mm: float = 100.0,
    image_size_px: tuple[int, int] = (752, 582),
    pixel_sigma_px: float = 0.05,
    name: str = "axis",
) -> CameraModel:
    """The single camera of the thesis as a CameraModel: it looks along world +y at ``spot_mm``
    (imaged at the chip's centre), image x along world x and image y along world -z, turned by
    ``rotation_deg`` (``camera.rotation_deg``: positive turns world +x towards image +y), with
    focal lengths such that the plane y = spot_mm[1] is imaged at ``um_per_px`` (x, y)
    (``camera.um_per_px``; calibration.py's model). ``distance_mm`` only sets the focal length:
    for points in that plane the map is the same at any distance."""
    angle = math.radians(rotation_deg)
    right, down, forward = np.eye(3)[0], -np.eye(3)[2], np.eye(3)[1]
    rotation = np.vstack(
        [
            math.cos(angle) * right - math.sin(angle) * down,
            math.sin(angle) * right + math.cos(angle) * down,
            forward,
        ]
    )
    spot = np.asarray(spot_mm, dtype=np.float64)
    centre = spot - distance_mm * forward
    rvec, _ = cv2.Rodrigues(rotation)
    width, height = image_size_px
    focal = (distance_mm * _UM_PER_MM / um_per_px[0], distance_mm * _UM_PER_MM / um_per_px[1])
    return CameraModel(
        name=name,
        matrix=intrinsic_matrix(focal, ((width - 1) / 2.0, (height - 1) / 2.0)),
        distortion=np.zeros(5),
        rotation_rad=np.asarray(rvec, dtype=np.float64).reshape(3),
        translation_mm=-rotation @ centre,
        image_size_px=(width, height),
        pixel_sigma_px=pixel_sigma_px,
    )
