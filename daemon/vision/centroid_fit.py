"""The pixel-integrated Gaussian model of a spot (daemon/vision/synthetic.py
``pixel_gaussian``): its weighted fit, which refines the robust centroid where rounding or
saturation bias the moments, and the Cramér-Rao bound the centroid reports as its 1-sigma.
Pure code: arrays in, results out."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from daemon.vision.synthetic import pixel_gaussian

QUANTISATION_VARIANCE = 1.0 / 12.0  # counts², rounding to integers
#: the fit has converged when its step moves the centre by less than this (the robust
#: centroid's own tolerance)
TOLERANCE_PX = 1e-5


@dataclass(frozen=True, slots=True)
class SpotFit:
    x: float
    y: float
    flux: float
    sigma_x: float
    sigma_y: float
    reduced_chi2: float  # weighed squared residual per degree of freedom (~1: the model fits)


def fit_spot(
    excess: NDArray[np.float64],
    usable: NDArray[np.bool_],
    columns: NDArray[np.float64],
    rows: NDArray[np.float64],
    start: tuple[float, float, float, float],
    *,
    noise: float,
    gain_e_per_count: float,
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
    1/variance: photon noise ``value / gain`` plus the background's noise and rounding).
    """
    x, y, sx, sy = start
    data = excess[usable]
    weights = 1.0 / (
        np.clip(data, 0.0, None) / gain_e_per_count + noise * noise + QUANTISATION_VARIANCE
    )
    share_x, _, _ = pixel_gaussian(columns, x, sx)
    share_y, _, _ = pixel_gaussian(rows, y, sy)
    model_shape = np.outer(share_y, share_x)[usable]
    flux = float((weights * model_shape) @ data) / float((weights * model_shape) @ model_shape)
    damping = 1e-3
    for _ in range(30):
        share_x, dx_middle, dx_sigma = pixel_gaussian(columns, x, sx)
        share_y, dy_middle, dy_sigma = pixel_gaussian(rows, y, sy)
        jacobian = np.stack(
            [
                flux * np.outer(share_y, dx_middle)[usable],
                flux * np.outer(dy_middle, share_x)[usable],
                np.outer(share_y, share_x)[usable],
                flux * np.outer(share_y, dx_sigma)[usable],
                flux * np.outer(dy_sigma, share_x)[usable],
            ],
            axis=1,
        )
        residual = data - flux * jacobian[:, 2]
        normal = jacobian.T @ (jacobian * weights[:, None])
        gradient = jacobian.T @ (weights * residual)
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
        if abs(step[0]) < TOLERANCE_PX and abs(step[1]) < TOLERANCE_PX:
            # the residual of the last step's start: the step is too small to change it
            degrees = max(1, data.size - 5)
            return SpotFit(x, y, flux, sx, sy, float(weights @ residual**2) / degrees)
    return None


def centroid_uncertainty(
    dx: NDArray[np.float64],
    dy: NDArray[np.float64],
    *,
    signal: float,
    var_x: float,
    var_y: float,
    background: float,
    white: int,
    gain_e_per_count: float,
    read_noise_e: float,
) -> tuple[float, float]:
    """Cramér–Rao-style 1-sigma (px) of x and y for the measured spot.

    Models the spot as the pixel-integrated Gaussian with the measured signal and
    second-moment widths, and takes the Fisher information of its position under photon
    noise (variance ``mu / gain``), read noise ``(read_noise_e / gain)²`` and quantisation
    (1/12 count²); saturated pixels carry none. For a symmetric spot the position decouples
    from amplitude and background, so ``1 / sqrt(I_xx)`` is the bound.
    """
    sx, sy = math.sqrt(var_x), math.sqrt(var_y)
    share_x, slope_x, _ = pixel_gaussian(dx, 0.0, sx)
    share_y, slope_y, _ = pixel_gaussian(dy, 0.0, sy)
    mean = signal * np.outer(share_y, share_x) + background
    variance = mean / gain_e_per_count + (read_noise_e / gain_e_per_count) ** 2
    variance += QUANTISATION_VARIANCE
    information = np.where(mean < white, signal**2 / variance, 0.0)
    fisher_x = float(share_y**2 @ information @ slope_x**2)
    fisher_y = float(slope_y**2 @ information @ share_x**2)
    return (
        1.0 / math.sqrt(fisher_x) if fisher_x > 0 else math.inf,
        1.0 / math.sqrt(fisher_y) if fisher_y > 0 else math.inf,
    )
