"""Online adaptation in the IR observer (daemon.model.adaptation, issue 19): the heat and
convection factors estimated with the temperatures converge to the truth within their own
reported uncertainty, and change nothing beyond noise when the model is right."""

from __future__ import annotations

import math

import numpy as np
import pytest

from daemon.model import ThermalModel, ThermalNetwork, load_network
from daemon.model.adaptation import adaptation_priors, adapted_parameters
from daemon.model.calibration import CalibratedParameter, Calibration
from daemon.model.identify import apply_parameters, parse_parameters
from daemon.model.model import ModelError
from daemon.model.observer import STAND_DRIFT_SIGMA_UM, IrObserver
from tests.test_model_steppers import lumped  # the one-node network of the analytic oracles

AMBIENT_C = 22.0
HEAT = {"2": 0.5, "9": 0.5}
REGIONS = {"node-2": ("2",), "node-9": ("9",), "node-16": ("16",)}
IR_NOISE_C = 0.05
IR_OFFSET_C = 0.5


@pytest.fixture(scope="module")
def preset() -> ThermalNetwork:
    return load_network("thesis-two-link")


def test_one_node_converges_to_the_closed_form_truth_within_its_uncertainty() -> None:
    """C dT/dt = s_h q - s_c g (T - T_amb): T = T_amb + s_h q / (s_c g) (1 - e^{-s_c g t / C}).
    The early slope tells s_h, the level s_c; the model believes s_h = s_c = 1."""
    capacitance, r_ambient, heat_w = 10.0, 5.0, 1.0
    true_heat, true_convection = 1.4, 0.8
    network = lumped(capacitance, r_ambient)
    model = ThermalModel(network, dt_s=1.0, ambient_c=AMBIENT_C)
    model.set_heat({"only": heat_w})
    observer = IrObserver(
        model, {"ir": ("only",)}, 0.01, adapt=adapted_parameters(network), parameter_random_walk=0
    )
    rng = np.random.default_rng(3)
    g = true_convection / r_ambient
    for t in range(1, 401):
        truth = AMBIENT_C + true_heat * heat_w / g * (1 - math.exp(-g * t / capacitance))
        observer.step(float(t), {"ir": truth + 0.3 + float(rng.normal(0.0, 0.01))})
    estimates = observer.parameter_estimates()
    for name, truth in (("heat", true_heat), ("convection", true_convection)):
        value, sigma = estimates[name]
        assert 0 < sigma < 0.05 * truth  # it learnt (the prior: 0.5 in the log)
        assert abs(value - truth) <= 3 * sigma, (name, value, sigma)
    offset, offset_sigma = estimates["offset:ir"]
    assert abs(offset - 0.3) <= 3 * offset_sigma


def truth_model(
    preset: ThermalNetwork, heat: float, convection: float, dt_s: float
) -> ThermalModel:
    specs = parse_parameters(["convection"], preset, REGIONS)
    network = apply_parameters(preset, specs, np.array([math.log(convection)]), REGIONS).network
    model = ThermalModel(network, dt_s=dt_s)
    model.set_heat({node: watts * heat for node, watts in HEAT.items()})
    return model


