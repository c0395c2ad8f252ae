"""The pixels' noise model the centroid weighs and reports with, and its photon-transfer
estimate from one frame. Pure code: arrays in, results out.

A pixel's variance (counts²) grows linearly with its signal (photon transfer, EMVA 1288):
``offset + slope * excess``, where ``excess`` is the signal above the local background,
``slope`` is 1 / gain (counts per electron: the shot noise of the spot's own electrons) and
``offset`` holds everything present at the background level (read noise, the dark signal's
shot noise, rounding). A camera that knows its gain gives ``slope`` directly
(:meth:`NoiseModel.from_gain`); otherwise :func:`estimate_noise_model` measures both from the
residuals of a model of the spot: the spot's pixels span the signal range and the window's
flanks pin the offset, which is what the photon-transfer curve of a flat-field series does
with many frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

QUANTISATION_VARIANCE = 1.0 / 12.0  # counts², rounding to integers
#: the gain a camera can plausibly have at most (electrons per count): a slope estimated at
#: or under 1 / this is "no measurable shot noise"
MAX_GAIN_E_PER_COUNT = 1.0e6
#: re-weighting passes of the photon-transfer regression (its weights depend on its answer;
#: the third pass changes the slope by under 1 % in the benchmark's settings)
_REWEIGHTING_PASSES = 3
#: fewest pixel pairs for an estimate (a slope and an offset from fewer are noise)
_MIN_PAIRS = 16


@dataclass(frozen=True, slots=True)
class NoiseModel:
    """A pixel's variance (counts²) as ``offset + slope * excess`` (module docstring)."""

    offset: float  # counts² at the background level
    slope: float  # counts per electron (1 / gain)

    @classmethod
    def from_gain(
        cls, gain_e_per_count: float, read_noise_e: float, background: float
    ) -> NoiseModel:
        """The model of a sensor of known gain: the background's shot noise, read noise and
        rounding at the background level ``background`` (counts above the sensor's zero)."""
        slope = 1.0 / gain_e_per_count
        offset = max(background, 0.0) * slope + (read_noise_e * slope) ** 2
        return cls(offset + QUANTISATION_VARIANCE, slope)

    @property
    def gain_e_per_count(self) -> float:
        """Electrons per count: 1 / slope, at most :data:`MAX_GAIN_E_PER_COUNT`."""
        return (
            min(1.0 / self.slope, MAX_GAIN_E_PER_COUNT)
            if self.slope > 0
            else (MAX_GAIN_E_PER_COUNT)
        )

    def variance(self, excess: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.offset + self.slope * np.clip(excess, 0.0, None)


def estimate_noise_model(
    excess: NDArray[np.float64],
    model: NDArray[np.float64],
    usable: NDArray[np.bool_],
    *,
    offset: float,
) -> NoiseModel | None:
    """Photon transfer from one frame: the noise model whose ``offset`` (counts²) the
    background gave (the local background's noise, measured on the ring around the spot) and
    whose slope explains the scatter of ``excess`` (window minus background, counts) about
    ``model`` (the fitted spot, same shape) over the ``usable`` (unsaturated) pixels; None
    with too few pixels.

    The slope is measured on *differences of neighbouring residuals*, not on the residuals
    themselves: a smooth misfit of the model (a spot that is not quite Gaussian) mostly
    cancels in a difference, and would otherwise read as shot noise. For independent pixels
    ``E[(r_i - r_j)² / 2] = offset + slope * (m_i + m_j) / 2``, a straight line in the pair's
    mean signal whose slope is fitted by weighted least squares (weights 1 / variance², the
    variance of a squared Gaussian being twice its variance squared; re-weighted with each
    answer). The offset is not fitted with it: the spot's bright pixels leave it loosely
    determined, and the fit's weights on the faint flanks hang on it.
    """
    residual = excess - model
    horizontal = usable[:, 1:] & usable[:, :-1]
    vertical = usable[1:, :] & usable[:-1, :]
    halves = np.concatenate(
        [
            0.5 * (residual[:, 1:] - residual[:, :-1])[horizontal] ** 2,
            0.5 * (residual[1:, :] - residual[:-1, :])[vertical] ** 2,
        ]
    )
    level = np.concatenate(
        [
            0.5 * (model[:, 1:] + model[:, :-1])[horizontal],
            0.5 * (model[1:, :] + model[:-1, :])[vertical],
        ]
    )
    if halves.size < _MIN_PAIRS:
        return None
    np.clip(level, 0.0, None, out=level)
    above = halves - offset
    slope = 0.0
    # sums of products, not ``@``: OpenBLAS runs a dot product of over 10,000 elements (a
    # broad spot's pairs) on several threads, 100x slower than one on a loaded machine
    for _ in range(_REWEIGHTING_PASSES):
        weighted = level / np.square(offset + slope * level)
        spread = float(np.sum(weighted * level))
        if spread <= 0.0 or not math.isfinite(spread):
            return NoiseModel(offset, 0.0)
        slope = max(float(np.sum(weighted * above)) / spread, 0.0)
    return NoiseModel(offset, slope)
