"""The thesis's centroid, replicated: ``extract_centroid.m`` (thesis appendix A.1, 3.2.3,
4.7.2). Pure code: arrays in, results out. Coordinates as in daemon/vision/centroid.py."""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from daemon.vision.centroid_result import CentroidError, CentroidResult
from daemon.vision.synthetic import full_scale

#: Histogram bins (thesis A.1: ten shades, [0, 0.1), ..., [0.9, 1.0) of full scale), written
#: as the MATLAB script's literals so that the float comparisons are the same.
_THESIS_BIN_EDGES = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0])


def threshold_counts(value: float, bit_depth: int) -> int:
    """A threshold in counts: values up to 1 are fractions of full scale, larger ones counts.

    Fractions are rounded like MATLAB's ``round`` (half away from zero), as the thesis's
    ``TRESHOLD = round(TRESHOLD/100*MAXIMUM)`` does.
    """
    if value < 0:
        raise ValueError(f"a threshold cannot be negative, got {value}")
    counts = value * full_scale(bit_depth) if value <= 1.0 else value
    return math.floor(counts + 0.5)


def _matlab_round(value: float) -> int:
    return int(math.copysign(math.floor(abs(value) + 0.5), value))


def thesis_histogram(pixels: NDArray[Any], bit_depth: int) -> tuple[int, ...]:
    """``g_nbPixel`` of extract_centroid.m: pixels > 0 counted by value / MAXIMUM in ten bins
    ``[k/10, (k+1)/10)``. Faithful to the script, a pixel at exactly full scale falls in no
    bin (its test is ``< 1.0``)."""
    if pixels.dtype in (np.uint8, np.uint16):
        # count every value once, then add the counts up with the script's tests tabulated
        per_value = np.bincount(pixels.ravel(), minlength=0x10000)
        counts = np.bincount(_thesis_bin_of_count(bit_depth), weights=per_value, minlength=11)
    else:
        normalised = pixels[pixels > 0].astype(np.float64) / full_scale(bit_depth)
        bins = np.searchsorted(_THESIS_BIN_EDGES, normalised, side="right") - 1
        counts = np.bincount(bins[bins < 10], minlength=10)
    return tuple(int(n) for n in counts[:10])


@functools.cache
def _thesis_bin_of_count(bit_depth: int) -> NDArray[np.intp]:
    """Histogram bin of every count 0..65535 by the script's float tests; 10: no bin."""
    counts = np.arange(0x10000, dtype=np.float64)
    bins = np.searchsorted(_THESIS_BIN_EDGES, counts / full_scale(bit_depth), side="right") - 1
    bins[counts == 0] = 10  # the script counts only pixels > 0
    bins[bins > 10] = 10  # value / MAXIMUM >= 1.0 matches no test
    return np.asarray(bins, dtype=np.intp)


def thesis_centroid(
    image: NDArray[Any],
    bit_depth: int,
    um_per_px: tuple[float, float],
    *,
    low: float,
    high: float | None,
    box: int,
    binary: bool,
) -> CentroidResult:
    """extract_centroid.m (thesis A.1), with its 1-based indices turned into ours.

    1. every pixel equal to the image maximum; the middle of their extreme rows and columns;
    2. a box of half-size ``box`` around it (MATLAB ``round``, clipped to the image);
    3. histogram of the box (before thresholding) and the maximum intensity;
    4. pixels below the low threshold set to 0; in binary mode (``isRoundPixel``) the others to
       one constant (the script uses 1.0; any constant gives the same centroid); otherwise
       pixels above the optional high threshold to white (the "highest intensity threshold"
       of 4.7.2, not in the printed listing);
    5. "area" (sum of the values) 0: the error "threshold too high";
    6. intensity-weighted first moments. The script returns 1-based coordinates; ours are
       0-based (pixel centre at x = c), i.e. the script's value minus one.
    """
    white = full_scale(bit_depth)
    peak = float(image.max())
    brightest = image == image.max()
    rows = np.flatnonzero(brightest.any(axis=1))
    columns = np.flatnonzero(brightest.any(axis=0))
    # 1-based middle, as in the script, so that its round() sees the same numbers.
    middle_row = (rows[0] + rows[-1]) / 2.0 + 1.0
    middle_column = (columns[0] + columns[-1]) / 2.0 + 1.0
    height, width = image.shape
    row_first = max(1, _matlab_round(middle_row - box)) - 1
    row_last = min(_matlab_round(middle_row + box), height)  # exclusive in 0-based slicing
    column_first = max(1, _matlab_round(middle_column - box)) - 1
    column_last = min(_matlab_round(middle_column + box), width)
    area = image[row_first:row_last, column_first:column_last]
    histogram = thesis_histogram(area, bit_depth)

    low_counts = threshold_counts(low, bit_depth)
    kept = area >= low_counts  # "if small_pic(i,j) < TRESHOLD: small_pic(i,j) = 0"
    if binary:
        weights = kept.astype(np.float64)
    else:
        weights = np.where(kept, area, 0).astype(np.float64)
        if high is not None:
            weights[kept & (area > threshold_counts(high, bit_depth))] = float(white)
    total = float(weights.sum())
    if total == 0.0:
        raise CentroidError(
            "threshold",
            f"threshold too high: no pixel of the box reaches the low threshold "
            f"({low_counts} counts; maximum {peak:g})",
        )
    x_px = float(weights.sum(axis=0) @ np.arange(column_first, column_last)) / total
    y_px = float(weights.sum(axis=1) @ np.arange(row_first, row_last)) / total
    used = weights > 0
    saturated = int(np.count_nonzero(area[used] >= white))
    flags = []
    if saturated:
        flags.append("saturated")
    if (
        (used[0].any() and row_first == 0)
        or (used[-1].any() and row_last == height)
        or (used[:, 0].any() and column_first == 0)
        or (used[:, -1].any() and column_last == width)
    ):
        flags.append("edge")
    return CentroidResult(
        method="thesis",
        x_px=x_px,
        y_px=y_px,
        x_um=x_px * um_per_px[0],
        y_um=y_px * um_per_px[1],
        sigma_x_px=math.nan,
        sigma_y_px=math.nan,
        sigma_x_um=math.nan,
        sigma_y_um=math.nan,
        signal=total,
        peak=peak,
        peak_fraction=peak / white,
        background=0.0,
        noise=math.nan,
        width_x_px=math.nan,
        width_y_px=math.nan,
        snr=math.nan,
        saturated_fraction=saturated / max(1, int(used.sum())),
        histogram=histogram,
        flags=tuple(flags),
        iterations=1,
    )
