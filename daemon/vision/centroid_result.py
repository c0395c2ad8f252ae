"""The centroid's result and error, shared by both methods (daemon/vision/centroid.py)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal

Method = Literal["robust", "thesis"]
#: whose gain the noise model uses: the settings' (camera.gain_e_per_count), the camera's (a
#: driver that knows its sensor), measured on the frame (photon transfer), or none could be had
GainSource = Literal["config", "camera", "frames", "unknown"]
METHODS: tuple[Method, ...] = ("robust", "thesis")


class CentroidError(ValueError):
    """A frame gave no centroid. ``code`` names the problem for machines (``blank``,
    ``no-spot``, ``edge``, ``threshold``, ``dimensions``, ``unreadable``); ``str()`` for people."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True, slots=True)
class CentroidResult:
    """One frame's measurement. Counts are raw pixel values; widths are 1-sigma (px)."""

    method: Method
    x_px: float
    y_px: float
    x_um: float
    y_um: float
    sigma_x_px: float  # estimated 1-sigma uncertainty of x_px (photon + read noise)
    sigma_y_px: float
    sigma_x_um: float
    sigma_y_um: float
    signal: float  # integrated signal the centroid weighs (counts)
    peak: float  # brightest pixel (counts) of the measured area
    peak_fraction: float  # peak / full scale (the thesis's "maximum intensity")
    background: float  # local background level at the spot (counts)
    noise: float  # RMS noise of the background (counts)
    width_x_px: float  # second-moment width of the weighed spot
    width_y_px: float
    snr: float  # integrated signal / its noise
    saturated_fraction: float  # share of the spot's pixels at full scale
    histogram: tuple[int, ...]  # 10 bins of pixel value / full scale over the measured area
    # "saturated", "saturation-fit-failed", "edge" (window clipped by the frame, spot whole),
    # "low-snr" (snr < 20), "gain-unestimated" (no photon transfer: sigma counts the
    # background's noise only), "hot-pixels" (some replaced in the window), "quantised-moments"
    # (noise under half a count, but the refining fit did not converge or the spot is not
    # Gaussian: the moments stand, up to ~1.5x the Cramér-Rao bound)
    flags: tuple[str, ...]
    iterations: int
    # electrons per count of the noise model behind sigma_*, and whose (GainSource); the
    # thesis method has no noise model (0.0, "unknown")
    gain_e_per_count: float = 0.0
    gain_source: GainSource = "unknown"

    def as_dict(self) -> dict[str, Any]:
        data = asdict(self)
        data["histogram"] = list(self.histogram)
        data["flags"] = list(self.flags)
        return data
