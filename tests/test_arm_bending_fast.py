"""The UR's followed model with the links' bending, made cheap (issue 31): the Kalman filter's
covariance steps by the structure of their matrices (daemon/model/covariance.py) give what the
dense formulas give, step by step and over a followed run, and the filter's products run on
one BLAS thread (daemon/model/blas.py: on two, an 88-state product cost ~16 ms of CPU on a
loaded machine). The shipped UR bench config has bending and the room thermometer on."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

import daemon.model.observer as observer_module
from config.settings import load_settings
from daemon.arm.controller import ArmController, ArmModelOptions
from daemon.arm.controller_loading import load_controller
from daemon.arm.joint_temperatures import JointTemperatureModel
from daemon.model.covariance import joseph_update, propagate_nodes
from daemon.model.network import FloatArray
from daemon.run.arm.setup import ARMS_DIR
from daemon.run.followed.setup import JOINT_SENSOR_NOISE_C, followed_model
from daemon.run.states import RunParameters

REPO_ROOT = Path(__file__).resolve().parent.parent
ARM = ARMS_DIR / "ur5e.toml"
DUTY = "ur5e-pick-and-place"
#: the followed model with the links' bending, 10 s steps (the algebra does not depend on
#: the step; 0.1 s steps would only make the test slower)
OPTIONS = ArmModelOptions(bending=True, motor_side_share=0.75, model_dt_s=10.0)
#: states of the UR5e's filter with bending: 75 nodes, 6 joint offsets, 7 adapted factors
STATES = 88
#: agreement with the dense formulas, relative to the covariance's largest entry (and the
#: temperatures'): the same algebra in another order, so rounding, ~1e-16 per product
TOLERANCE = 1e-9


def dense_propagate(
    p: FloatArray, nodes: int, a: FloatArray, b: FloatArray, noise: FloatArray
) -> FloatArray:
    """The oracle: the whole Jacobian ``J = [[a, b], [0, I]]``, ``J P J^T + diag(noise)``."""
    jacobian = np.eye(p.shape[0])
    jacobian[:nodes, :nodes] = a
    jacobian[:nodes, nodes:] = b
    result: FloatArray = jacobian @ p @ jacobian.T + np.diag(noise)
    return result


def dense_joseph(
    p: FloatArray, gain: FloatArray, h: FloatArray, hp: FloatArray, noise: FloatArray
) -> FloatArray:
    """The oracle: ``(I - K H) P (I - K H)^T + K R K^T`` with the whole ``I - K H``."""
    identity_minus = np.eye(p.shape[0]) - gain @ h
    result: FloatArray = identity_minus @ p @ identity_minus.T + gain @ np.diag(noise) @ gain.T
    return result


def random_covariance(rng: np.random.Generator, size: int) -> FloatArray:
    """A covariance with the filter's spread of scales (1e-6 .. 4 degC^2)."""
    root = rng.normal(size=(size, size)) * np.exp(rng.uniform(-7.0, 0.7, size))[:, None]
    result: FloatArray = root @ root.T
    return result


def close(fast: FloatArray, oracle: FloatArray) -> bool:
    return bool(np.max(np.abs(fast - oracle)) <= TOLERANCE * np.max(np.abs(oracle)))


def test_the_structured_propagation_is_the_dense_one() -> None:
    """``J P J^T`` by blocks equals the dense product for the filter's shapes, including a
    Jacobian whose constant states all feed the nodes (``b`` full)."""
    rng = np.random.default_rng(3)
    for nodes, size in ((75, STATES), (41, 54), (5, 5), (3, 9)):
        p = random_covariance(rng, size)
        a = np.eye(nodes) + 0.1 * rng.normal(size=(nodes, nodes))
        b = rng.normal(size=(nodes, size - nodes))
        noise = rng.uniform(0.0, 1e-3, size)
        fast = propagate_nodes(p, nodes, a, b, noise)
        oracle = dense_propagate(p, nodes, a, b, noise)
        assert close(fast, oracle), (nodes, size)
        assert np.array_equal(fast, fast.T) or close(fast, fast.T)


def test_the_structured_joseph_update_is_the_dense_one_for_any_gain() -> None:
    """The rank-m Joseph form equals the dense one for the optimal gain and for a wrong one
    (the Joseph form's point: right for any gain, so an expansion that assumed the optimal
    gain would fail the second)."""
    rng = np.random.default_rng(5)
    size, readings = STATES, 6
    p = random_covariance(rng, size)
    h = np.zeros((readings, size))
    h[np.arange(readings), rng.choice(75, readings, replace=False)] = 1.0
    h[np.arange(readings), 75 + np.arange(readings)] = 1.0  # each reading's offset
    noise = np.full(readings, JOINT_SENSOR_NOISE_C**2)
    hp = h @ p
    optimal = np.asarray(np.linalg.solve(hp @ h.T + np.diag(noise), hp).T, dtype=np.float64)
    for gain in (optimal, optimal * 0.7 + 0.01 * rng.normal(size=optimal.shape)):
        fast = joseph_update(p, gain, h, hp, noise)
        assert close(fast, dense_joseph(p, gain, h, hp, noise))


