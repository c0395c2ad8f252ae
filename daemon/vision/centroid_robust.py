"""The robust, near-optimal spot centroid the daemon measures with (see :func:`robust_centroid`).
Pure code: arrays in, results out. Coordinates as in daemon/vision/centroid.py."""

from __future__ import annotations

import functools
import math
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from daemon.vision.centroid_fit import (
    TOLERANCE_PX,
    centroid_uncertainty,
    fit_spot,
    frame_noise_model,
)
from daemon.vision.centroid_result import CentroidError, CentroidResult, GainSource
from daemon.vision.photon_transfer import QUANTISATION_VARIANCE, NoiseModel
from daemon.vision.synthetic import full_scale

# Robust method tuning (see robust_centroid for the reasoning behind each).
_DETECTION_SIGMAS = 8.0  # spot must stand this far above the smoothed image's noise
_THRESHOLD_SIGMAS = 3.0  # threshold over the local background, in noise sigmas
# window half-size in second-moment widths: ISO 11146 integrates over 3 beam diameters (±6σ)
# without a threshold; with 3 noise sigmas subtracted, nothing beyond ±4σ weighs any more
_WINDOW_SIGMAS = 4.0
_MIN_HALF_WIDTH = 3.0  # px
_MIN_FRAME_PX = 16  # room for a window and its background ring
_RING_PX = 3  # width of the band around the window that gives the local background
_MAX_ITERATIONS = 40
_EDGE_SHIFT_PX = 1e-3  # a frame edge that would move the centroid more than this cuts the spot
_LOW_SNR = 20.0
# Below this background noise (counts RMS) rounding is no longer dithered by noise: a spot's
# faint flanks round the same way frame after frame, the errors of windowed moments become a
# function of the sub-pixel position, and moments stay 1.2-1.5x the Cramér-Rao bound (8-bit
# frames of a 16-bit-class sensor). A fit of the pixel-integrated Gaussian that weighs each
# pixel by its photon + quantisation variance reaches the bound there (benchmarks/
# bench_centroid.py), so such frames are refined by it. 0.5 count: quantisation (1/12
# count²) is then a quarter or more of the pixel variance.
_QUANTISED_NOISE_COUNTS = 0.5
# ... but only where a Gaussian describes the spot: fits of Gaussian spots end at a reduced
# chi² of ~1 (~0.1 without noise), of flat-top or rotated elliptical ones at 300 and more,
# whose fitted centre would then be biased; those keep their moments (flag
# "quantised-moments").
_FIT_MAX_REDUCED_CHI2 = 4.0
#: the 8 neighbours of a pixel (dilating with it gives their maximum)
_NEIGHBOURS = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], dtype=np.uint8)
_MIN_REDUCED_FRAME_PX = 64  # smaller frames are searched at full resolution
_FILTER_DTYPES = tuple(np.dtype(t) for t in (np.uint8, np.uint16, np.float32))


