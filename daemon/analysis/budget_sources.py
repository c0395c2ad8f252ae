"""The measurement's sources of error of thesis chapter 4, one function each. Pure.

Analytic where the thesis was (4.3 cantilever bending, 4.4 misalignment cosine errors, 4.5 the
diode hole's expansion tipping the diode), and the statistics of the recordings where it
experimented (4.6 idle-induced vibration and 4.7 the centroid: the scatter of a stationary
recording against the centroid's Cramér-Rao bound; 4.8 the camera's own drift: a recording on
a fixed target). SI units in the analytic functions (m, Pa, N, rad, K), µm in the statistics.
Every function states which equation or paragraph it is; DESIGN.md's misprints apply (Young's
modulus of 6061-T6 is 70 GPa, not MPa).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from daemon.analysis.fits import FitError, fit_exponential

#: Standard gravity (m/s²): the weight of 4.3's link and diode.
G_M_PER_S2 = 9.80665


# --- 4.3 cantilever bending ------------------------------------------------------------------


def second_moment_m4(thickness_m: float, width_m: float) -> float:
    """4.3.1: ``I = b h³ / 12``, ``b`` the link's thickness and ``h`` its width (the link
    bends in the plane of its width: it hangs from the shaft with its width vertical)."""
    return thickness_m * width_m**3 / 12.0


def cantilever_deflection_m(
    force_n: float, length_m: float, youngs_modulus_pa: float, second_moment: float
) -> float:
    """Eq. 4.1's magnitude: the free end's deflection ``F L³ / (3 E I)`` of a cantilever of
    length ``L`` under ``F`` at its free end (4.3: the worst case, the link's and the diode's
    whole weight at the end)."""
    if length_m <= 0 or youngs_modulus_pa <= 0 or second_moment <= 0:
        raise ValueError("the cantilever needs a positive length, Young's modulus and I")
    return force_n * length_m**3 / (3.0 * youngs_modulus_pa * second_moment)


def foreshortening_m(length_m: float, deflection_m: float) -> float:
    """4.3.2: the shortening along the link of its end deflected by ``deflection_m`` (the arc
    keeps its length, small-deformation theory): ``L - sqrt(L² - δy²)``, written so that it
    keeps its digits when ``δy << L`` (``δy² / (L + sqrt(L² - δy²))``)."""
    if abs(deflection_m) >= length_m:
        raise ValueError("a deflection as large as the link is not a small deformation")
    return deflection_m**2 / (length_m + math.sqrt(length_m**2 - deflection_m**2))


def deflection_for_shortening_m(length_m: float, shortening_m: float) -> float:
    """4.3.2's converse: the end deflection that would shorten the link by ``shortening_m``."""
    return math.sqrt(length_m**2 - (length_m - shortening_m) ** 2)


# --- 4.4 link misalignment -----------------------------------------------------------------


def misalignment_z_m(deformation_m: float, theta_rad: float) -> float:
    """4.4.1, about z (the shaft's axis): the chip sees ``ΔL cos θ``, short by
    ``δL_x = ΔL (1 - cos θ)`` (written with sin² to keep its digits at small angles)."""
    return abs(deformation_m) * 2.0 * math.sin(theta_rad / 2.0) ** 2


def misalignment_y_m(deformation_m: float, beta_rad: float) -> float:
    """4.4.1, about y (seen from above): the chip plane is tilted by β from the deformation,
    ``δL_x = ΔL (1 - 1/cos β)``; its magnitude ``ΔL (1/cos β - 1)``."""
    return abs(deformation_m) * (1.0 / math.cos(beta_rad) - 1.0)


# --- 4.5 the diode hole --------------------------------------------------------------------


def hole_expansion_m(alpha_per_k: float, diameter_m: float, delta_t_k: float) -> float:
    """4.5.1: the hole's diameter grows as every dimension of the link, ``α D |ΔT|``."""
    return alpha_per_k * diameter_m * abs(delta_t_k)


def diode_tilt_rad(
    link_thickness_m: float, hole_diameter_m: float, diode_diameter_m: float
) -> float:
    """Eq. 4.2: the largest tilt of a diode of diameter ``c`` in a hole of diameter ``2b``
    through a link of thickness ``a``. The thesis's two relations, ``tan α = (b - x) / a`` and
    ``cos α = c / (b + x)``, add up to ``c + a sin α = 2b cos α``, whose root is
    ``α = arccos(c / R) - atan2(a, 2b)`` with ``R = sqrt((2b)² + a²)`` (the printed Eq. 4.2 is
    the same root through atan2 of its two solutions). No play (``2b <= c``): no tilt."""
    if link_thickness_m <= 0 or diode_diameter_m <= 0:
        raise ValueError("the link's thickness and the diode's diameter must be positive")
    if hole_diameter_m <= diode_diameter_m:
        return 0.0
    reach = math.hypot(hole_diameter_m, link_thickness_m)
    return math.acos(diode_diameter_m / reach) - math.atan2(link_thickness_m, hole_diameter_m)


def tilt_shift_m(lever_m: float, tilt_rad: float) -> float:
    """4.5.3 (Figure 4.13): a beam tipped by ``tilt_rad`` moves its spot ``lever tan α`` on a
    chip ``lever`` away (75 mm in the thesis)."""
    return lever_m * math.tan(tilt_rad)


