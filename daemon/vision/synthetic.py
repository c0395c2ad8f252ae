"""Synthetic laser-spot frames with known sub-pixel truth, and the Cramér–Rao bound they imply.

Used by the tests, the centroid benchmark and the simulated camera. Pixel (row r, column c)
covers ``[c - 0.5, c + 0.5] x [r - 0.5, r + 0.5]`` with its centre at (x = c, y = r), the
convention of the whole project (DESIGN.md "Centroid"). A pixel's value is the *mean* of the
continuous spot profile over its area (pixel integration), so the profile's amplitude is
``peak_fraction`` of full scale and a broad spot's brightest pixel is close to it.

Profiles:

* ``"gaussian"``: ``exp(-u²/2σx² - v²/2σy²)``; axis-aligned ellipses are integrated exactly
  with erf (separable), rotated ones (``angle_rad``) numerically.
* ``"flat_top"``: the tuned "sharp-edged circle" of thesis 4.7.1: a disc of radius
  ``flat_top_radius_px`` whose edge falls off as ``erfc((ρ - R) / (√2 σ))``, integrated
  numerically (6 x 6 Gauss–Legendre nodes per pixel; the rule is symmetric, so a rendered
  spot's centroid is its centre to ~1e-10 px, which the tests check).

Noise, in the order a camera adds it: photon (Poisson) noise on the electrons of spot and
background (``gain_e_per_count`` electrons per count), Gaussian read noise in counts, hot
pixels, then quantisation to integers and clipping at full scale (saturation).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.special import erf

Profile = Literal["gaussian", "flat_top"]

#: Gauss–Legendre nodes per pixel and axis for the profiles without a closed-form integral.
_QUADRATURE_NODES = 6
#: How far (in spot widths) a profile is evaluated; beyond it the profile is below 1e-12.
_SUPPORT_SIGMAS = 7.5


def full_scale(bit_depth: int) -> int:
    """Largest count a ``bit_depth``-bit pixel holds (white, 2**bit_depth - 1)."""
    return (1 << bit_depth) - 1


def _sigmas(sigma_px: float | tuple[float, float]) -> tuple[float, float]:
    sx, sy = (sigma_px, sigma_px) if isinstance(sigma_px, int | float) else sigma_px
    if sx <= 0 or sy <= 0:
        raise ValueError(f"sigma_px must be positive, got {sigma_px!r}")
    return float(sx), float(sy)


def pixel_gaussian(
    centres: NDArray[np.float64], middle: float, sigma: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Share of a unit-area Gaussian (centre ``middle``) falling in each pixel
    ``[c - 0.5, c + 0.5]``, via erf, and its derivatives with respect to ``middle`` and
    ``sigma`` (for Fisher information and fits)."""
    lower = (centres - 0.5 - middle) / sigma
    upper = (centres + 0.5 - middle) / sigma
    share = 0.5 * (erf(upper / math.sqrt(2.0)) - erf(lower / math.sqrt(2.0)))
    density_lower = np.exp(-0.5 * lower * lower) / math.sqrt(2.0 * math.pi)
    density_upper = np.exp(-0.5 * upper * upper) / math.sqrt(2.0 * math.pi)
    d_middle = -(density_upper - density_lower) / sigma
    d_sigma = -(upper * density_upper - lower * density_lower) / sigma
    return np.asarray(share), np.asarray(d_middle), np.asarray(d_sigma)


def _profile_on_grid(
    columns: NDArray[np.float64],
    rows: NDArray[np.float64],
    *,
    centre_xy: tuple[float, float],
    sigma_xy: tuple[float, float],
    profile: Profile,
    flat_top_radius_px: float,
    angle_rad: float,
) -> NDArray[np.float64]:
    """Pixel-mean of the unit-amplitude profile on the pixels ``rows x columns``."""
    x0, y0 = centre_xy
    sx, sy = sigma_xy
    if profile == "gaussian" and angle_rad == 0.0:
        # pixel mean of the unit-amplitude profile = share of the unit-area one x σ√(2π)
        gx = pixel_gaussian(columns, x0, sx)[0] * (sx * math.sqrt(2.0 * math.pi))
        gy = pixel_gaussian(rows, y0, sy)[0] * (sy * math.sqrt(2.0 * math.pi))
        return np.outer(gy, gx)
    nodes, weights = np.polynomial.legendre.leggauss(_QUADRATURE_NODES)
    offsets = 0.5 * nodes  # nodes on [-1, 1] -> pixel [-0.5, 0.5]
    xs = (columns[:, None] + offsets[None, :]).ravel() - x0  # (nc*q,)
    ys = (rows[:, None] + offsets[None, :]).ravel() - y0  # (nr*q,)
    dx = xs[None, :]
    dy = ys[:, None]
    cos, sin = math.cos(angle_rad), math.sin(angle_rad)
    u = cos * dx + sin * dy
    v = -sin * dx + cos * dy
    if profile == "gaussian":
        values = np.exp(-0.5 * ((u / sx) ** 2 + (v / sy) ** 2))
    else:
        edge = 0.5 * (sx + sy)
        rho = np.hypot(u, v)
        values = 0.5 * (1.0 - erf((rho - flat_top_radius_px) / (math.sqrt(2.0) * edge)))
    q = _QUADRATURE_NODES
    w = 0.5 * weights  # weights sum to 1 over a pixel
    values = values.reshape(rows.size, q, columns.size, q)
    return np.asarray(np.einsum("iajb,a,b->ij", values, w, w), dtype=np.float64)