def _locate(image: NDArray[Any]) -> tuple[float, float, float]:
    """Coarse spot position (x, y) and 1-sigma width (px) on a reduced, smoothed copy.

    2 x 2 means, a 3 x 3 median, a ``pyrDown`` (4x fewer pixels a side in all) and a 3 x 3 box
    filter integrate a ~12 x 12 px neighbourhood: isolated hot pixels are removed and a noise
    spike keeps ~1/144 of its value while the spot weighs its integrated signal, so they
    cannot capture the search. Costs ~0.15 ms on a 752 x 582 frame instead of smoothing at
    full resolution.
    """
    small = image if image.dtype in _FILTER_DTYPES else image.astype(np.float32)
    scale, offset = 1, 0.0
    if min(small.shape) >= _MIN_REDUCED_FRAME_PX:
        # exact 2 x 2 means (bilinear at exactly half size), 3x cheaper than a pyrDown here
        half_rows, half_columns = small.shape[0] // 2, small.shape[1] // 2
        small = cv2.resize(
            small[: 2 * half_rows, : 2 * half_columns],
            (half_columns, half_rows),
            interpolation=cv2.INTER_LINEAR,
        )
        # a hot pixel is now inside one pixel, at a quarter of its value: the 3 x 3 median
        # removes it (and any pair); a spot wider than a pixel passes
        small = cv2.medianBlur(small, 3)
        small = cv2.pyrDown(small)
        scale, offset = 4, 0.5  # reduced pixel k is centred on full-resolution 4k + 0.5
    smooth = cv2.boxFilter(small, cv2.CV_32F, (3, 3), borderType=cv2.BORDER_REPLICATE)
    # take off the background's tilt (a plane fitted to a sparse grid, where the spot is a
    # few points among ~2,000), so that a brighter side of the frame cannot outshine a spot
    fit, grid_x, grid_y = _tilt_fit(smooth.shape)
    offset_level, slope_x, slope_y = fit @ smooth[1::3, 1::3].ravel()
    smooth -= (offset_level + slope_x * grid_x[None, :] + slope_y * grid_y[:, None]).astype(
        np.float32
    )
    sample = smooth[1::3, 1::3].ravel()  # a sparse sample: the spot is a small part of it
    # one-sided spread (median minus the 15.9th percentile, 1 sigma for Gaussian noise): the
    # spot and hot pixels only ever add to the upper side
    lower_rank, middle_rank = int(0.1587 * (sample.size - 1)), sample.size // 2
    ordered = np.partition(sample, (lower_rank, middle_rank))
    level = float(ordered[middle_rank])
    spread = level - float(ordered[lower_rank])
    # the outermost reduced pixels are left out of the search: the filters' replicated borders
    # multiply a hot pixel there, and a spot that close to the edge is cut anyway
    _, top, _, (column, row) = cv2.minMaxLoc(smooth[1:-1, 1:-1])
    column, row = column + 1, row + 1
    if top - level <= _DETECTION_SIGMAS * max(spread, 0.5 / 9):
        raise CentroidError(
            "no-spot",
            f"no spot above the noise: brightest smoothed level {top - level:.3g} counts "
            f"over the background, noise {spread:.3g}",
        )
    # width from the area above half of the smoothed peak, around the peak only
    reach = 12
    patch = smooth[
        max(0, row - reach) : row + reach + 1, max(0, column - reach) : column + reach + 1
    ]
    area = float(np.count_nonzero(patch > level + 0.5 * (top - level))) * scale * scale
    width = math.sqrt(area / (2.0 * math.pi * math.log(2.0)))
    return column * scale + offset, row * scale + offset, width


