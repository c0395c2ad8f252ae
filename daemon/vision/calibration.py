"""Camera calibration from the robot itself (issue 18): pixel pitch and rotation, pure.

The robot moves the laser spot through known offsets (u, v) in the camera plane: u along the
robot's world x, v along world -z (image rows grow downwards; drivers/sim/bench.py). The spot's
centroid (x, y) in pixels then follows

    x = x0 + (cos t * u - sin t * v) / p_x
    y = y0 + (sin t * u + cos t * v) / p_y

with p_x, p_y the calibrated micrometres per pixel (``camera.um_per_px``) and t the camera's
rotation from the robot's axes (``camera.rotation_deg``). Each image axis is an ordinary linear
least-squares fit x = x0 + a u + b v (and y = y0 + c u + d v); then p_x = 1 / |(a, b)|,
t_x = atan2(-b, a), p_y = 1 / |(c, d)|, t_y = atan2(c, d). The two axes' angles agree for a
chip square to the optics; their difference is reported as ``skew_deg``, and t is their mean.
Standard errors come from each fit's residual variance, s^2 (A^T A)^-1, propagated to
(p, t) through the first-order derivatives (the two axes' fits are independent).

:func:`camera_to_robot` is the inverse the run needs: a spot drift measured in chip micrometres
(pixels x um_per_px) back to a robot offset along world x and z.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

#: Fewest points with a residual to estimate the noise from: 3 parameters per axis, plus one.
MIN_POINTS = 4
#: Relative condition number of the design beyond which the offsets do not span the plane
#: (all on one line, or all the same): the fit is singular.
MAX_CONDITION = 1e8


class CalibrationError(ValueError):
    """The measurements cannot give a calibration; ``str()`` is the one line for the user."""


@dataclass(frozen=True, slots=True)
class CameraCalibration:
    """The result: micrometres per pixel along the image axes and the rotation, with their
    1-sigma standard errors; ``residual_px`` is the RMS of the fit's residuals."""

    um_per_px: tuple[float, float]
    um_per_px_se: tuple[float, float]
    rotation_deg: float
    rotation_se_deg: float
    skew_deg: float  # t_y - t_x: non-orthogonality of the image axes seen by the robot
    residual_px: float
    points: int

    def toml(self) -> str:
        """The ``[camera]`` keys to paste into (or merge with) the settings file."""
        return (
            "[camera]\n"
            f"um_per_px = [{self.um_per_px[0]:.5f}, {self.um_per_px[1]:.5f}]"
            f"  # +- {self.um_per_px_se[0]:.5f}, {self.um_per_px_se[1]:.5f} (1 sigma)\n"
            f"rotation_deg = {self.rotation_deg:.4f}  # +- {self.rotation_se_deg:.4f} (1 sigma)\n"
        )


def pattern_offsets_um(size_um: float, step_um: float) -> list[tuple[float, float]]:
    """The square grid of (u, v) offsets from -size to +size every step, centre included,
    visited row by row in a serpentine (short moves)."""
    if size_um <= 0 or step_um <= 0:
        raise CalibrationError("the pattern's size and step must be positive")
    if step_um > size_um:
        raise CalibrationError(
            f"the step ({step_um:g} um) is larger than the pattern's half-width ({size_um:g} um)"
        )
    count = math.floor(size_um / step_um + 1e-9)
    ticks = [k * step_um for k in range(-count, count + 1)]
    offsets = []
    for row, v in enumerate(ticks):
        for u in ticks if row % 2 == 0 else reversed(ticks):
            offsets.append((u, v))
    return offsets


