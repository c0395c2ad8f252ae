"""First-order exponential fits, steady-state time and the thesis's predictive curve.

Heating curves of robot links are first-order exponentials (thesis 2.2.3, after Leitner et
al.): rising, ``y = y0 + A (1 - exp(-(t - t0)/tau))``, or decaying after the heat stops,
``y = y0 + A exp(-(t - t0)/tau)``. ``tau`` is the time constant, the time to reach
(e - 1)/e ~ 63 % of the change (thesis 3.5.1, footnote 2). Steady state is where the signal
stays within a band, by default +-3 sigma (thesis 3.5.1, footnote 3: "+-3 sigma = +-15 um").
Appendix A.2's ``time2def`` is the curve fitted to the two-link deformation that drove the
thesis's compensation: ``577.7035 (1 - exp(-0.0047 t))`` um.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import curve_fit

logger = logging.getLogger(__name__)

Kind = Literal["rising", "decaying"]
KINDS: tuple[Kind, ...] = ("rising", "decaying")


class FitError(ValueError):
    """The data cannot be fitted (too few points, flat, or the optimiser did not converge)."""


@dataclass(frozen=True)
class ExponentialCurve:
    """A first-order exponential; ``amplitude`` is the total change A."""

    kind: Kind
    y0: float
    amplitude: float
    tau_s: float
    t0_s: float = 0.0

    def __call__(self, t_s: ArrayLike) -> NDArray[np.float64]:
        decay = np.exp(-(np.asarray(t_s, dtype=float) - self.t0_s) / self.tau_s)
        if self.kind == "rising":
            return self.y0 + self.amplitude * (1.0 - decay)
        return self.y0 + self.amplitude * decay

    @property
    def final_value(self) -> float:
        """The asymptote: y0 + A when rising, y0 when decaying."""
        return self.y0 + self.amplitude if self.kind == "rising" else self.y0

    def settling_time_s(self, band: float) -> float:
        """First time after which the curve stays within ``band`` of its asymptote."""
        if band <= 0:
            raise ValueError(f"band must be positive, got {band}")
        if abs(self.amplitude) <= band:
            return self.t0_s
        return self.t0_s + self.tau_s * math.log(abs(self.amplitude) / band)


#: Thesis appendix A.2, ``time2def``: predicted two-link deformation (um) at time t (s).
TIME2DEF = ExponentialCurve(kind="rising", y0=0.0, amplitude=577.7035, tau_s=1.0 / 0.0047)

#: Named predictive curves a replay may be driven by.
PREDICTIVE_CURVES: dict[str, ExponentialCurve] = {"time2def": TIME2DEF}


def predictive_curve(name: str) -> ExponentialCurve:
    try:
        return PREDICTIVE_CURVES[name]
    except KeyError:
        known = ", ".join(sorted(PREDICTIVE_CURVES))
        raise ValueError(f"unknown predictive curve {name!r}; known: {known}") from None


@dataclass(frozen=True)
class ExponentialFit:
    """A least-squares fit with the parameters' standard errors (from the covariance)."""

    curve: ExponentialCurve
    y0_stderr: float
    amplitude_stderr: float
    tau_stderr_s: float
    residual_std: float  # standard deviation of data minus fit
    n: int
    # from the data (see steady_state_time), and None also when the fitted curve is still
    # outside that band at the end of the data: the signal has not settled within the run
    steady_state_s: float | None
    steady_band: float  # half-width of the band used
    end_s: float = math.nan  # the last sample's time

    def to_dict(self) -> dict[str, object]:
        result: dict[str, object] = asdict(self.curve)
        result.update({key: value for key, value in asdict(self).items() if key != "curve"})
        result["final_value"] = self.curve.final_value
        # The same band applied to the fitted curve: robust to a single noisy late sample.
        band = self.steady_band
        result["fit_settling_s"] = self.curve.settling_time_s(band) if band > 0 else None
        result["steady"] = self.steady_state_s is not None
        return result


def _running_mean(values: NDArray[np.float64], window: int) -> NDArray[np.float64]:
    """Centred running mean; near the ends the window shrinks to the samples available."""
    if window <= 1:
        return values
    kernel = np.ones(window)
    sums = np.convolve(values, kernel, mode="same")
    counts = np.convolve(np.ones_like(values), kernel, mode="same")
    smoothed: NDArray[np.float64] = sums / counts
    return smoothed


def steady_state_time(
    t_s: ArrayLike,
    y: ArrayLike,
    *,
    band: float | None = None,
    sigmas: float = 3.0,
    final_fraction: float = 0.2,
    smoothing: int = 9,
) -> tuple[float | None, float]:
    """First time after which ``y`` stays within a band around its final level.

    The final level is the mean of the last ``final_fraction`` of the samples. The band's
    half-width is ``band`` when given (e.g. 15 um as thesis 3.5.1 footnote 3), otherwise
    ``sigmas`` standard deviations of that final segment. A noisy sample beyond 3 sigma comes
    once in 370 even at steady state, so "stays within" is judged on a centred running mean
    of ``smoothing`` samples (1: the raw samples); the band itself is the raw data's.
    Returns (time or None, band used); None when the signal is still outside at the end.
    """
    times = np.asarray(t_s, dtype=float)
    values = np.asarray(y, dtype=float)
    finite = np.isfinite(times) & np.isfinite(values)
    times, values = times[finite], values[finite]
    if values.size < 2:
        raise ValueError("need at least two samples for a steady-state time")
    if not 0 < final_fraction <= 1:
        raise ValueError(f"final_fraction must be in (0, 1], got {final_fraction}")
    if smoothing < 1:
        raise ValueError(f"smoothing must be at least 1 sample, got {smoothing}")
    segment = values[-max(2, round(final_fraction * values.size)) :]
    level = float(segment.mean())
    half_width = float(band) if band is not None else sigmas * float(segment.std(ddof=1))
    smoothed = _running_mean(values, min(smoothing, values.size))
    outside = np.flatnonzero(np.abs(smoothed - level) > half_width)
    if outside.size == 0:
        return float(times[0]), half_width
    last_outside = int(outside[-1])
    if last_outside == values.size - 1:
        return None, half_width
    return float(times[last_outside + 1]), half_width