@contextmanager
def dense_filter(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """The observer with the dense formulas (what it computed before)."""
    with monkeypatch.context() as patch:
        patch.setattr(observer_module, "propagate_nodes", dense_propagate)
        patch.setattr(observer_module, "joseph_update", dense_joseph)
        yield


def followed(model: JointTemperatureModel, truth: ArmController, steps: int, rng_seed: int) -> None:
    """``steps`` steps of a followed run: the model advanced, fed the truth's joint
    temperatures with a sensor's noise and an offset each (the filter's factors and offsets
    then move, not only its temperatures)."""
    rng = np.random.default_rng(rng_seed)
    offsets = np.array([0.4, -0.3, 0.2, 0.5, -0.1, 0.3])
    start = model.time_s
    for k in range(1, steps + 1):
        t = start + k * OPTIONS.model_dt_s
        truth.advance_to(t)
        model.advance_to(t)
        reading = truth.thermal.joint_temperatures_c() + offsets
        model.observe((reading + rng.normal(0.0, JOINT_SENSOR_NOISE_C, 6)).tolist())


def observer_state(model: JointTemperatureModel) -> tuple[FloatArray, FloatArray, FloatArray]:
    observer = model.controller.observer
    assert observer is not None
    estimates = observer.parameter_estimates()
    values = np.array([estimates[name][0] for name in sorted(estimates)])
    return observer.temperatures_c, values, observer._p.copy()


def test_a_followed_run_with_bending_is_the_dense_filters(monkeypatch: pytest.MonkeyPatch) -> None:
    """40 minutes of a followed UR5e run with bending, against a truth whose motors heat 30 %
    more: the structured filter's temperatures, factors, offsets and covariance are the dense
    filter's, checked every 10 minutes; and the run did move the filter (its factors left
    their prior, its covariance shrank), so the comparison is not of two idle filters."""
    truths = [load_controller(ARM, DUTY, OPTIONS) for _ in range(2)]
    for truth in truths:
        truth.heat_scales = np.full(6, 1.3)
    fast = JointTemperatureModel(load_controller(ARM, DUTY, OPTIONS), JOINT_SENSOR_NOISE_C)
    dense = JointTemperatureModel(load_controller(ARM, DUTY, OPTIONS), JOINT_SENSOR_NOISE_C)
    assert fast.controller.observer is not None
    assert fast.controller.observer._p.shape == (STATES, STATES)
    prior = observer_state(fast)
    for block in range(4):
        followed(fast, truths[0], 60, block)
        with dense_filter(monkeypatch):
            followed(dense, truths[1], 60, block)
        (t_fast, v_fast, p_fast), (t_dense, v_dense, p_dense) = (
            observer_state(fast),
            observer_state(dense),
        )
        assert np.allclose(t_fast, t_dense, rtol=TOLERANCE, atol=0.0), block
        assert np.allclose(v_fast, v_dense, rtol=TOLERANCE, atol=TOLERANCE), block
        assert close(p_fast, p_dense), block
    heat = [n for n in fast.controller.observer.parameter_estimates() if n.startswith("heat:")]
    estimates = fast.controller.observer.parameter_estimates()
    # the heated joints' factors followed the truth's 1.3 (wrist 2 releases no heat here)
    assert sum(estimates[n][0] > 1.15 for n in heat) >= 4, estimates
    assert np.trace(p_fast) < 0.5 * np.trace(prior[2])


def test_the_filters_products_run_on_one_blas_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    """With BLAS allowed two threads, the filter's propagation and update run on one, and
    the setting is given back after each."""

    def numpy_blas_threads() -> int:
        # numpy's own BLAS (the filter's products are numpy's)
        infos = [i for i in threadpool_info() if i["user_api"] == "blas"]
        chosen = [i for i in infos if "numpy" in i["filepath"]] or infos
        return int(chosen[0]["num_threads"])

    seen: list[int] = []

    def spied(function: Callable[..., FloatArray]) -> Callable[..., FloatArray]:
        def call(*args: Any) -> FloatArray:
            seen.append(numpy_blas_threads())
            return function(*args)

        return call

    monkeypatch.setattr(observer_module, "propagate_nodes", spied(propagate_nodes))
    monkeypatch.setattr(observer_module, "joseph_update", spied(joseph_update))
    truth = load_controller(ARM, DUTY, OPTIONS)
    model = JointTemperatureModel(load_controller(ARM, DUTY, OPTIONS), JOINT_SENSOR_NOISE_C)
    with threadpool_limits(limits=2, user_api="blas"):
        followed(model, truth, 3, 0)
        after = numpy_blas_threads()
    assert seen == [1] * 6
    assert after == 2


def test_the_shipped_ur_bench_follows_the_bending_and_the_room() -> None:
    """config/ur5e-sim.toml, as a lab following the guide has it: the links' bending on (the
    88-state filter), the bench's room thermometer."""
    settings = load_settings(REPO_ROOT / "config" / "ur5e-sim.toml")
    assert settings.arm.bending and settings.room.driver == "sim"
    model = followed_model(settings, RunParameters.from_settings(settings))
    assert model.controller.options.bending
    assert model.controller.observer is not None
    assert model.controller.observer._p.shape == (STATES, STATES)