@functools.cache
def _tilt_fit(
    shape: tuple[int, ...],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Least-squares operator giving (level, slope x, slope y) from the sparse grid
    ``[1::3, 1::3]`` of an image of ``shape``, and the centred x and y of its pixels."""
    grid_y = np.arange(shape[0], dtype=np.float64) - 0.5 * (shape[0] - 1)
    grid_x = np.arange(shape[1], dtype=np.float64) - 0.5 * (shape[1] - 1)
    sample_y, sample_x = np.meshgrid(grid_y[1::3], grid_x[1::3], indexing="ij")
    design = np.column_stack([np.ones(sample_x.size), sample_x.ravel(), sample_y.ravel()])
    return np.asarray(np.linalg.pinv(design), dtype=np.float64), grid_x, grid_y


def _median(values: NDArray[Any]) -> float:
    """Median by partial sort: ``np.median``'s generality costs more than this whole step."""
    flat = values.ravel()
    middle = flat.size // 2
    if flat.size % 2:
        return float(np.partition(flat, middle)[middle])
    pair = np.partition(flat, (middle - 1, middle))
    return 0.5 * float(pair[middle - 1] + pair[middle])


def _window_weights(
    pixel_starts: NDArray[np.float64], pixel_ends: NDArray[np.float64], middle: float, half: float
) -> NDArray[np.float64]:
    """Overlap of each pixel ``[start, end]`` (``c ± 0.5``) with the window ``[middle ± half]``.

    A soft-edged window is exactly centred on the estimate whatever its sub-pixel position,
    so what it truncates (and any residual background) is symmetric about the estimate and
    cannot pull the converged centroid to the pixel grid.
    """
    overlap = np.minimum(pixel_ends, middle + half) - np.maximum(pixel_starts, middle - half)
    np.maximum(overlap, 0.0, out=overlap)
    np.minimum(overlap, 1.0, out=overlap)
    return overlap


def _support(window: NDArray[np.float64]) -> slice:
    """The pixels a window covers (a contiguous run)."""
    inside = np.flatnonzero(window > 0)
    return slice(int(inside[0]), int(inside[-1]) + 1)


def _grouped_median(counts: NDArray[np.float64]) -> float:
    """Median of non-negative whole numbers read as grouped data: value k stands for the
    interval [k - 1/2, k + 1/2] (0 for [0, 1/2]: these are magnitudes), and the median is
    interpolated inside its interval.

    The plain median of quantised magnitudes is a whole number: for noise under one count most
    differences are 0 and the median is exactly 0. The grouped median is continuous in the
    noise and, when every difference is 0, gives 1/4 count, i.e. 0.26 count of noise: the
    rounding error (uniform, sqrt(1/12) = 0.29 count RMS) that is then the only noise left.
    """
    size = counts.size
    middle = float(np.partition(counts, size // 2)[size // 2])
    below = int(np.count_nonzero(counts < middle - 0.5))
    within = int(np.count_nonzero(np.abs(counts - middle) < 0.5))
    lower = max(middle - 0.5, 0.0)
    width = 0.5 if middle < 0.5 else 1.0
    return lower + (0.5 * size - below) / within * width


def _local_background(
    region: NDArray[np.float64], *, quantised: bool = False
) -> tuple[float, float, float, float]:
    """(level at the region centre, slope x, slope y, noise sigma) from the region's border.

    The medians of the four bands are robust to hot pixels and, for a linear gradient, equal
    the plane at each band's middle, so a tilted background is removed exactly. The noise
    comes from differences of neighbouring pixels along the bands (a gradient cancels out):
    their median absolute value (MAD), read as grouped data when the pixels are whole counts
    (``quantised``, :func:`_grouped_median`) so that it does not collapse to 0 under one
    count of noise.
    """
    ring = _RING_PX
    left, right = region[:, :ring], region[:, -ring:]
    top, bottom = region[:ring, :], region[-ring:, :]
    m_left, m_right = _median(left), _median(right)
    m_top, m_bottom = _median(top), _median(bottom)
    height, width = region.shape
    level = 0.25 * (m_left + m_right + m_top + m_bottom)
    slope_x = (m_right - m_left) / max(1, width - ring)
    slope_y = (m_bottom - m_top) / max(1, height - ring)
    steps = np.concatenate(
        [
            np.diff(left, axis=0).ravel(),
            np.diff(right, axis=0).ravel(),
            np.diff(top, axis=1).ravel(),
            np.diff(bottom, axis=1).ravel(),
        ]
    )
    magnitudes = np.abs(steps)
    spread = _grouped_median(magnitudes) if quantised else _median(magnitudes)
    noise = 1.4826 / math.sqrt(2.0) * spread
    return level, slope_x, slope_y, noise


def _without_hot_pixels(
    region: NDArray[np.float64], plane: NDArray[np.float64], noise: float
) -> tuple[NDArray[np.float64], int]:
    """``region`` with isolated hot pixels replaced by their 3 x 3 median, and their number.

    A full-scale hot pixel 10 px from the centre of a mid-scale 3-px spot moves the centroid
    by ~0.3 px, so the locator's immunity is not enough. A pixel is hot when it stands more
    than 8 noise sigmas (at least one count) above the brightest of its 8 neighbours and more
    than three times as far above the background: every pixel of a spot has a neighbour at
    least that bright (the brightest pixel of a pixel-integrated Gaussian wider than
    0.65 px has a neighbour above a third of it).
    """
    values = region.astype(np.float32)
    brightest_neighbour = cv2.dilate(values, _NEIGHBOURS).astype(np.float64)
    hot = (region - brightest_neighbour > max(8.0 * noise, 1.0)) & (
        region - plane > 3.0 * (brightest_neighbour - plane)
    )
    count = int(np.count_nonzero(hot))
    if count:
        median = cv2.medianBlur(values, 3).astype(np.float64)
        region = np.where(hot, median, region)
    return region, count


def _truncation_shift(
    centres: NDArray[np.float64], weights: NDArray[np.float64], middle: float, edge: float
) -> float:
    """How far (px) the centroid is pulled away from a frame ``edge`` that cuts the window.

    The spot is symmetric about ``middle``, so what lies beyond the edge mirrors what lies
    beyond the edge's mirror image on the other side: its moment over the total is the shift
    its absence causes.
    """
    mirror = 2.0 * middle - edge
    beyond = centres > mirror if edge < middle else centres < mirror
    total = float(weights.sum())
    return abs(float(weights[beyond] @ (centres[beyond] - middle))) / total if total else math.inf


def robust_centroid(
    image: NDArray[Any],
    bit_depth: int,
    um_per_px: tuple[float, float],
    *,
    gain_e_per_count: float | None,
    read_noise_e: float,
    gain_source: GainSource = "config",
) -> CentroidResult:
    """Background-subtracted, threshold-subtracted, iteratively re-centred windowed moments.

    1. :func:`_locate` finds the spot on a reduced, smoothed, de-tilted image (hot pixels,
       noise and a brighter side of the frame cannot capture it) and guesses its width.
    2. A region around it: the background plane and noise come from its border band
       (:func:`_local_background`), so the background is measured, not assumed, and gradients
       are removed.
    3. Each pixel weighs ``max(I - background - T, 0)`` with ``T`` three noise sigmas: the
       threshold is *subtracted*, so a pixel's weight rises continuously from 0 as it crosses
       ``T``. (Only zeroing pixels below a threshold, as the thesis does, makes the weights
       jump with the sub-pixel position and biases the centroid.)
    4. ISO 11146-style iteration: first and second moments in a soft-edged window centred on
       the current estimate, half-size 4 second-moment widths, until the estimate moves less
       than 1e-5 px; the region is re-cut if the window outgrows it.
    5. A partly saturated spot is then located by a fit of the pixel-integrated Gaussian to
       its unsaturated flanks (:func:`daemon.vision.centroid_fit.fit_spot`), since clipped
       moments alias.
       Where that model does not fit (a saturated flat-topped spot) the moments stand and the
       frame is flagged ``saturation-fit-failed``: expect up to ~0.01 px of sub-pixel bias.
    6. Isolated hot pixels in the region are replaced by their 3 x 3 median first
       (:func:`_without_hot_pixels`), and a frame edge that cuts the window is tolerated only
       while the part it hides cannot move the centroid by 0.001 px
       (:func:`_truncation_shift`).
    7. The pixels' noise model (reported 1-sigma, fit weights, SNR): from the sensor's gain
       ``gain_e_per_count`` when given (``gain_source`` says whose: the settings' or the
       camera's), else measured on this frame by photon transfer
       (:func:`daemon.vision.photon_transfer.estimate_noise_model`) on the residuals of a fit
       of the spot (``gain_source`` "frames"; "unknown", flag ``gain-unestimated``, when the
       fit fails: then only the background's noise is counted and the 1-sigma is low).
    """
    white = full_scale(bit_depth)
    height, width = image.shape
    if min(height, width) < _MIN_FRAME_PX:
        raise CentroidError(
            "dimensions", f"wrong dimensions: {width}x{height} px is too small to measure"
        )
    quantised = bool(np.issubdtype(image.dtype, np.integer))
    x, y, coarse_width = _locate(image)
    half_x = half_y = max(_MIN_HALF_WIDTH, _WINDOW_SIGMAS * coarse_width)
    iterations = 0
    for _recut in range(6):
        slack = 2.0 + 0.25 * max(half_x, half_y) + _RING_PX
        c0 = max(0, math.floor(x - half_x - slack))
        c1 = min(width, math.ceil(x + half_x + slack) + 1)
        r0 = max(0, math.floor(y - half_y - slack))
        r1 = min(height, math.ceil(y + half_y + slack) + 1)
        region = image[r0:r1, c0:c1].astype(np.float64)
        level, slope_x, slope_y, noise = _local_background(region, quantised=quantised)
        columns = np.arange(c0, c1, dtype=np.float64)
        rows = np.arange(r0, r1, dtype=np.float64)
        centre_x, centre_y = 0.5 * (c0 + c1 - 1), 0.5 * (r0 + r1 - 1)
        plane = (
            level + slope_x * (columns - centre_x)[None, :] + slope_y * (rows - centre_y)[:, None]
        )
        threshold = _THRESHOLD_SIGMAS * noise
        region, hot_pixels = _without_hot_pixels(region, plane, noise)
        excess = region - plane
        weights = np.maximum(excess - threshold, 0.0)
        starts_x, ends_x = columns - 0.5, columns + 0.5
        starts_y, ends_y = rows - 0.5, rows + 0.5
        # moments about the region centre, all three from one product: [1, u, u²] @ weights
        u, v = columns - centre_x, rows - centre_y
        powers_x = np.stack([np.ones_like(u), u, u * u])
        powers_y = np.stack([np.ones_like(v), v, v * v])
        outgrown = False
        for _ in range(_MAX_ITERATIONS):
            iterations += 1
            wx = _window_weights(starts_x, ends_x, x, half_x)
            wy = _window_weights(starts_y, ends_y, y, half_y)
            moments_x = powers_x @ ((wy @ weights) * wx)
            moments_y = powers_y @ ((weights @ wx) * wy)
            total = float(moments_x[0])
            if total <= 0.0:
                raise CentroidError("no-spot", "no spot above the noise in the window")
            mean_x, mean_y = moments_x[1] / total, moments_y[1] / total
            var_x = max(float(moments_x[2] / total - mean_x * mean_x), 1.0 / 12.0)
            var_y = max(float(moments_y[2] / total - mean_y * mean_y), 1.0 / 12.0)
            shift_x = centre_x + float(mean_x) - x
            shift_y = centre_y + float(mean_y) - y
            x += shift_x
            y += shift_y
            new_half_x = max(_MIN_HALF_WIDTH, _WINDOW_SIGMAS * math.sqrt(var_x) + 1.0)
            new_half_y = max(_MIN_HALF_WIDTH, _WINDOW_SIGMAS * math.sqrt(var_y) + 1.0)
            settled = (
                abs(shift_x) < TOLERANCE_PX
                and abs(shift_y) < TOLERANCE_PX
                and abs(new_half_x - half_x) < 0.01
                and abs(new_half_y - half_y) < 0.01
            )
            half_x, half_y = new_half_x, new_half_y
            # the window must stay inside the background ring, except where the region
            # already reaches the frame edge (re-cutting cannot help there)
            outgrown = (
                (c0 > 0 and x - half_x < c0 + _RING_PX - 0.5)
                or (c1 < width and x + half_x > c1 - _RING_PX - 0.5)
                or (r0 > 0 and y - half_y < r0 + _RING_PX - 0.5)
                or (r1 < height and y + half_y > r1 - _RING_PX - 0.5)
            )
            if outgrown or settled:
                break
        if not outgrown:
            break

    wx = _window_weights(starts_x, ends_x, x, half_x)
    wy = _window_weights(starts_y, ends_y, y, half_y)
    in_x, in_y = _support(wx), _support(wy)
    wx, wy = wx[in_x], wy[in_y]
    window_columns, window_rows = columns[in_x], rows[in_y]
    spot = weights[in_y, in_x]
    raw = region[in_y, in_x]
    flags: list[str] = []
    edges = (
        ("left", x - half_x < -0.5, window_columns, -0.5),
        ("right", x + half_x > width - 0.5, window_columns, width - 0.5),
        ("top", y - half_y < -0.5, window_rows, -0.5),
        ("bottom", y + half_y > height - 0.5, window_rows, height - 0.5),
    )
    for side, clipped, centres, edge in edges:
        if not clipped:
            continue
        profile = (wy @ spot) * wx if side in ("left", "right") else (spot @ wx) * wy
        shift = _truncation_shift(centres, profile, x if side in ("left", "right") else y, edge)
        if shift > _EDGE_SHIFT_PX:
            raise CentroidError(
                "edge",
                f"spot cut by the frame edge ({side}): the part beyond it would move the "
                f"centroid by about {shift:.2g} px",
            )
        if "edge" not in flags:
            flags.append("edge")
    above_all = excess[in_y, in_x]
    above = np.where(above_all > threshold, above_all, 0.0)
    spot_pixels = int(np.count_nonzero(above))
    signal = float(wy @ above @ wx)
    saturated = int(np.count_nonzero(raw >= white))
    if saturated:
        flags.insert(0, "saturated")
    unsaturated = raw < white
    start = (
        x,
        y,
        math.sqrt(max(var_x - 1.0 / 12.0, 0.1)),
        math.sqrt(max(var_y - 1.0 / 12.0, 0.1)),
    )
    measured: NoiseModel | None = None
    if gain_e_per_count is None:  # photon transfer (step 7)
        offset = max(noise * noise, QUANTISATION_VARIANCE if quantised else 0.0)
        measured, start = frame_noise_model(
            above_all, unsaturated, window_columns, window_rows, start, offset=offset
        )
        gain_source = "unknown" if measured is None else "frames"
        if measured is None:
            flags.append("gain-unestimated")
            measured = NoiseModel(noise * noise + QUANTISATION_VARIANCE, 0.0)
        fit_noise = measured
    else:
        fit_noise = NoiseModel(noise * noise + QUANTISATION_VARIANCE, 1.0 / gain_e_per_count)
    if saturated or noise < _QUANTISED_NOISE_COUNTS:
        fit = fit_spot(
            above_all,
            unsaturated,
            window_columns,
            window_rows,
            start,
            noise_model=fit_noise,
        )
        usable = (
            fit is not None
            and abs(fit.x - x) < 1.0
            and abs(fit.y - y) < 1.0
            and (saturated or fit.reduced_chi2 <= _FIT_MAX_REDUCED_CHI2)
        )
        if fit is not None and usable:
            x, y, signal = fit.x, fit.y, fit.flux
            var_x, var_y = fit.sigma_x**2 + 1.0 / 12.0, fit.sigma_y**2 + 1.0 / 12.0
        else:
            flags.append("saturation-fit-failed" if saturated else "quantised-moments")
    if hot_pixels:
        flags.append("hot-pixels")
    background = level + slope_x * (x - centre_x) + slope_y * (y - centre_y)
    noise_model = measured or NoiseModel.from_gain(
        gain_e_per_count or 1.0, read_noise_e, max(background, 0.0)
    )
    snr = signal / math.sqrt(signal * noise_model.slope + spot_pixels * noise**2 + 1e-300)
    if snr < _LOW_SNR:
        flags.append("low-snr")
    sigma_x, sigma_y = centroid_uncertainty(
        window_columns - x,
        window_rows - y,
        signal=signal,
        var_x=max(var_x - 1.0 / 12.0, 0.25),
        var_y=max(var_y - 1.0 / 12.0, 0.25),
        background=max(background, 0.0),
        white=white,
        noise_model=noise_model,
    )
    peak = float(raw.max())
    scaled = np.clip(raw * (10.0 / white), 0, 9).astype(np.intp)
    histogram = tuple(int(n) for n in np.bincount(scaled.ravel(), minlength=10))
    return CentroidResult(
        method="robust",
        x_px=x,
        y_px=y,
        x_um=x * um_per_px[0],
        y_um=y * um_per_px[1],
        sigma_x_px=sigma_x,
        sigma_y_px=sigma_y,
        sigma_x_um=sigma_x * um_per_px[0],
        sigma_y_um=sigma_y * um_per_px[1],
        signal=signal,
        peak=peak,
        peak_fraction=peak / white,
        background=background,
        noise=noise,
        width_x_px=math.sqrt(var_x),
        width_y_px=math.sqrt(var_y),
        snr=snr,
        saturated_fraction=saturated / max(1, spot_pixels),
        histogram=histogram,
        flags=tuple(flags),
        iterations=iterations,
        gain_e_per_count=noise_model.gain_e_per_count,
        gain_source=gain_source,
    )