def _support_half_width(sigma_xy: tuple[float, float], flat_top_radius_px: float) -> float:
    return _SUPPORT_SIGMAS * max(sigma_xy) + flat_top_radius_px + 1.0


def expected_spot(
    shape: tuple[int, int],
    centre_xy: tuple[float, float],
    sigma_px: float | tuple[float, float] = 3.0,
    amplitude: float = 1.0,
    *,
    profile: Profile = "gaussian",
    flat_top_radius_px: float = 0.0,
    angle_rad: float = 0.0,
) -> NDArray[np.float64]:
    """The noise-free spot alone (no background), ``amplitude`` times the unit profile."""
    sigma_xy = _sigmas(sigma_px)
    if profile == "flat_top" and flat_top_radius_px <= 0:
        raise ValueError("a flat_top profile needs flat_top_radius_px > 0")
    height, width = shape
    image = np.zeros(shape, dtype=np.float64)
    reach = _support_half_width(sigma_xy, flat_top_radius_px)
    x0, y0 = centre_xy
    c0, c1 = max(0, math.floor(x0 - reach)), min(width, math.ceil(x0 + reach) + 1)
    r0, r1 = max(0, math.floor(y0 - reach)), min(height, math.ceil(y0 + reach) + 1)
    if c0 >= c1 or r0 >= r1:
        return image  # the spot is entirely off the chip
    columns = np.arange(c0, c1, dtype=np.float64)
    rows = np.arange(r0, r1, dtype=np.float64)
    image[r0:r1, c0:c1] = amplitude * _profile_on_grid(
        columns,
        rows,
        centre_xy=(x0, y0),
        sigma_xy=sigma_xy,
        profile=profile,
        flat_top_radius_px=flat_top_radius_px,
        angle_rad=angle_rad,
    )
    return image


def _background_plane(
    shape: tuple[int, int], background: float, gradient_xy: tuple[float, float]
) -> NDArray[np.float64] | float:
    """Background level (counts) with a linear gradient about the frame centre."""
    if gradient_xy == (0.0, 0.0):
        return background
    height, width = shape
    gx, gy = gradient_xy
    x = (np.arange(width) - (width - 1) / 2.0) * gx
    y = (np.arange(height) - (height - 1) / 2.0) * gy
    return np.asarray(background + y[:, None] + x[None, :], dtype=np.float64)