def _axis_fit(
    design: NDArray[np.float64], values: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Least squares ``values = design @ beta``: beta, its covariance, the residuals."""
    solution = np.linalg.lstsq(design, values, rcond=None)[0]
    beta: NDArray[np.float64] = np.asarray(solution, dtype=np.float64)
    residuals: NDArray[np.float64] = values - design @ beta
    dof = design.shape[0] - design.shape[1]
    variance = float(residuals @ residuals) / dof
    covariance: NDArray[np.float64] = variance * np.linalg.inv(design.T @ design)
    return beta, covariance, residuals


def fit_calibration(
    offsets_um: Sequence[tuple[float, float]], centroids_px: Sequence[tuple[float, float]]
) -> CameraCalibration:
    """Fit pitch and rotation to spot centroids measured at known offsets (module docstring)."""
    if len(offsets_um) != len(centroids_px):
        raise CalibrationError(
            f"{len(offsets_um)} offsets but {len(centroids_px)} centroids: they must pair up"
        )
    if len(offsets_um) < MIN_POINTS:
        raise CalibrationError(
            f"{len(offsets_um)} points: at least {MIN_POINTS} are needed to fit and estimate "
            "the errors"
        )
    uv = np.asarray(offsets_um, dtype=np.float64)
    xy = np.asarray(centroids_px, dtype=np.float64)
    if not (np.all(np.isfinite(uv)) and np.all(np.isfinite(xy))):
        raise CalibrationError("the offsets and centroids must be finite")
    centred = uv - uv.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False)
    if singular[-1] <= 0 or singular[0] / singular[-1] > MAX_CONDITION:
        raise CalibrationError(
            "singular fit: the offsets do not span the camera plane (all on one line or the "
            "same point)"
        )
    design = np.column_stack([np.ones(len(uv)), uv])
    (_, a, b), cov_x, res_x = _axis_fit(design, xy[:, 0])
    (_, c, d), cov_y, res_y = _axis_fit(design, xy[:, 1])
    norm_x, norm_y = math.hypot(a, b), math.hypot(c, d)
    if norm_x == 0 or norm_y == 0:
        raise CalibrationError(
            "singular fit: the spot did not move on the chip along " + ("x" if norm_x == 0 else "y")
        )
    pitch_x, pitch_y = 1.0 / norm_x, 1.0 / norm_y
    angle_x, angle_y = math.atan2(-b, a), math.atan2(c, d)
    # first-order propagation: d(1/|g|)/dg = -g/|g|^3 ; d atan2(-b, a) = (b da - a db)/|g|^2,
    # d atan2(c, d) = (d dc - c dd)/|g|^2
    g_px = np.array([-a, -b]) / norm_x**3
    g_py = np.array([-c, -d]) / norm_y**3
    g_tx = np.array([b, -a]) / norm_x**2
    g_ty = np.array([d, -c]) / norm_y**2
    var_px = float(g_px @ cov_x[1:, 1:] @ g_px)
    var_py = float(g_py @ cov_y[1:, 1:] @ g_py)
    var_t = (float(g_tx @ cov_x[1:, 1:] @ g_tx) + float(g_ty @ cov_y[1:, 1:] @ g_ty)) / 4.0
    skew = math.remainder(angle_y - angle_x, 2 * math.pi)
    rotation = angle_x + skew / 2.0
    residual = float(np.sqrt(np.mean(np.concatenate([res_x, res_y]) ** 2)))
    return CameraCalibration(
        um_per_px=(pitch_x, pitch_y),
        um_per_px_se=(math.sqrt(var_px), math.sqrt(var_py)),
        rotation_deg=math.degrees(math.remainder(rotation, 2 * math.pi)),
        rotation_se_deg=math.degrees(math.sqrt(var_t)),
        skew_deg=math.degrees(skew),
        residual_px=residual,
        points=len(uv),
    )


def camera_to_robot(
    drift_um: tuple[float, float], rotation_deg: float
) -> tuple[float, float, float]:
    """A spot drift in chip micrometres (pixels x ``camera.um_per_px``) as the robot offset
    that produced it: (world x, y, z) um. Inverse of the model: (u, v) = R(-t) (dx, dy), then
    x = u, z = -v; the camera sees nothing along world y (0)."""
    angle = math.radians(rotation_deg)
    cos, sin = math.cos(angle), math.sin(angle)
    dx, dy = drift_um
    u = cos * dx + sin * dy
    v = -sin * dx + cos * dy
    return (u, 0.0, -v)
