"""The IR state observer (daemon.model.observer): a Kalman filter on the exact discretisation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from config.settings import BenchSettings, IrRegion, Settings
from daemon.model import ThermalModel, ThermalNetwork, load_network
from daemon.model.observer import DRIFT_WARNING, IrObserver, regions_to_nodes
from drivers.sim.bench import truth_network

HEAT = {"2": 0.5, "9": 0.5}
REGIONS = {"node-2": ("2",), "node-9": ("9",), "node-16": ("16",)}
IR_NOISE_C = 0.05
IR_OFFSET_C = 0.5


@pytest.fixture(scope="module")
def preset() -> ThermalNetwork:
    return load_network("thesis-two-link")


def controller(network: ThermalNetwork) -> ThermalModel:
    model = ThermalModel(network, dt_s=1.0)
    model.set_heat(HEAT)
    return model


def readings(
    truth: ThermalModel, rng: np.random.Generator, offset_c: float = IR_OFFSET_C
) -> dict[str, float]:
    return {
        region: float(truth.temperatures_c[truth.network.node_index(nodes[0])])
        + offset_c
        + float(rng.normal(0.0, IR_NOISE_C))
        for region, nodes in REGIONS.items()
    }


def test_infinite_ir_noise_is_the_open_loop_model_exactly(preset: ThermalNetwork) -> None:
    open_loop = controller(preset)
    observer = IrObserver(controller(preset), REGIONS, math.inf)
    truth = controller(preset)
    rng = np.random.default_rng(0)
    for t in (0.4, 1.0, 2.5, 60.0, 61.3, 900.0, 3600.0):  # partial steps too
        open_loop.advance_to(t)
        truth.advance_to(t)
        deformation, sigma = observer.step(t, readings(truth, rng, offset_c=3.0))
        assert observer.last_innovation is None  # nothing fused
        np.testing.assert_array_equal(observer.temperatures_c, open_loop.temperatures_c)
        assert deformation == open_loop.deformation_um_scalar()
        # the uncertainty grows with the process noise alone: sqrt(w^T P w) with P from Q
        assert sigma > 0.0
    assert not observer.drifting


def test_huge_finite_ir_noise_approaches_the_open_loop_model(preset: ThermalNetwork) -> None:
    open_loop = controller(preset)
    observer = IrObserver(controller(preset), REGIONS, 1e6, offset_sigma_c=0.0)
    rng = np.random.default_rng(1)
    for t in range(1, 601):
        open_loop.advance_to(float(t))
        observer.step(float(t), readings(open_loop, rng, offset_c=10.0))
    np.testing.assert_allclose(observer.temperatures_c, open_loop.temperatures_c, atol=1e-6)


def test_without_process_noise_and_offsets_the_covariance_stays_zero(
    preset: ThermalNetwork,
) -> None:
    """Known start, perfect model: the filter is certain and the readings change nothing."""
    observer = IrObserver(
        controller(preset), REGIONS, IR_NOISE_C, process_noise_c2_per_s=0.0, offset_sigma_c=0.0
    )
    open_loop = controller(preset)
    rng = np.random.default_rng(2)
    for t in range(1, 301):
        open_loop.advance_to(float(t))
        _, sigma = observer.step(float(t), readings(open_loop, rng, offset_c=0.0))
        assert sigma == 0.0
    np.testing.assert_allclose(observer.temperatures_c, open_loop.temperatures_c, atol=1e-12)


def test_converges_to_the_bench_truth_when_the_model_is_wrong(preset: ThermalNetwork) -> None:
    """The bench's truth (drivers.sim.bench): the preset with convection x0.7 and heat x1.3.
    The open-loop model is ~65 um off after an hour; the filter follows the truth, learns
    the IR offset, and its 1-sigma covers its error."""
    settings = Settings(
        bench=BenchSettings(
            truth_network="thesis-two-link", truth_convection_scale=0.7, truth_heat_scale=1.3
        )
    )
    truth = ThermalModel(truth_network(settings), dt_s=1.0)
    truth.set_heat({node: 1.3 * watts for node, watts in HEAT.items()})
    open_loop = controller(preset)
    observer = IrObserver(controller(preset), REGIONS, IR_NOISE_C)
    rng = np.random.default_rng(3)
    errors, sigmas, nis = [], [], []
    for step in range(1, 3601):
        t = float(step)
        truth.advance_to(t)
        open_loop.advance_to(t)
        deformation, sigma = observer.step(t, readings(truth, rng))
        errors.append(deformation - truth.deformation_um_scalar())
        sigmas.append(sigma)
        assert observer.last_innovation is not None
        nis.append(observer.last_innovation.nis)
    final_truth = truth.deformation_um_scalar()
    assert abs(open_loop.deformation_um_scalar() - final_truth) > 50.0
    last = np.array(errors[-600:])
    assert np.abs(last).max() < 2.0  # um, against > 50 um open loop
    assert np.sqrt(np.mean((last / np.array(sigmas[-600:])) ** 2)) < 2.0
    estimate = observer.offsets_c
    assert all(abs(v - IR_OFFSET_C) < 0.5 for v in estimate.values()), estimate
    # node temperatures nowhere near a region converge too (via the model's coupling)
    far = preset.node_index("12")
    assert abs(observer.temperatures_c[far] - truth.temperatures_c[far]) < 0.3
    # innovations stay consistent on the whole: NIS ~ chi-squared with 3 dof (mean 3)
    assert 1.5 < float(np.mean(nis)) < 6.0


def test_a_right_model_raises_no_drift_warning(preset: ThermalNetwork) -> None:
    """Right model, no process noise: only the IR offsets are unknown, so the innovations are
    white with the variance the filter claims and NIS is chi-squared with 3 dof."""
    truth = controller(preset)
    observer = IrObserver(controller(preset), REGIONS, IR_NOISE_C, process_noise_c2_per_s=0.0)
    rng = np.random.default_rng(4)
    nis = []
    for step in range(1, 1801):
        truth.advance_to(float(step))
        observer.step(float(step), readings(truth, rng))
        assert observer.last_innovation is not None
        nis.append(observer.last_innovation.nis)
    assert not observer.drifting
    assert observer.warning is None
    assert float(np.mean(nis)) == pytest.approx(3.0, rel=0.1)  # SE of the mean: 2 %


def test_a_persistent_bias_raises_the_drift_warning(preset: ThermalNetwork) -> None:
    """Truth heated 1.5x while the filter trusts its model (little process noise)."""
    truth = ThermalModel(preset, dt_s=1.0)
    truth.set_heat({node: 1.5 * watts for node, watts in HEAT.items()})
    observer = IrObserver(controller(preset), REGIONS, IR_NOISE_C, process_noise_c2_per_s=1e-7)
    rng = np.random.default_rng(5)
    for step in range(1, 1801):
        truth.advance_to(float(step))
        observer.step(float(step), readings(truth, rng))
    assert observer.drifting
    assert observer.warning == DRIFT_WARNING
    assert observer.biased_regions


def test_regions_from_settings_and_bad_noise(preset: ThermalNetwork) -> None:
    regions = (
        IrRegion(name="left", x=0, y=0, width=2, height=2, node="2"),
        IrRegion(name="background", x=5, y=5, width=2, height=2),
    )
    assert regions_to_nodes(regions) == {"left": ("2",)}
    with pytest.raises(ValueError, match="IR noise"):
        IrObserver(controller(preset), REGIONS, math.nan)
    with pytest.raises(ValueError, match="unknown node"):
        IrObserver(controller(preset), {"r": ("99",)}, 0.1)


def test_the_covariance_catches_up_when_the_caller_advances_the_model(
    preset: ThermalNetwork,
) -> None:
    """A heater switched at its exact time by the caller (model.advance_to) does not lose
    process noise: the covariance equals that of a filter predicted in one go."""
    direct = IrObserver(controller(preset), REGIONS, IR_NOISE_C)
    split = IrObserver(controller(preset), REGIONS, IR_NOISE_C)
    direct.predict(100.0)
    split.model.advance_to(37.5)
    split.model.set_heat({})
    split.predict(100.0)
    np.testing.assert_allclose(split.covariance_c2, direct.covariance_c2, rtol=1e-10, atol=0)
    assert split.corrected_deformation_um()[1] == direct.corrected_deformation_um()[1]