def render_spot(
    shape: tuple[int, int] = (582, 752),
    centre_xy: tuple[float, float] | None = None,
    sigma_px: float | tuple[float, float] = 3.0,
    peak_fraction: float = 0.5,
    *,
    bit_depth: int | None = 16,
    rng: np.random.Generator | None = None,
    background: float = 0.0,
    gradient_xy: tuple[float, float] = (0.0, 0.0),
    read_noise_counts: float = 0.0,
    photon_noise: bool = True,
    gain_e_per_count: float = 1.0,
    hot_pixels: int = 0,
    hot_pixel_value: float | None = None,
    profile: Profile = "gaussian",
    flat_top_radius_px: float = 0.0,
    angle_rad: float = 0.0,
) -> NDArray[np.generic]:
    """A camera frame of one laser spot centred at ``centre_xy`` (x, y in px).

    ``peak_fraction`` is the profile's amplitude above the background as a fraction of full
    scale (``> 1`` gives a saturated spot). ``background`` (counts) is the mean dark level at
    the frame centre, ``gradient_xy`` its slope in counts per px. Noise is drawn only from
    ``rng``: without one the frame is the noise-free expectation (still quantised). Hot pixels
    (``hot_pixels`` random positions, at ``hot_pixel_value`` counts, default full scale) need
    ``rng`` too.

    Returns ``uint8`` for 8-bit frames, ``uint16`` for 12- and 16-bit ones, and the
    unquantised, unclipped ``float64`` expectation plus noise when ``bit_depth`` is None (the
    amplitude then refers to a 16-bit full scale).
    """
    if bit_depth not in (None, 8, 12, 16):
        raise ValueError(f"bit_depth must be 8, 12, 16 or None, got {bit_depth!r}")
    white = full_scale(16 if bit_depth is None else bit_depth)
    if centre_xy is None:
        centre_xy = ((shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0)
    signal = expected_spot(
        shape,
        centre_xy,
        sigma_px,
        peak_fraction * white,
        profile=profile,
        flat_top_radius_px=flat_top_radius_px,
        angle_rad=angle_rad,
    )
    signal += _background_plane(shape, background, gradient_xy)
    return camera_noise(
        signal,
        bit_depth=bit_depth,
        rng=rng,
        read_noise_counts=read_noise_counts,
        photon_noise=photon_noise,
        gain_e_per_count=gain_e_per_count,
        hot_pixels=hot_pixels,
        hot_pixel_value=hot_pixel_value,
    )


def camera_noise(
    signal: NDArray[np.float64],
    *,
    bit_depth: int | None = 16,
    rng: np.random.Generator | None = None,
    read_noise_counts: float = 0.0,
    photon_noise: bool = True,
    gain_e_per_count: float = 1.0,
    hot_pixels: int = 0,
    hot_pixel_value: float | None = None,
) -> NDArray[np.generic]:
    """What a camera does to the expected frame ``signal`` (counts, float): the noise of
    :func:`render_spot` (module docstring's order), quantisation and clipping; the returned
    type as :func:`render_spot`'s. Also used by :mod:`daemon.vision.markers` (several
    markers in one frame)."""
    if bit_depth not in (None, 8, 12, 16):
        raise ValueError(f"bit_depth must be 8, 12, 16 or None, got {bit_depth!r}")
    white = full_scale(16 if bit_depth is None else bit_depth)
    signal = np.array(signal, dtype=np.float64)  # the caller's expectation stays as it was
    shape = signal.shape
    if rng is not None and photon_noise:
        electrons = rng.poisson(np.clip(signal, 0.0, None) * gain_e_per_count)
        signal = electrons / gain_e_per_count
    if rng is not None and read_noise_counts > 0:
        signal += rng.normal(0.0, read_noise_counts, size=shape)
    if hot_pixels > 0:
        if rng is None:
            raise ValueError("hot pixels are placed at random: pass rng")
        flat = rng.choice(signal.size, size=hot_pixels, replace=False)
        signal.flat[flat] = white if hot_pixel_value is None else hot_pixel_value
    if bit_depth is None:
        return signal
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    return np.clip(np.rint(signal), 0, white).astype(dtype)


def cramer_rao_bound(
    shape: tuple[int, int],
    centre_xy: tuple[float, float],
    sigma_px: float | tuple[float, float] = 3.0,
    peak_fraction: float = 0.5,
    bit_depth: int = 16,
    *,
    background: float = 0.0,
    read_noise_counts: float = 0.0,
    gain_e_per_count: float = 1.0,
    profile: Profile = "gaussian",
    flat_top_radius_px: float = 0.0,
    angle_rad: float = 0.0,
) -> tuple[float, float]:
    """1-sigma Cramér–Rao bound (px) on the spot's x and y for one frame of this setting.

    Fisher information of the pixel-integrated spot under Poisson photon noise plus Gaussian
    read and quantisation noise (variance ``mu/g + r² + 1/12`` counts² per pixel), for the
    unknowns x, y, amplitude and background (inverted jointly). Saturated pixels
    (expectation at or above full scale) carry no information and are left out, so for a
    saturated spot this is the bound of an ideal estimator that ignores them.
    """
    white = full_scale(bit_depth)
    sigma_xy = _sigmas(sigma_px)
    reach = _support_half_width(sigma_xy, flat_top_radius_px)
    x0, y0 = centre_xy
    c0, c1 = max(0, math.floor(x0 - reach)), min(shape[1], math.ceil(x0 + reach) + 1)
    r0, r1 = max(0, math.floor(y0 - reach)), min(shape[0], math.ceil(y0 + reach) + 1)
    columns = np.arange(c0, c1, dtype=np.float64)
    rows = np.arange(r0, r1, dtype=np.float64)
    amplitude = peak_fraction * white

    def unit(cx: float, cy: float) -> NDArray[np.float64]:
        return _profile_on_grid(
            columns,
            rows,
            centre_xy=(cx, cy),
            sigma_xy=sigma_xy,
            profile=profile,
            flat_top_radius_px=flat_top_radius_px,
            angle_rad=angle_rad,
        )

    step = 1e-4  # central differences: O(step²) = 1e-8 relative error
    shape_now = unit(x0, y0)
    d_x = amplitude * (unit(x0 + step, y0) - unit(x0 - step, y0)) / (2 * step)
    d_y = amplitude * (unit(x0, y0 + step) - unit(x0, y0 - step)) / (2 * step)
    mean = amplitude * shape_now + background
    variance = np.clip(mean, 0.0, None) / gain_e_per_count + read_noise_counts**2 + 1.0 / 12.0
    informative = mean < white
    derivatives = np.stack([d_x, d_y, shape_now, np.ones_like(mean)])[:, informative]
    weights = 1.0 / variance[informative]
    fisher = (derivatives * weights) @ derivatives.T
    covariance = np.linalg.inv(fisher)
    return math.sqrt(covariance[0, 0]), math.sqrt(covariance[1, 1])
