"""The pixel-integrated Gaussian model of a spot (daemon/vision/synthetic.py
``pixel_gaussian``): its weighted fit, which refines the robust centroid where rounding or
saturation bias the moments, and the Cramér-Rao bound the centroid reports as its 1-sigma.
Pure code: arrays in, results out."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from daemon.vision.photon_transfer import NoiseModel, estimate_noise_model
from daemon.vision.synthetic import pixel_gaussian

#: the fit has converged when its step moves the centre by less than this (the robust
#: centroid's own tolerance)
TOLERANCE_PX = 1e-5
_MAX_ITERATIONS = 30
#: The fit that gives the photon-transfer residuals stops at this step: its residuals then
#: differ from the converged ones by ~1e-3 of the spot's slope, far under the noise.
_TRANSFER_TOLERANCE_PX = 1e-3


@dataclass(frozen=True, slots=True)
class SpotFit:
    x: float
    y: float
    flux: float
    sigma_x: float
    sigma_y: float
    reduced_chi2: float  # weighed squared residual per degree of freedom (~1: the model fits)

    def model(self, columns: NDArray[np.float64], rows: NDArray[np.float64]) -> NDArray[np.float64]:
        """The fitted spot (counts above the background) on the pixels ``rows`` x ``columns``."""
        share_x, _, _ = pixel_gaussian(columns, self.x, self.sigma_x)
        share_y, _, _ = pixel_gaussian(rows, self.y, self.sigma_y)
        return self.flux * np.outer(share_y, share_x)


def fit_spot(
    excess: NDArray[np.float64],
    usable: NDArray[np.bool_],
    columns: NDArray[np.float64],
    rows: NDArray[np.float64],
    start: tuple[float, float, float, float],
    *,
    noise_model: NoiseModel,
    tolerance_px: float = TOLERANCE_PX,
) -> SpotFit | None:
    """Least-squares fit of a pixel-integrated Gaussian (x, y, flux, σx, σy) to the
    ``usable`` pixels of the background-subtracted window; None if it does not converge.

    Used where moments fall short of the bound. A partly saturated spot: moments of a clipped
    spot are biased with its sub-pixel position (by ~0.006 px for a spot saturated to 3x full
    scale), since the pixel values jump where the spot crosses full scale and the sampled
    moments alias that kink; its unsaturated flanks are undistorted. A quantised frame (noise
    under ``daemon.vision.centroid_robust._QUANTISED_NOISE_COUNTS``): see there. A model that
    knows the pixel
    integration fits either without that bias (Gauss–Newton, Levenberg damping, weights
    1/variance of ``noise_model`` at each pixel's value). Also the model whose residuals give
    the frame's own noise model when the gain is unknown
    (:func:`daemon.vision.photon_transfer.estimate_noise_model`).
    """
    x, y, sx, sy = start
    data = excess[usable]
    whole = bool(usable.all())  # no saturated pixel: plain ravels instead of masked copies
    # equal weights on every pixel (the photon-transfer fit): each Jacobian column is an
    # outer product, so the normal equations come from 1-D products (O(pixels) a step
    # instead of O(5² pixels)); numerically the same equations
    separable = whole and noise_model.slope == 0.0
    weights = 1.0 / noise_model.variance(data)

    def pick(values: NDArray[np.float64]) -> NDArray[np.float64]:
        return values.ravel() if whole else values[usable]

    share_x, _, _ = pixel_gaussian(columns, x, sx)
    share_y, _, _ = pixel_gaussian(rows, y, sy)
    model_shape = pick(np.outer(share_y, share_x))
    flux = float((weights * model_shape) @ data) / float((weights * model_shape) @ model_shape)
    damping = 1e-3
    for _ in range(_MAX_ITERATIONS):
        share_x, dx_middle, dx_sigma = pixel_gaussian(columns, x, sx)
        share_y, dy_middle, dy_sigma = pixel_gaussian(rows, y, sy)
        if separable:
            normal, gradient, chi2 = _separable_equations(
                excess, flux, (share_x, dx_middle, dx_sigma), (share_y, dy_middle, dy_sigma)
            )
            chi2 *= float(weights[0])
        else:
            # rows, not columns: (5, pixels) products are 3x faster than (pixels, 5) ones
            jacobian = np.stack(
                [
                    pick(np.outer(share_y, dx_middle)),
                    pick(np.outer(dy_middle, share_x)),
                    pick(np.outer(share_y, share_x)),
                    pick(np.outer(share_y, dx_sigma)),
                    pick(np.outer(dy_sigma, share_x)),
                ]
            )
            residual = data - flux * jacobian[2]
            jacobian[[0, 1, 3, 4]] *= flux
            normal = (jacobian * weights) @ jacobian.T
            gradient = jacobian @ (weights * residual)
            chi2 = float(weights @ residual**2)
        normal[np.diag_indices(5)] *= 1.0 + damping
        try:
            step = np.linalg.solve(normal, gradient)
        except np.linalg.LinAlgError:
            return None
        x += float(step[0])
        y += float(step[1])
        flux += float(step[2])
        sx = max(0.3, sx + float(step[3]))
        sy = max(0.3, sy + float(step[4]))
        if abs(step[0]) < tolerance_px and abs(step[1]) < tolerance_px:
            # the residual of the last step's start: the step is too small to change it
            degrees = max(1, data.size - 5)
            return SpotFit(x, y, flux, sx, sy, chi2 / degrees)
    return None


def frame_noise_model(
    excess: NDArray[np.float64],
    usable: NDArray[np.bool_],
    columns: NDArray[np.float64],
    rows: NDArray[np.float64],
    start: tuple[float, float, float, float],
    *,
    offset: float,
) -> tuple[NoiseModel | None, tuple[float, float, float, float]]:
    """The frame's own noise model (photon transfer, daemon/vision/photon_transfer.py) on
    the residuals of a fit with equal weights (the weights being what is measured), or None
    if that fit fails; and where a refining fit should start: where this one ended, when it
    stayed within a pixel of ``start``."""
    plain = fit_spot(
        excess,
        usable,
        columns,
        rows,
        start,
        noise_model=NoiseModel(offset, 0.0),
        tolerance_px=_TRANSFER_TOLERANCE_PX,
    )
    if plain is None:
        return None, start
    measured = estimate_noise_model(excess, plain.model(columns, rows), usable, offset=offset)
    if abs(plain.x - start[0]) < 1.0 and abs(plain.y - start[1]) < 1.0:
        start = (plain.x, plain.y, plain.sigma_x, plain.sigma_y)  # a step or two to go
    return measured, start


def _separable_equations(
    excess: NDArray[np.float64],
    flux: float,
    along_x: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    along_y: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Unweighted normal matrix, gradient and squared residual of the fit's step, from the
    separable Jacobian: column k is ``scale_k * outer(row_k, column_k)``, and
    ``<outer(a, b), outer(c, d)> = (a . c)(b . d)``."""
    share_x, dx_middle, dx_sigma = along_x
    share_y, dy_middle, dy_sigma = along_y
    row_factors = np.stack([share_y, dy_middle, share_y, share_y, dy_sigma])
    column_factors = np.stack([dx_middle, share_x, share_x, dx_sigma, share_x])
    scale = np.array([flux, flux, 1.0, flux, flux])
    residual = excess - flux * np.outer(share_y, share_x)
    normal = (row_factors @ row_factors.T) * (column_factors @ column_factors.T)
    normal *= np.outer(scale, scale)
    gradient = scale * np.einsum("ki,ki->k", row_factors @ residual, column_factors)
    return normal, gradient, float(np.vdot(residual, residual))


def centroid_uncertainty(
    dx: NDArray[np.float64],
    dy: NDArray[np.float64],
    *,
    signal: float,
    var_x: float,
    var_y: float,
    background: float,
    white: int,
    noise_model: NoiseModel,
) -> tuple[float, float]:
    """Cramér–Rao-style 1-sigma (px) of x and y for the measured spot.

    Models the spot as the pixel-integrated Gaussian with the measured signal and
    second-moment widths, and takes the Fisher information of its position under the
    pixels' ``noise_model`` (shot noise of the spot over the background's read noise, shot
    noise and rounding); saturated pixels carry none. For a symmetric spot the position decouples
    from amplitude and background, so ``1 / sqrt(I_xx)`` is the bound.
    """
    sx, sy = math.sqrt(var_x), math.sqrt(var_y)
    share_x, slope_x, _ = pixel_gaussian(dx, 0.0, sx)
    share_y, slope_y, _ = pixel_gaussian(dy, 0.0, sy)
    excess = signal * np.outer(share_y, share_x)
    mean = excess + background
    variance = noise_model.variance(excess)
    information = np.where(mean < white, signal**2 / variance, 0.0)
    fisher_x = float(share_y**2 @ information @ slope_x**2)
    fisher_y = float(slope_y**2 @ information @ share_x**2)
    return (
        1.0 / math.sqrt(fisher_x) if fisher_x > 0 else math.inf,
        1.0 / math.sqrt(fisher_y) if fisher_y > 0 else math.inf,
    )