# --- 4.6, 4.7: a stationary recording --------------------------------------------------------


@dataclass(frozen=True)
class Scatter:
    """A stationary recording's scatter along each chip axis (µm, 1-sigma), after removing a
    straight line (what the link's slow drift over a short recording does), against the
    centroid's own Cramér-Rao bound (median of the frames' reported 1-sigma). ``excess``: the
    scatter the bound does not explain (vibration and whatever else moved the spot)."""

    frames: int
    duration_s: float
    std_um: tuple[float, float]
    range_um: tuple[float, float]
    bound_um: tuple[float, float]

    @property
    def excess_um(self) -> tuple[float, float]:
        x, y = (
            math.sqrt(max(s * s - b * b, 0.0))
            for s, b in zip(self.std_um, self.bound_um, strict=True)
        )
        return x, y


def _detrended(t: NDArray[np.float64], values: NDArray[np.float64]) -> NDArray[np.float64]:
    if t.size < 3 or float(np.ptp(t)) == 0.0:
        centred: NDArray[np.float64] = values - values.mean()
        return centred
    slope, intercept = np.polyfit(t, values, 1)
    residual: NDArray[np.float64] = values - (slope * t + intercept)
    return residual


def stationary_scatter(
    t_s: ArrayLike, x_um: ArrayLike, y_um: ArrayLike, sigma_x_um: ArrayLike, sigma_y_um: ArrayLike
) -> Scatter:
    """:class:`Scatter` of the frames of a stationary recording (NaN frames left out)."""
    t, x, y, sx, sy = (
        np.asarray(a, dtype=np.float64) for a in (t_s, x_um, y_um, sigma_x_um, sigma_y_um)
    )
    good = np.isfinite(t) & np.isfinite(x) & np.isfinite(y)
    if int(good.sum()) < 3:
        raise ValueError("a stationary recording needs at least three measured frames")
    t, x, y = t[good], x[good], y[good]
    rx, ry = _detrended(t, x), _detrended(t, y)
    bounds = tuple(
        float(np.nanmedian(s[good])) if np.isfinite(s[good]).any() else 0.0 for s in (sx, sy)
    )
    return Scatter(
        frames=int(t.size),
        duration_s=float(t[-1] - t[0]),
        std_um=(float(rx.std(ddof=1)), float(ry.std(ddof=1))),
        range_um=(float(np.ptp(rx)), float(np.ptp(ry))),
        bound_um=(bounds[0], bounds[1]),
    )


# --- 4.8: the camera's drift on a fixed target -------------------------------------------------


@dataclass(frozen=True)
class Drift:
    """A fixed target's apparent motion along chip x over a recording (µm): the total change
    (a first-order fit's amplitude, thesis 4.8's warm-up curve, or the end-to-start change when
    it does not fit), its time constant when fitted, and the scatter about it."""

    frames: int
    duration_s: float
    change_um: float
    tau_s: float | None
    residual_std_um: float
    how: str
    change_se_um: float = 0.0  # standard error of the change

    @property
    def resolved(self) -> bool:
        """Whether the change stands out of the recording's noise (twice its standard error,
        the thesis's 95 %); if not, the recording only bounds the drift."""
        return abs(self.change_um) > 2.0 * self.change_se_um


#: Share of a drift recording averaged at each end for the end-to-start change.
DRIFT_EDGE_SHARE = 0.1


def camera_drift(t_s: ArrayLike, x_um: ArrayLike) -> Drift:
    """:class:`Drift` of a recording of a fixed target: a first-order exponential when it fits
    (thesis 4.8: the stand warms as the camera does, within ~30 min), else the change between
    the means of the first and last tenths."""

    t, x = np.asarray(t_s, dtype=np.float64), np.asarray(x_um, dtype=np.float64)
    good = np.isfinite(t) & np.isfinite(x)
    t, x = t[good], x[good]
    if t.size < 5:
        raise ValueError("a drift recording needs at least five measured frames")
    edge = max(1, int(t.size * DRIFT_EDGE_SHARE))
    endpoint = float(x[-edge:].mean() - x[:edge].mean())
    duration = float(t[-1] - t[0])
    try:
        # one form for either sign: y0 + A (1 - exp(-t/tau)), A of the drift's sign
        fit = fit_exponential(t, x, "rising", t0_s=float(t[0]))
    except (FitError, ValueError, RuntimeError):
        fit = None
    if (
        fit is not None
        and math.isfinite(fit.curve.amplitude)
        and math.isfinite(fit.amplitude_stderr)
        and fit.curve.tau_s < 10 * duration
    ):
        # the amplitude the curve has reached by the end (a tau far past the recording would
        # extrapolate a drift the recording never saw), its error the amplitude's scaled alike
        share = 1.0 - math.exp(-duration / fit.curve.tau_s)
        reached = fit.curve.amplitude * share
        se = max(fit.amplitude_stderr * share, fit.residual_std * math.sqrt(2.0 / edge))
        return Drift(int(t.size), duration, reached, fit.curve.tau_s, fit.residual_std, "fit", se)
    residual = float((x - np.interp(t, [t[0], t[-1]], [x[:edge].mean(), x[-edge:].mean()])).std())
    se = residual * math.sqrt(2.0 / edge)
    return Drift(int(t.size), duration, endpoint, None, residual, "ends", se)