def follow(
    preset: ThermalNetwork, heat: float, convection: float, *, adapt: bool, seed: int = 0
) -> tuple[IrObserver, float]:
    """One hour at 5 s of the preset against a truth with the given factors; the observer and
    its deformation error's RMS over the second half (µm)."""
    dt_s = 5.0
    truth = truth_model(preset, heat, convection, dt_s)
    model = ThermalModel(preset, dt_s=dt_s)
    model.set_heat(HEAT)
    observer = IrObserver(
        model, REGIONS, IR_NOISE_C, adapt=adapted_parameters(preset) if adapt else ()
    )
    rng = np.random.default_rng(seed)
    errors = []
    for k in range(1, 721):
        t = k * dt_s
        truth.advance_to(t)
        readings = {
            region: float(truth.temperatures_c[preset.node_index(nodes[0])])
            + IR_OFFSET_C
            + float(rng.normal(0.0, IR_NOISE_C))
            for region, nodes in REGIONS.items()
        }
        deformation, _ = observer.step(t, readings)
        errors.append(deformation - truth.deformation_um_scalar())
    half = np.array(errors[len(errors) // 2 :])
    return observer, float(np.sqrt(np.mean(half**2)))


@pytest.mark.parametrize(("heat", "convection"), [(1.3, 0.7), (0.7, 1.0), (1.0, 1.5)])
def test_wrong_model_factors_converge_within_their_uncertainty(
    preset: ThermalNetwork, heat: float, convection: float
) -> None:
    adapted, adapted_rms = follow(preset, heat, convection, adapt=True)
    estimates = adapted.parameter_estimates()
    for name, truth in (("heat", heat), ("convection", convection)):
        value, sigma = estimates[name]
        assert 0 < sigma < 0.15 * truth
        assert abs(value - truth) <= 3 * sigma, (name, value, sigma)
    for region in REGIONS:
        offset, sigma = estimates[f"offset:{region}"]
        assert abs(offset - IR_OFFSET_C) <= 3 * sigma
    # the plain filter follows the temperatures but not the model's error: adaptation does
    _, plain_rms = follow(preset, heat, convection, adapt=False)
    assert adapted_rms < plain_rms


def test_right_model_adaptation_changes_nothing_beyond_noise(preset: ThermalNetwork) -> None:
    adapted, adapted_rms = follow(preset, 1.0, 1.0, adapt=True, seed=5)
    _, plain_rms = follow(preset, 1.0, 1.0, adapt=False, seed=5)
    for name in ("heat", "convection"):
        value, sigma = adapted.parameter_estimates()[name]
        assert abs(value - 1.0) <= 3 * sigma, (name, value, sigma)
    # the deformation error stays at the filter's noise level (a few hundredths of a µm)
    assert adapted_rms <= 2 * plain_rms + 0.02


def test_the_measured_deformation_teaches_alpha_alone(preset: ThermalNetwork) -> None:
    """A truth expanding 1.2x what the model believes: the measured deformation teaches the
    ``alpha`` factor (within its 1-sigma) and the corrected deformation follows, while the
    temperatures are exactly those of a filter that never saw the camera."""
    dt_s, true_alpha = 5.0, 1.2
    specs = parse_parameters(["alpha"], preset, REGIONS)
    expanding = apply_parameters(preset, specs, np.array([math.log(true_alpha)]), REGIONS)
    truth = ThermalModel(expanding.network, dt_s=dt_s)
    truth.set_heat(HEAT)
    observers = []
    for _ in range(2):
        model = ThermalModel(preset, dt_s=dt_s)
        model.set_heat(HEAT)
        observers.append(IrObserver(model, REGIONS, IR_NOISE_C, adapt=adapted_parameters(preset)))
    with_camera, without = observers
    rng = np.random.default_rng(11)
    errors: dict[int, list[float]] = {0: [], 1: []}
    for k in range(1, 721):
        t = k * dt_s
        truth.advance_to(t)
        readings = {
            region: float(truth.temperatures_c[preset.node_index(nodes[0])])
            + float(rng.normal(0.0, IR_NOISE_C))
            for region, nodes in REGIONS.items()
        }
        for observer in observers:
            observer.step(t, readings)
        measured = truth.deformation_um_scalar() + float(rng.normal(0.0, 0.2))
        assert with_camera.update_deformation(measured, 0.2) is not None
        assert without.update_deformation(math.nan, 0.2) is None
        for n, observer in enumerate(observers):
            errors[n].append(observer.corrected_deformation_um()[0] - truth.deformation_um_scalar())
        np.testing.assert_allclose(with_camera.temperatures_c, without.temperatures_c, atol=1e-9)
    value, sigma = with_camera.parameter_estimates()["alpha"]
    assert 0 < sigma < 0.02
    assert abs(value - true_alpha) <= 3 * sigma
    assert without.parameter_estimates()["alpha"][0] == 1.0
    rms = [float(np.sqrt(np.mean(np.square(errors[n][360:])))) for n in (0, 1)]
    assert rms[0] < 0.2  # µm: the filter's noise level, where the camera-blind one is 20 % off
    assert rms[0] < rms[1] / 10


def test_with_infinite_ir_noise_adaptation_is_the_open_loop_model_exactly(
    preset: ThermalNetwork,
) -> None:
    open_loop = ThermalModel(preset, dt_s=1.0)
    open_loop.set_heat(HEAT)
    model = ThermalModel(preset, dt_s=1.0)
    model.set_heat(HEAT)
    observer = IrObserver(model, REGIONS, math.inf, adapt=adapted_parameters(preset))
    for t in (0.4, 1.0, 2.5, 60.0, 61.3, 900.0):
        open_loop.advance_to(t)
        observer.step(t, {region: 99.0 for region in REGIONS})
        np.testing.assert_array_equal(observer.temperatures_c, open_loop.temperatures_c)
    assert observer.parameter_estimates()["heat"][0] == 1.0


def test_an_identified_prior_is_kept_and_a_certain_one_is_fixed(preset: ThermalNetwork) -> None:
    """Priors (e.g. identification's value and relative error): a certain prior with no
    random walk never moves, even when wrong; an uncertain one learns."""
    dt_s = 5.0
    truth = truth_model(preset, 1.3, 1.0, dt_s)
    model = ThermalModel(preset, dt_s=dt_s)
    model.set_heat(HEAT)
    priors = {"heat": (1.1, 0.0), "convection": (0.9, 0.2)}
    observer = IrObserver(
        model,
        REGIONS,
        IR_NOISE_C,
        adapt=adapted_parameters(preset, priors=priors),
        parameter_random_walk=0.0,
    )
    rng = np.random.default_rng(7)
    assert observer.parameter_estimates()["convection"] == pytest.approx((0.9, 0.9 * 0.2))
    for k in range(1, 361):
        truth.advance_to(k * dt_s)
        readings = {
            region: float(truth.temperatures_c[preset.node_index(nodes[0])])
            + float(rng.normal(0.0, IR_NOISE_C))
            for region, nodes in REGIONS.items()
        }
        observer.step(k * dt_s, readings)
    estimates = observer.parameter_estimates()
    assert estimates["heat"][0] == pytest.approx(1.1, abs=1e-12)
    assert estimates["heat"][1] == 0.0
    assert estimates["convection"][0] != pytest.approx(0.9, abs=1e-3)  # it moved


def test_adapted_parameters_are_checked(preset: ThermalNetwork) -> None:
    parsed = adapted_parameters(preset, ["heat:9", "convection"], {"heat:9": (1.2, 0.1)})
    assert [(p.name, p.kind) for p in parsed] == [("heat:9", "heat"), ("convection", "convection")]
    assert parsed[0].node_indices == (preset.node_index("9"),)
    assert parsed[0].prior_log == pytest.approx(math.log(1.2))
    assert parsed[1].node_indices == tuple(range(preset.node_count))
    with pytest.raises(ModelError, match="unknown adapted parameter 'contact:3'"):
        adapted_parameters(preset, ["contact:3"])
    with pytest.raises(ModelError, match="unknown adapted parameter 'alpha:3'"):
        adapted_parameters(preset, ["alpha:3"])
    with pytest.raises(ModelError, match="heat:nowhere"):
        adapted_parameters(preset, ["heat:nowhere"])
    with pytest.raises(ModelError, match="given twice"):
        adapted_parameters(preset, ["heat", "heat"])
    with pytest.raises(ModelError, match="prior"):
        adapted_parameters(preset, ["heat"], {"heat": (0.0, 0.1)})


def calibration(*parameters: CalibratedParameter) -> Calibration:
    return Calibration("thesis-two-link", ("1",), "2026-11-23T00:00:00Z", parameters=parameters)


def test_an_identified_network_gives_the_priors_and_what_not_to_adapt() -> None:
    names = ("heat", "heat:9", "convection")
    assert adaptation_priors(None, names, 0.4) == (names, dict.fromkeys(names, (1.0, 0.4)))
    identified = calibration(
        CalibratedParameter("heat:2", 1.21, 0.024, 0.02),
        CalibratedParameter("heat:9", 1.19, 0.036, 0.03),
        CalibratedParameter("convection", 0.72, 0.036, 0.05),
        CalibratedParameter("alpha", 1.0, None, None, identifiable=False, reason="unseen"),
    )
    # the file holds the identified values: prior 1 with identification's relative error;
    # one heat factor over both heaters takes the larger error
    assert adaptation_priors(identified, names, 0.4) == (
        names,
        {"heat": (1.0, 0.03), "heat:9": (1.0, 0.03), "convection": (1.0, 0.05)},
    )
    unidentifiable = calibration(
        CalibratedParameter("heat", 1.2, 0.02, 0.017),
        CalibratedParameter("convection", 0.7, 2.0, 3.0, identifiable=False, reason="SE"),
    )
    assert adaptation_priors(unidentifiable, names, 0.4) == (
        ("heat", "heat:9"),
        {"heat": (1.0, 0.017), "heat:9": (1.0, 0.017)},
    )
    # what identification did not fit keeps the default prior
    only_alpha = calibration(CalibratedParameter("alpha", 1.1, 0.01, 0.01))
    assert adaptation_priors(only_alpha, ("heat",), 0.4) == (("heat",), {"heat": (1.0, 0.4)})


def test_a_stand_drift_of_known_shape_is_not_taken_for_expansion(preset: ThermalNetwork) -> None:
    """The spot drift carries a stand warm-up A (1 - e^{-t/tau}) (thesis 4.8) besides the
    link's 1.2x expansion: with the stand drift in the state both come out within their
    1-sigma; without it, alpha takes in the stand and misses the truth."""
    dt_s, true_alpha, stand_um, tau_s, scale = 5.0, 1.2, 3.0, 600.0, 2.0
    specs = parse_parameters(["alpha"], preset, REGIONS)
    expanding = apply_parameters(preset, specs, np.array([math.log(true_alpha)]), REGIONS)
    truth = ThermalModel(expanding.network, dt_s=dt_s)
    truth.set_heat(HEAT)
    observers = []
    for tau in (tau_s, None):
        model = ThermalModel(preset, dt_s=dt_s)
        model.set_heat(HEAT)
        adapt = adapted_parameters(preset, ["alpha"])
        observers.append(IrObserver(model, REGIONS, IR_NOISE_C, adapt=adapt, stand_drift_tau_s=tau))
    rng = np.random.default_rng(13)
    for k in range(1, 721):
        t = k * dt_s
        truth.advance_to(t)
        readings = {
            region: float(truth.temperatures_c[preset.node_index(nodes[0])])
            + float(rng.normal(0.0, IR_NOISE_C))
            for region, nodes in REGIONS.items()
        }
        # what the camera sees (scaled µm): the scaled link, the stand, the noise; unscaled
        chip_um = scale * truth.deformation_um_scalar() + stand_um * (1 - math.exp(-t / tau_s))
        measured = (chip_um + float(rng.normal(0.0, 0.2))) / scale
        for observer in observers:
            observer.step(t, readings)
            observer.update_deformation(measured, 0.2 / scale, scale)
    with_stand, without = (o.parameter_estimates() for o in observers)
    alpha, alpha_sigma = with_stand["alpha"]
    assert abs(alpha - true_alpha) <= 3 * alpha_sigma
    amplitude, amplitude_sigma = with_stand["stand_drift_um"]
    assert amplitude_sigma < STAND_DRIFT_SIGMA_UM / 3  # it learnt
    assert abs(amplitude - stand_um) <= 3 * amplitude_sigma
    assert "stand_drift_um" not in without
    biased, biased_sigma = without["alpha"]
    assert abs(biased - true_alpha) > 3 * biased_sigma


def test_a_barely_known_alpha_is_applied_shrunk_towards_its_prior(
    preset: ThermalNetwork,
) -> None:
    """Applied: prior + u^3 / (u^2 + sigma^2) in the log (u: the estimate's departure), so an
    uncertain estimate moves the compensation less than it moved itself, a sure one fully."""
    model = ThermalModel(preset, dt_s=1.0)
    model.set_heat(HEAT)
    prior = adapted_parameters(preset, ["alpha"], {"alpha": (1.1, 0.5)})
    observer = IrObserver(model, REGIONS, IR_NOISE_C, adapt=prior, stand_drift_tau_s=None)
    assert observer.deformation_gain == pytest.approx(1.1)  # no data: the prior
    observer.step(600.0, None)
    predicted = observer.model.deformation_um_scalar()
    observer.update_deformation(1.3 * predicted, noise_um=0.05 * predicted)
    estimate, sigma = observer.parameter_estimates()["alpha"]
    departure, log_sigma = math.log(estimate / 1.1), sigma / estimate
    applied = 1.1 * math.exp(departure**3 / (departure**2 + log_sigma**2))
    assert observer.deformation_gain == pytest.approx(applied)
    assert 1.1 < observer.deformation_gain < estimate
    assert observer.corrected_deformation_um()[0] == pytest.approx(applied * predicted)
