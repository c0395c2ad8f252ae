"""The tool's pose from its markers' pixels directly (issue 20): one calibrated camera is enough.

Triangulation (:mod:`daemon.vision.tool_pose`) needs every marker in two or more cameras; one
camera sees no depth of a single point. Three or more markers of known tool-frame geometry
seen by one camera give the tool's whole pose all the same: a perspective-n-point problem
(the thesis's single camera along one axis, 3.2.3, stays a valid setup for the whole arm;
issue 20). The same fit takes the views of several cameras at once (each marker seen by any
of them), so a marker seen by one camera only still counts.

- Start: ``cv2.solvePnP`` with SQPnP (Terzakis & Lourakis, ECCV 2020: the global optimum of
  the unweighted problem, planar or not) in the camera that sees the most markers (four or
  more), or the caller's expected pose (the taught pose) when no camera sees four: three
  points leave up to four poses (P3P), the expected one picks the right branch.
- Refinement: Gauss-Newton on the reprojection error weighted by each centroid's 1-sigma (the
  maximum-likelihood pose for Gaussian pixel noise), in the perturbation of
  :func:`daemon.vision.multiview.rigid_pose_from_markers`: ``t -> t + dt``,
  ``R -> exp([dr]x) R``, world frame, so the covariances of both are comparable. A marker at
  ``X = R m + t`` moves by ``dX = dt - [R m]x dr``; ``d pixel / dX`` is OpenCV's
  (:func:`daemon.vision.multiview.projection_jacobian`).
- Covariance: ``(J^T W J)^-1`` of ``[dt (mm), dr (rad)]`` at the solution, from the centroids'
  sigmas (not rescaled by the residuals: the sigmas are the centroid's own, tested against
  Monte Carlo). Seen by one camera the depth along its line of sight is known far worse than
  the lateral position (by about the distance over the markers' spread): the covariance
  says so, and the compensation's drift inherits it.

Refused, in one line (:class:`~daemon.vision.multiview.MultiviewError`): fewer than three
markers seen, markers in one line, three markers without an expected pose, a pose that puts a
marker behind a camera, views that do not determine the pose.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from daemon.vision.cameras import CameraModel
from daemon.vision.multiview import MultiviewError, depths_mm, projection_jacobian
from daemon.vision.points import on_one_line, skew

FloatArray = NDArray[np.float64]

#: Markers a camera must see for SQPnP's start without an expected pose (P3P is ambiguous).
MIN_PNP_MARKERS = 4
#: Fewest markers for any pose (six unknowns, two equations per marker and view).
MIN_POSE_MARKERS = 3
#: Gauss-Newton: at most this many steps, done when a step is below the tolerance (mm and rad
#: alike: far below any marker noise); each step is halved while it raises the cost.
_MAX_ITERATIONS = 30
_STEP_TOLERANCE = 1e-11
_MAX_HALVINGS = 20
#: Information matrices worse conditioned than this do not determine the pose.
_MAX_CONDITION = 1e14


@dataclass(frozen=True, eq=False)
class ViewPose:
    """A tool pose fitted to marker pixels: ``pose`` (4x4, tool -> world), its 6x6
    ``covariance`` of ``[dt (mm), dr (rad)]`` (world frame, as
    :func:`~daemon.vision.multiview.rigid_pose_from_markers`), the weighted residuals' ``chi2``
    over ``dof`` (2 per observation - 6), the reprojection ``residuals_px`` (one row per
    observation, in the order of ``observations``: (camera, marker) pairs)."""

    pose: FloatArray
    covariance: FloatArray
    chi2: float
    dof: int
    residuals_px: FloatArray
    observations: tuple[tuple[int, int], ...]

    @property
    def markers(self) -> tuple[int, ...]:
        """The markers that entered the fit (seen by at least one camera)."""
        return tuple(sorted({marker for _, marker in self.observations}))


def _check_spread(points: FloatArray) -> None:
    if on_one_line(points):
        raise MultiviewError(
            "the seen markers lie on one line: the rotation about it is undetermined; show "
            "three or more markers not in a line"
        )


def _pnp_starts(camera: CameraModel, model: FloatArray, pixels: FloatArray) -> list[FloatArray]:
    """Candidate poses (tool -> world, 4x4) of the markers in one camera: SQPnP's and AP3P's
    (on the first four markers; it returns every pose they allow). SQPnP alone sometimes lands
    on the far branch of the near-ambiguity of a small, shallow target seen from afar (2 of 80
    noisy views of the bench's marker cross in the tests); refined, the wrong branches end
    with a reprojection error far above the noise and the best fit wins."""
    to_world = np.linalg.inv(camera.world_to_camera)
    starts: list[FloatArray] = []
    for flag, count in ((cv2.SOLVEPNP_SQPNP, len(model)), (cv2.SOLVEPNP_AP3P, MIN_PNP_MARKERS)):
        try:
            found, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                model[:count].reshape(-1, 1, 3),
                pixels[:count].reshape(-1, 1, 2),
                camera.matrix,
                camera.distortion,
                flags=flag,
            )
        except cv2.error:
            continue  # a degenerate subset: the other solver's start stands
        for rvec, tvec in zip(rvecs[:found], tvecs[:found], strict=True):
            tool_to_camera = np.eye(4)
            tool_to_camera[:3, :3] = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]
            tool_to_camera[:3, 3] = np.asarray(tvec, dtype=np.float64).reshape(3)
            starts.append(np.asarray(to_world @ tool_to_camera, dtype=np.float64))
    if not starts:
        raise MultiviewError(f"camera {camera.name}: solvePnP found no pose of the markers")
    return starts


def pose_from_views(
    cameras: Sequence[CameraModel],
    model_mm: ArrayLike,
    pixels: ArrayLike,
    sigmas_px: ArrayLike | None = None,
    *,
    expected_pose: ArrayLike | None = None,
) -> ViewPose:
    """The tool pose (and its covariance) from the markers' ``pixels`` (cameras x markers x 2,
    NaN where a camera does not see a marker) whose tool-frame positions are ``model_mm``
    (markers x 3), by perspective-n-point (module docstring): one camera seeing four markers
    (or three, given ``expected_pose``, 4x4 tool -> world) is enough. ``sigmas_px`` (cameras x
    markers x 2): each centroid's 1-sigma, default each camera's ``pixel_sigma_px``."""
    model = np.asarray(model_mm, dtype=np.float64)
    if model.ndim != 2 or model.shape[1] != 3 or not np.all(np.isfinite(model)):
        raise MultiviewError(f"the markers' model must be finite M x 3, got shape {model.shape}")
    count = model.shape[0]
    observed = np.asarray(pixels, dtype=np.float64)
    if observed.shape != (len(cameras), count, 2):
        raise MultiviewError(
            f"expected pixels of shape ({len(cameras)} cameras, {count} markers, 2), got "
            f"{observed.shape}"
        )
    if sigmas_px is None:
        sigmas = np.empty_like(observed)
        for index, camera in enumerate(cameras):
            sigmas[index] = camera.pixel_sigma_px
    else:
        sigmas = np.asarray(sigmas_px, dtype=np.float64)
        if sigmas.shape != observed.shape:
            raise MultiviewError(f"sigmas of shape {sigmas.shape} for pixels {observed.shape}")
    seen = np.all(np.isfinite(observed), axis=2)
    observations = tuple((int(c), int(m)) for c, m in zip(*np.nonzero(seen), strict=True))
    if any(not np.all(sigmas[c, m] > 0) for c, m in observations):
        raise MultiviewError("pixel sigmas must be positive and finite")
    markers = sorted({m for _, m in observations})
    per_camera = seen.sum(axis=1)
    if len(markers) < MIN_POSE_MARKERS:
        raise MultiviewError(
            f"{len(markers)} marker(s) seen: a pose from the cameras' views needs "
            f"{MIN_POSE_MARKERS} or more ({MIN_PNP_MARKERS} in one camera without the "
            f"expected pose; markers per camera: {per_camera.tolist()})"
        )
    _check_spread(model[markers])
    best = int(np.argmax(per_camera))
    starts: list[FloatArray] = []
    if expected_pose is not None:
        expected = np.asarray(expected_pose, dtype=np.float64)
        if expected.shape != (4, 4) or not np.all(np.isfinite(expected)):
            raise MultiviewError(f"the expected pose must be a finite 4x4, got {expected.shape}")
        starts.append(expected)
    if per_camera[best] >= MIN_PNP_MARKERS:
        in_best = np.nonzero(seen[best])[0]
        starts.extend(_pnp_starts(cameras[best], model[in_best], observed[best, in_best]))
    elif not starts:
        raise MultiviewError(
            f"no camera sees {MIN_PNP_MARKERS} markers (markers per camera: "
            f"{per_camera.tolist()}): three points leave up to four poses; give the expected "
            "pose or show a fourth marker"
        )
    by_camera = [
        (c, np.array([m for cc, m in observations if cc == c], dtype=np.intp))
        for c in range(len(cameras))
        if per_camera[c]
    ]
    weights = np.vstack([1.0 / sigmas[c, ms].reshape(-1, 2) for c, ms in by_camera])

    def system(rotation: FloatArray, translation: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Whitened residuals and their Jacobian in (dt, dr) at a pose."""
        residual_rows: list[FloatArray] = []
        jacobian_rows: list[FloatArray] = []
        for c, ms in by_camera:
            arms = model[ms] @ rotation.T
            predicted, d_point = projection_jacobian(cameras[c], arms + translation)
            residual_rows.append(predicted - observed[c, ms])
            for arm, block in zip(arms, d_point, strict=True):
                jacobian_rows.append(block @ np.hstack([np.eye(3), -skew(arm)]))
        residual = np.vstack(residual_rows) * weights
        jacobian = np.vstack(jacobian_rows) * weights.reshape(-1, 1)
        return np.asarray(residual.ravel()), np.asarray(jacobian)

    def refine(start: FloatArray) -> tuple[float, FloatArray, FloatArray, FloatArray, FloatArray]:
        """Gauss-Newton from ``start``: cost, rotation, translation, residual, Jacobian."""
        rotation, translation = start[:3, :3].copy(), start[:3, 3].copy()
        residual, jacobian = system(rotation, translation)
        cost = float(residual @ residual)
        for _ in range(_MAX_ITERATIONS):
            step = np.linalg.lstsq(jacobian, -residual, rcond=None)[0]
            for _ in range(_MAX_HALVINGS):
                trial_rotation = Rotation.from_rotvec(step[3:]).as_matrix() @ rotation
                trial_translation = translation + step[:3]
                trial_residual, trial_jacobian = system(trial_rotation, trial_translation)
                trial_cost = float(trial_residual @ trial_residual)
                if trial_cost <= cost * (1.0 + 1e-12):
                    break
                step = 0.5 * step
            rotation, translation = trial_rotation, trial_translation
            residual, jacobian, cost = trial_residual, trial_jacobian, trial_cost
            if np.linalg.norm(step) < _STEP_TOLERANCE:
                break
        return cost, rotation, translation, residual, jacobian

    fits = [refine(start) for start in starts]
    cost, rotation, translation, residual, jacobian = min(fits, key=lambda fit: fit[0])
    for c, ms in by_camera:
        behind = int(np.sum(depths_mm(cameras[c], model[ms] @ rotation.T + translation) <= 0))
        if behind:
            raise MultiviewError(
                f"camera {cameras[c].name}: the fitted pose puts {behind} marker(s) behind it"
            )
    information = jacobian.T @ jacobian
    if not np.all(np.isfinite(information)) or np.linalg.cond(information) > _MAX_CONDITION:
        raise MultiviewError("the markers' views do not determine the tool's pose")
    covariance = np.linalg.inv(information)
    pose = np.eye(4)
    pose[:3, :3] = rotation
    pose[:3, 3] = translation
    ordered = tuple((c, int(m)) for c, ms in by_camera for m in ms)
    return ViewPose(
        pose=pose,
        covariance=0.5 * (covariance + covariance.T),
        chi2=cost,
        dof=2 * len(observations) - 6,
        residuals_px=residual.reshape(-1, 2) / weights,
        observations=ordered,
    )


def depth_sigma_mm(camera: CameraModel, fit: ViewPose) -> tuple[float, float]:
    """The fitted tool position's 1-sigma along ``camera``'s line of sight to it and the
    largest across it (mm): how much worse one camera sees depth."""
    centre = fit.pose[:3, 3]
    axis = centre - camera.centre_mm
    axis = axis / np.linalg.norm(axis)
    covariance = fit.covariance[:3, :3]
    along = float(axis @ covariance @ axis)
    projector = np.eye(3) - np.outer(axis, axis)
    across = float(np.linalg.eigvalsh(projector @ covariance @ projector)[-1])
    return math.sqrt(along), math.sqrt(max(across, 0.0))