def direction_of(y: ArrayLike) -> Kind:
    """ "rising" when the signal ends at least as high as it started, else "decaying"."""
    values = np.asarray(y, dtype=float)
    finite = values[np.isfinite(values)]
    return "rising" if finite.size == 0 or finite[-1] >= finite[0] else "decaying"


def _initial_guess(t: NDArray[np.float64], y: NDArray[np.float64], kind: Kind) -> list[float]:
    edge = max(1, y.size // 20)
    start, end = float(y[:edge].mean()), float(y[-edge:].mean())
    change = end - start
    progress = (y - start) / change if change != 0 else np.zeros_like(y)
    reached = np.flatnonzero(progress >= 1 - math.exp(-1))
    tau = float(t[reached[0]] - t[0]) if reached.size and reached[0] > 0 else (t[-1] - t[0]) / 3
    tau = max(tau, (t[-1] - t[0]) / y.size)
    if kind == "rising":
        return [start, change, tau]
    return [end, -change, tau]


def fit_exponential(
    t_s: ArrayLike,
    y: ArrayLike,
    kind: Kind = "rising",
    *,
    t0_s: float | None = None,
    band: float | None = None,
    sigmas: float = 3.0,
    final_fraction: float = 0.2,
    smoothing: int = 9,
) -> ExponentialFit:
    """Least-squares first-order exponential through (t, y); NaN samples are dropped.

    ``t0_s`` is the start of the exponential (default: the first time); it is fixed because
    t0 and A cannot both be identified from one curve. Standard errors come from the fit's
    covariance scaled by the residual variance. ``band``, ``sigmas``, ``final_fraction`` and
    ``smoothing`` set the steady-state test, see :func:`steady_state_time`.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    times = np.asarray(t_s, dtype=float)
    values = np.asarray(y, dtype=float)
    if times.shape != values.shape:
        raise ValueError("t and y must have the same length")
    finite = np.isfinite(times) & np.isfinite(values)
    times, values = times[finite], values[finite]
    if values.size < 4:
        raise FitError(f"need at least 4 samples to fit 3 parameters, got {values.size}")
    if np.ptp(values) == 0:
        raise FitError("the signal is flat: no exponential to fit")
    order = np.argsort(times)
    times, values = times[order], values[order]
    start = float(times[0]) if t0_s is None else float(t0_s)

    def model(
        t: NDArray[np.float64], y0: float, amplitude: float, tau: float
    ) -> NDArray[np.float64]:
        return ExponentialCurve(kind, y0, amplitude, tau, start)(t)

    span = float(times[-1] - times[0])
    guess = _initial_guess(times, values, kind)
    try:
        params, covariance = curve_fit(
            model,
            times,
            values,
            p0=guess,
            bounds=([-np.inf, -np.inf, span * 1e-6], [np.inf, np.inf, span * 1e3]),
            maxfev=20_000,
        )
    except (RuntimeError, ValueError) as err:
        raise FitError(f"the exponential fit did not converge: {err}") from err
    errors = np.sqrt(np.clip(np.diag(covariance), 0.0, np.inf))
    if not np.all(np.isfinite(errors)):
        raise FitError("the fit's parameters are not identifiable from this data")
    y0, amplitude, tau = (float(p) for p in params)
    curve = ExponentialCurve(kind=kind, y0=y0, amplitude=amplitude, tau_s=tau, t0_s=start)
    residuals = values - curve(times)
    steady_s, half_width = steady_state_time(
        times,
        values,
        band=band,
        sigmas=sigmas,
        final_fraction=final_fraction,
        smoothing=smoothing,
    )
    end = float(times[-1])
    # The band around the final segment's mean is met early by a signal still rising slowly
    # (its last fifth then spans a wide band): steady only if the fit agrees (issue 19: "steady
    # from 438 s" of a 600 s run with tau 2730 s).
    if steady_s is not None and half_width > 0 and curve.settling_time_s(half_width) > end:
        steady_s = None
    logger.debug("fitted %s exponential: %s", kind, curve)
    return ExponentialFit(
        curve=curve,
        y0_stderr=float(errors[0]),
        amplitude_stderr=float(errors[1]),
        tau_stderr_s=float(errors[2]),
        residual_std=float(residuals.std(ddof=3)) if values.size > 3 else 0.0,
        n=int(values.size),
        steady_state_s=steady_s,
        steady_band=half_width,
        end_s=end,
    )
