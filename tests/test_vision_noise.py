"""The centroid's noise model with no setting touched (issue 30): the gain measured on each
frame by photon transfer, checked against the sensor that made the frames (known gain, the
Cramér–Rao bound) at 8, 12 and 16 bits, and against a hand-made residual field."""

from __future__ import annotations

import math

import numpy as np
import pytest

from config.settings import CameraSettings
from daemon.vision import cramer_rao_bound, full_scale, measure_centroid, render_spot
from daemon.vision.centroid import measure_with_camera_settings
from daemon.vision.photon_transfer import NoiseModel, estimate_noise_model

SHAPE = (120, 160)
#: the benchmark's sensor: dark 100 e-, read noise 5 e-, full well 65,535 e- at every depth
DARK_E, READ_E, FULL_WELL_E = 100.0, 5.0, 65535.0


def sensor(bit_depth: int) -> dict[str, float]:
    gain = FULL_WELL_E / full_scale(bit_depth)
    return {
        "background": DARK_E / gain,
        "read_noise_counts": READ_E / gain,
        "gain_e_per_count": gain,
    }


@pytest.mark.parametrize(
    ("bit_depth", "sigma_px", "peak"),
    [(16, 3.0, 0.5), (16, 2.0, 0.1), (12, 5.0, 0.8), (12, 3.0, 2.0), (8, 2.0, 0.1), (8, 3.0, 0.5)],
)
def test_default_settings_meet_the_bound_and_report_the_scatter(
    bit_depth: int, sigma_px: float, peak: float
) -> None:
    """No gain given (the default [camera] section): RMS within 1.3x the Cramér–Rao bound and
    the median reported 1-sigma within 20 % of the observed scatter. With the old default of
    1 e-/count the 8-bit report was ~17x the scatter and the 8-bit RMS 2.4x the bound."""
    noise = sensor(bit_depth)
    rng = np.random.default_rng(bit_depth * 100 + int(10 * sigma_px) + int(10 * peak))
    errors, reported, gains = [], [], []
    for _ in range(150):
        centre = (60 + 30 * rng.random(), 50 + 20 * rng.random())
        image = render_spot(SHAPE, centre, sigma_px, peak, bit_depth=bit_depth, rng=rng, **noise)
        result = measure_centroid(image, bit_depth=bit_depth)
        assert result.gain_source == "frames"
        errors.append((result.x_px - centre[0], result.y_px - centre[1]))
        reported.append((result.sigma_x_px, result.sigma_y_px))
        gains.append(result.gain_e_per_count)
    bound = float(
        np.mean(cramer_rao_bound(SHAPE, (75.3, 60.6), sigma_px, peak, bit_depth, **noise))
    )
    rms = float(np.sqrt(np.mean(np.square(errors))))
    assert rms <= 1.3 * bound
    assert float(np.median(reported)) == pytest.approx(rms, rel=0.2)
    # the gain itself: within 20 % (rounding inflates the 8-bit frames' faint pixels a little)
    assert float(np.median(gains)) == pytest.approx(noise["gain_e_per_count"], rel=0.2)


def test_who_gave_the_gain_is_said() -> None:
    image = render_spot(SHAPE, (80.3, 60.6), 3.0, 0.5, rng=np.random.default_rng(3), background=100)
    assert measure_centroid(image).gain_source == "frames"
    told = measure_centroid(image, gain_e_per_count=2.0, read_noise_e=5.0)
    assert (told.gain_source, told.gain_e_per_count) == ("config", 2.0)
    camera = CameraSettings()
    assert camera.gain_e_per_count is None  # the default: nothing to set
    from_camera = measure_with_camera_settings(image, camera, camera_gain_e_per_count=3.0)
    assert (from_camera.gain_source, from_camera.gain_e_per_count) == ("camera", 3.0)
    assert measure_with_camera_settings(image, camera).gain_source == "frames"
    configured = CameraSettings(gain_e_per_count=4.0)
    result = measure_with_camera_settings(image, configured, camera_gain_e_per_count=3.0)
    assert (result.gain_source, result.gain_e_per_count) == ("config", 4.0)
    thesis = measure_centroid(image, method="thesis", low=200)
    assert thesis.gain_source == "unknown"


def test_photon_transfer_recovers_a_known_variance_line() -> None:
    """Residuals drawn with variance offset + slope * model: the slope comes back, and a
    smooth misfit of the model (a broad bump, as a slightly non-Gaussian spot leaves) does
    not read as shot noise."""
    rng = np.random.default_rng(7)
    rows, columns = np.mgrid[0:41, 0:41]
    model = 4000.0 * np.exp(-((rows - 20.0) ** 2 + (columns - 20.0) ** 2) / (2 * 5.0**2))
    truth = NoiseModel(offset=25.0, slope=0.25)  # 4 e-/count
    usable = np.ones(model.shape, dtype=bool)
    slopes, bumped = [], []
    misfit = 60.0 * np.exp(-((rows - 20.0) ** 2 + (columns - 20.0) ** 2) / (2 * 8.0**2))
    for _ in range(40):
        excess = model + rng.normal(0.0, 1.0, model.shape) * np.sqrt(truth.variance(model))
        slopes.append(estimate_noise_model(excess, model, usable, offset=25.0).slope)
        bumped.append(estimate_noise_model(excess + misfit, model, usable, offset=25.0).slope)
    assert float(np.mean(slopes)) == pytest.approx(0.25, rel=0.03)
    assert float(np.mean(bumped)) == pytest.approx(0.25, rel=0.05)
    # direct residuals would have read the bump's mean square as noise: about 4x the slope
    direct = float(np.mean(misfit**2)) / float(np.mean(model))
    assert direct > 0.5


def test_too_few_pixels_or_no_shot_noise() -> None:
    model = np.full((3, 3), 10.0)
    assert estimate_noise_model(model, model, np.ones((3, 3), bool), offset=1.0) is None
    flat = np.zeros((20, 20))
    noise = np.random.default_rng(1).normal(0.0, 1.0, flat.shape)
    estimate = estimate_noise_model(noise, flat, np.ones(flat.shape, bool), offset=1.0)
    assert estimate is not None and estimate.slope == 0.0
    assert math.isclose(estimate.gain_e_per_count, 1e6)
    assert NoiseModel.from_gain(4.0, 8.0, 100.0) == NoiseModel(25.0 + 4.0 + 1 / 12, 0.25)
