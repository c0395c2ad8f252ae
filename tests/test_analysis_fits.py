"""First-order exponential fits, steady-state time and the thesis's time2def curve."""

import math
from pathlib import Path

import numpy as np
import pytest

from daemon.analysis import (
    TIME2DEF,
    ExponentialCurve,
    FitError,
    fit_exponential,
    predictive_curve,
    steady_state_time,
    write_report,
)


def test_time2def_is_the_appendix_a2_curve() -> None:
    curve = predictive_curve("time2def")
    assert curve is TIME2DEF
    t = np.array([0.0, 100.0, 520.0, 5000.0])
    assert curve(t) == pytest.approx(577.7035 * (1 - np.exp(-0.0047 * t)))
    assert curve.tau_s == pytest.approx(1 / 0.0047)
    assert curve.final_value == pytest.approx(577.7035)
    with pytest.raises(ValueError, match="time2def"):
        predictive_curve("nope")


@pytest.mark.parametrize(
    ("kind", "y0", "amplitude", "tau_s", "noise"),
    [
        ("rising", 22.0, 12.0, 660.0, 0.08),  # a link warming (thesis 3.5.1: tau 660 s)
        ("rising", 0.0, 150.0, 300.0, 0.9),  # a deformation measured on the chip
        ("decaying", 22.0, 10.0, 900.0, 0.1),  # cooling after the heaters stop
    ],
)
def test_fit_recovers_known_parameters_from_noisy_curves(
    kind: str, y0: float, amplitude: float, tau_s: float, noise: float
) -> None:
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 6 * tau_s, 5.0)
    truth = ExponentialCurve(kind=kind, y0=y0, amplitude=amplitude, tau_s=tau_s)  # type: ignore[arg-type]
    fit = fit_exponential(t, truth(t) + rng.normal(0, noise, t.size), kind)  # type: ignore[arg-type]
    # Within four standard errors of the truth, and the errors are small but not zero.
    assert abs(fit.curve.y0 - y0) < 4 * fit.y0_stderr
    assert abs(fit.curve.amplitude - amplitude) < 4 * fit.amplitude_stderr
    assert abs(fit.curve.tau_s - tau_s) < 4 * fit.tau_stderr_s
    assert 0 < fit.tau_stderr_s < 0.05 * tau_s
    assert fit.residual_std == pytest.approx(noise, rel=0.1)
    assert fit.n == t.size


def test_standard_errors_match_the_scatter_of_repeated_fits() -> None:
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 2000.0, 10.0)
    truth = ExponentialCurve(kind="rising", y0=1.0, amplitude=50.0, tau_s=400.0)
    fits = [fit_exponential(t, truth(t) + rng.normal(0, 1.0, t.size)) for _ in range(60)]
    taus = np.array([f.curve.tau_s for f in fits])
    reported = np.mean([f.tau_stderr_s for f in fits])
    assert np.std(taus, ddof=1) == pytest.approx(reported, rel=0.3)


def test_steady_state_of_a_clean_curve_is_where_it_enters_the_band() -> None:
    # 150 (1 - exp(-t/300)) is within 1.5 um of 150 from t = 300 ln(100) = 1381.55 s.
    curve = ExponentialCurve(kind="rising", y0=0.0, amplitude=150.0, tau_s=300.0)
    assert curve.settling_time_s(1.5) == pytest.approx(300 * math.log(100))
    t = np.arange(0.0, 20000.0, 1.0)
    steady, band = steady_state_time(t, curve(t), band=1.5, final_fraction=0.05)
    assert band == 1.5
    assert steady == pytest.approx(300 * math.log(100), abs=1.0)


def test_steady_state_band_defaults_to_three_sigma_of_the_final_segment() -> None:
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 4000.0, 2.0)
    y = 10 * (1 - np.exp(-t / 200)) + rng.normal(0, 0.05, t.size)
    steady, band = steady_state_time(t, y)
    assert band == pytest.approx(3 * 0.05, rel=0.15)
    # The curve is within 0.15 of 10 after 200 ln(10/0.15) = 840 s; noise can push the last
    # excursion somewhat later, never earlier than the clean curve allows.
    assert steady is not None and 700 < steady < 2000
    fit = fit_exponential(t, y)
    assert fit.steady_band == pytest.approx(band)
    assert fit.steady_state_s == steady


def test_a_signal_still_moving_at_the_end_has_no_steady_state() -> None:
    t = np.arange(100.0)
    steady, _ = steady_state_time(t, t * 2.0, band=0.5)
    assert steady is None


def test_unfittable_data_is_a_clear_error() -> None:
    with pytest.raises(FitError, match="flat"):
        fit_exponential(np.arange(10.0), np.ones(10))
    with pytest.raises(FitError, match="at least 4"):
        fit_exponential([0.0, 1.0, 2.0], [0.0, 1.0, 1.5])
    with pytest.raises(ValueError, match="kind"):
        fit_exponential(np.arange(10.0), np.arange(10.0), "linear")  # type: ignore[arg-type]


def test_a_slow_rise_cut_short_is_not_steady_though_its_last_fifth_is_banded() -> None:
    """Issue 19: 600 s of a rise with tau 2730 s. Its last fifth spans a wide band, so the
    data test alone calls it steady long before the end; the fitted curve is still far from
    its asymptote at 600 s, so the fit says it is not steady, and gives tau."""
    rng = np.random.default_rng(19)
    t = np.arange(0.0, 600.0, 1.0)
    y = 120 * (1 - np.exp(-t / 2730)) + rng.normal(0, 0.3, t.size)
    data_only, band = steady_state_time(t, y)
    assert data_only is not None and data_only < 600  # the misleading answer
    fit = fit_exponential(t, y)
    assert fit.steady_state_s is None and fit.end_s == 599.0
    assert fit.curve.settling_time_s(band) > 600
    assert fit.curve.tau_s == pytest.approx(2730, rel=0.3)
    document = fit.to_dict()
    assert document["steady"] is False and document["fit_settling_s"] > 600


@pytest.mark.slow
def test_the_report_says_not_steady_with_the_time_constant(tmp_path: Path) -> None:
    rng = np.random.default_rng(20)
    rows = [
        {
            "step": k,
            "scheduled_s": float(k),
            "predicted_x_um": 120 * (1 - math.exp(-k / 2730)) + rng.normal(0, 0.3),
            "residual_um": rng.normal(0, 0.5),
        }
        for k in range(600)
    ]
    page = write_report(rows, tmp_path).html.read_text(encoding="utf-8")
    assert "not steady within the run (τ = " in page and "fit settles (s)" in page
