"""The steppers against analytic oracles: lumped node, steady state, fin, semi-infinite solid,
energy balance, positivity, convergence order, and the on-demand ``advance_to``."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.special import erfc

from daemon.model import (
    Hole,
    ModelError,
    Resistance,
    Segment,
    ThermalModel,
    ThermalNetwork,
    build_geometry_network,
    load_network,
    material,
    positivity_bound_s,
    semi_infinite_deformation_m,
    steady_state_c,
)

AMBIENT_C = 22.0


def lumped(capacitance: float = 10.0, r_ambient: float = 5.0) -> ThermalNetwork:
    return ThermalNetwork(
        name="lumped",
        node_names=("only",),
        positions_mm=np.array([0.0]),
        capacitance_j_per_c=np.array([capacitance]),
        alpha_per_c=np.array([1e-5]),
        r_ambient_c_per_w=np.array([r_ambient]),
        r_end_c_per_w=np.array([math.inf]),
        resistances=(),
        reference_nodes=("only", "only"),
    )


def random_network(seed: int, count: int = 9) -> ThermalNetwork:
    """A chain with random C, R and R_inf plus a few random cross links (a general graph)."""
    rng = np.random.default_rng(seed)
    resistances = [Resistance(i, i + 1, float(rng.uniform(0.2, 3.0))) for i in range(count - 1)]
    for _ in range(3):
        a, b = rng.choice(count, size=2, replace=False)
        resistances.append(Resistance(int(a), int(b), float(rng.uniform(1.0, 10.0))))
    r_ambient = rng.uniform(50.0, 500.0, count)
    r_ambient[rng.random(count) < 0.3] = math.inf  # some nodes reach ambient only via others
    r_ambient[0] = 100.0
    return ThermalNetwork(
        name=f"random-{seed}",
        node_names=tuple(f"n{i}" for i in range(count)),
        positions_mm=np.arange(count, dtype=np.float64) * 10.0,
        capacitance_j_per_c=rng.uniform(1.0, 20.0, count),
        alpha_per_c=np.full(count, 2e-5),
        r_ambient_c_per_w=r_ambient,
        r_end_c_per_w=np.full(count, math.inf),
        resistances=tuple(resistances),
        reference_nodes=("n0", f"n{count - 1}"),
    )


# -- a single lumped node: T = T_amb + q R (1 - exp(-t / RC)) ----------------------------------


@pytest.mark.parametrize("dt_s", [0.1, 1.0, 7.0, 500.0])
def test_exact_stepper_matches_the_exponential_for_any_dt(dt_s: float) -> None:
    capacitance, resistance, heat = 10.0, 5.0, 2.0
    model = ThermalModel(lumped(capacitance, resistance), "exact", dt_s, AMBIENT_C)
    model.set_heat({"only": heat})
    for t_s in (0.3, 12.0, 49.5, 50.0, 1234.5):
        model.advance_to(t_s)
        expected = AMBIENT_C + heat * resistance * (1 - math.exp(-t_s / (resistance * capacitance)))
        assert model.temperatures_c[0] == pytest.approx(expected, rel=1e-12, abs=1e-12)
        assert model.time_s == t_s


def test_explicit_stepper_is_eq_5_1_on_one_node() -> None:
    capacitance, resistance, heat, dt_s = 10.0, 5.0, 2.0, 3.0
    model = ThermalModel(lumped(capacitance, resistance), "explicit", dt_s, AMBIENT_C)
    with pytest.raises(ValueError, match="heat input '1' names no node of network"):
        model.set_heat({"1": heat})  # never by number (issue 19): by name only
    model.set_heat({"only": heat})
    temperature = AMBIENT_C
    for step in range(1, 20):
        temperature += dt_s / capacitance * (heat + (AMBIENT_C - temperature) / resistance)
        model.advance_to(step * dt_s)
        assert model.temperatures_c[0] == pytest.approx(temperature, rel=1e-14)


# -- steady state -------------------------------------------------------------------------------


@pytest.mark.parametrize("stepper", ["exact", "implicit"])
@pytest.mark.parametrize("seed", [1, 2])
def test_long_run_reaches_the_direct_linear_solve(stepper: str, seed: int) -> None:
    network = random_network(seed)
    heat = np.random.default_rng(seed + 100).uniform(0.0, 2.0, network.node_count)
    conductance = network.conductance_matrix.toarray()
    expected = AMBIENT_C + np.linalg.solve(conductance, heat)
    slowest = 1.0 / min(np.linalg.eigvals(conductance / network.capacitance_j_per_c[:, None]).real)
    model = ThermalModel(network, stepper, dt_s=slowest / 10, ambient_c=AMBIENT_C)  # type: ignore[arg-type]
    model.set_heat({name: float(q) for name, q in zip(network.node_names, heat, strict=True)})
    model.advance_to(60 * slowest)
    np.testing.assert_allclose(model.temperatures_c, expected, rtol=1e-9)
    np.testing.assert_allclose(steady_state_c(network, heat, AMBIENT_C), expected, rtol=1e-12)


# -- the fin with an adiabatic tip, heated at its base, converges at O(dx^2) --------------------


def fin(nodes: int) -> tuple[ThermalNetwork, float, float, float]:
    """A 200 mm aluminium fin, end faces adiabatic; returns (network, k A m, m, L)."""
    aluminium = material("6061-T6")
    length_mm, width_mm, thickness_mm, h = 200.0, 20.0, 4.0, 25.0
    segment = Segment(length_mm, width_mm, thickness_mm, aluminium, length_mm / (nodes - 1), h)
    network = build_geometry_network("fin", [segment], end_faces=False)
    area = width_mm * thickness_mm * 1e-6
    perimeter = 2 * (width_mm + thickness_mm) * 1e-3
    m = math.sqrt(h * perimeter / (aluminium.conductivity_w_per_mk * area))
    return network, aluminium.conductivity_w_per_mk * area * m, m, length_mm * 1e-3


def test_fin_with_adiabatic_tip_converges_at_second_order() -> None:
    heat_w = 3.0
    errors = []
    for nodes in (11, 21, 41, 81):
        # theta(x) = Q cosh(m (L - x)) / (k A m sinh(m L)) for base flux Q (Incropera 3.6.2).
        network, kam, m, length = fin(nodes)
        x = network.positions_mm * 1e-3
        exact = heat_w * np.cosh(m * (length - x)) / (kam * math.sinh(m * length))
        heat = np.zeros(nodes)
        heat[0] = heat_w
        rise = steady_state_c(network, heat, AMBIENT_C) - AMBIENT_C
        errors.append(float(np.max(np.abs(rise - exact))))
    orders = [math.log2(coarse / fine) for coarse, fine in itertools.pairwise(errors)]
    assert all(abs(order - 2.0) < 0.1 for order in orders), (errors, orders)
    assert errors[-1] < 1e-3 * heat_w / kam


# -- the semi-infinite solid before heat reaches the far end ------------------------------------


def surface_step_bar(dx_mm: float, length_mm: float) -> ThermalNetwork:
    """An insulated aluminium bar whose node 0 is tied to ambient by a tiny resistance, so that
    raising ambient raises its surface at once: the semi-infinite solid's boundary."""
    aluminium = material("6061-T6")
    count = round(length_mm / dx_mm) + 1
    area = 1e-4
    volume = area * dx_mm * 1e-3
    capacitance = np.full(count, aluminium.volumetric_heat_capacity_j_per_m3k * volume)
    capacitance[[0, -1]] /= 2
    r = dx_mm * 1e-3 / (aluminium.conductivity_w_per_mk * area)
    r_end = np.full(count, math.inf)
    r_end[0] = 1e-9
    return ThermalNetwork(
        name="semi-infinite",
        node_names=tuple(str(i + 1) for i in range(count)),
        positions_mm=np.arange(count, dtype=np.float64) * dx_mm,
        capacitance_j_per_c=capacitance,
        alpha_per_c=np.full(count, aluminium.expansion_per_k),
        r_ambient_c_per_w=np.full(count, math.inf),
        r_end_c_per_w=r_end,
        resistances=tuple(Resistance(i, i + 1, r) for i in range(count - 1)),
        reference_nodes=("1", str(round(100 / dx_mm) + 1)),  # the first 100 mm
    )


def test_bar_follows_the_erfc_profile_and_its_integral() -> None:
    aluminium = material("6061-T6")
    network = surface_step_bar(dx_mm=2.0, length_mm=400.0)
    step_c, tau_s = 10.0, 60.0
    # 2 sqrt(a tau) = 129 mm: at 400 mm erfc is 1e-5, the far end has not been reached.
    model = ThermalModel(network, "exact", 5.0, AMBIENT_C + step_c, initial_c=AMBIENT_C)
    model.advance_to(tau_s)
    x = network.positions_mm * 1e-3
    spread = 2 * math.sqrt(aluminium.diffusivity_m2_per_s * tau_s)
    np.testing.assert_allclose(
        model.temperatures_c - AMBIENT_C, step_c * erfc(x / spread), atol=1e-4 * step_c
    )
    expected_um = 1e6 * semi_infinite_deformation_m(
        alpha_per_k=aluminium.expansion_per_k,
        length_m=0.1,
        delta_t_k=step_c,
        diffusivity_m2_per_s=aluminium.diffusivity_m2_per_s,
        tau_s=tau_s,
    )
    assert model.deformation_um_scalar() == pytest.approx(expected_um, rel=2e-4)


# -- energy balance -----------------------------------------------------------------------------


def test_explicit_step_conserves_energy_exactly() -> None:
    """Eq. 5.1 summed over nodes: internal flows cancel, so sum C dT = dt (q - losses)."""
    network = random_network(3)
    dt_s = positivity_bound_s(network)
    model = ThermalModel(network, "explicit", dt_s, AMBIENT_C)
    heat = {"n0": 1.5, "n4": 0.7}
    model.set_heat(heat)
    g_ambient = network.ambient_conductance_w_per_c
    for _ in range(200):
        before = model.temperatures_c
        model.step()
        stored = float(np.sum(network.capacitance_j_per_c * (model.temperatures_c - before)))
        lost = float(np.sum(g_ambient * (before - AMBIENT_C)))
        assert stored == pytest.approx(dt_s * (sum(heat.values()) - lost), rel=1e-10)


def test_exact_stepper_balances_heat_in_and_out() -> None:
    """sum C (T(t) - T(0)) = Q t - int losses dt; the integral by Simpson's rule on a fine
    output grid (exact output at every point, so only the quadrature errs, O(h^4))."""
    network = load_network("thesis-two-link")
    model = ThermalModel(network, "exact", 0.5, AMBIENT_C)
    heat_w = 1.0
    model.set_heat({"2": 0.5, "9": 0.5})
    g_ambient = network.ambient_conductance_w_per_c
    times = np.linspace(0.0, 1200.0, 2401)
    losses = []
    for t_s in times:
        model.advance_to(float(t_s))
        losses.append(float(np.sum(g_ambient * (model.temperatures_c - AMBIENT_C))))
    h = times[1] - times[0]
    simpson = h / 3 * (losses[0] + losses[-1] + 4 * sum(losses[1:-1:2]) + 2 * sum(losses[2:-1:2]))
    stored = float(np.sum(network.capacitance_j_per_c * (model.temperatures_c - AMBIENT_C)))
    assert stored == pytest.approx(heat_w * times[-1] - simpson, rel=1e-9)


# -- positivity under the explicit bound ----------------------------------------------------------


@pytest.mark.parametrize("seed", [4, 5, 6])
def test_explicit_at_the_bound_never_undershoots_nor_overshoots(seed: int) -> None:
    network = random_network(seed)
    rng = np.random.default_rng(seed)
    heat = rng.uniform(0.0, 1.0, network.node_count) * (rng.random(network.node_count) < 0.5)
    model = ThermalModel(network, "explicit", positivity_bound_s(network), AMBIENT_C)
    model.set_heat({name: float(q) for name, q in zip(network.node_names, heat, strict=True)})
    steady = steady_state_c(network, heat, AMBIENT_C)
    previous = model.temperatures_c
    for _ in range(3000):
        model.step()
        current = model.temperatures_c
        assert np.all(current >= previous - 1e-12)  # monotone warm-up: no undershoot
        assert np.all(current <= steady + 1e-9)  # and no overshoot of the steady state
        previous = current


def test_explicit_refuses_a_dt_above_the_bound_and_states_it() -> None:
    network = load_network("thesis-two-link")
    bound = positivity_bound_s(network)
    with pytest.raises(ModelError, match=f"{bound:.6g}"):
        ThermalModel(network, "explicit", 2.0)


def test_explicit_sub_steps_when_asked() -> None:
    network = load_network("thesis-two-link")
    bound = positivity_bound_s(network)
    coarse = ThermalModel(network, "explicit", 3 * bound, allow_substeps=True)
    fine = ThermalModel(network, "explicit", bound)
    for model in (coarse, fine):
        model.set_heat({"2": 0.5, "9": 0.5})
        model.advance_to(30 * bound)
    np.testing.assert_allclose(coarse.temperatures_c, fine.temperatures_c, rtol=1e-12)


# -- convergence of explicit and implicit to exact ----------------------------------------------


@pytest.mark.parametrize("stepper", ["explicit", "implicit"])
def test_first_order_steppers_converge_to_exact_at_first_order(stepper: str) -> None:
    network = load_network("thesis-two-link")
    heat = {"2": 0.5, "9": 0.5}
    end_s = 300.0
    reference = ThermalModel(network, "exact", 1.0)
    reference.set_heat(heat)
    reference.advance_to(end_s)
    errors = []
    for dt_s in (1.0, 0.5, 0.25, 0.125):
        model = ThermalModel(network, stepper, dt_s)  # type: ignore[arg-type]
        model.set_heat(heat)
        model.advance_to(end_s)
        errors.append(float(np.max(np.abs(model.temperatures_c - reference.temperatures_c))))
    orders = [math.log2(coarse / fine) for coarse, fine in itertools.pairwise(errors)]
    assert all(abs(order - 1.0) < 0.1 for order in orders), (errors, orders)


# -- advance_to on demand --------------------------------------------------------------------


def test_advance_to_in_pieces_equals_one_go_and_partial_steps_are_exact() -> None:
    network = load_network("thesis-two-link")
    one_go = ThermalModel(network, "exact", 1.0)
    pieces = ThermalModel(network, "exact", 1.0)
    fine = ThermalModel(network, "exact", 0.1)
    for model in (one_go, pieces, fine):
        model.set_heat({"2": 0.5, "9": 0.5})
    one_go.advance_to(100.7)
    for t_s in np.arange(0.0, 100.7, 0.35):
        pieces.advance_to(float(t_s))
    pieces.advance_to(100.7)
    fine.advance_to(100.7)
    np.testing.assert_allclose(pieces.temperatures_c, one_go.temperatures_c, rtol=1e-12)
    np.testing.assert_allclose(fine.temperatures_c, one_go.temperatures_c, rtol=1e-12)


def test_heat_changes_take_effect_from_the_current_time() -> None:
    capacitance, resistance = 10.0, 5.0
    model = ThermalModel(lumped(capacitance, resistance), "exact", 1.0, AMBIENT_C)
    model.set_heat({"only": 2.0})
    model.advance_to(30.0)
    warm = model.temperatures_c[0]
    model.set_heat({})  # heaters off: exponential decay from where it was
    model.advance_to(42.5)
    expected = AMBIENT_C + (warm - AMBIENT_C) * math.exp(-12.5 / (resistance * capacitance))
    assert model.temperatures_c[0] == pytest.approx(expected, rel=1e-12)


def test_time_cannot_go_back_and_unknown_nodes_are_named() -> None:
    model = ThermalModel(load_network("thesis-two-link"))
    model.advance_to(10.0)
    with pytest.raises(ModelError, match="back in time"):
        model.advance_to(5.0)
    with pytest.raises(ValueError, match="'shaft-42'"):
        model.set_heat({"shaft-42": 1.0})
    with pytest.raises(ValueError, match="'18'"):
        model.set_heat({"18": 1.0})


def test_heat_at_a_position_goes_to_the_nearest_nodes() -> None:
    network = load_network("thesis-two-link")
    by_node, by_position = ThermalModel(network), ThermalModel(network)
    by_node.set_heat({"2": 0.5, "9": 0.3, "3": 0.1, "4": 0.1})
    by_position.set_heat_at_position({25.4: 0.5, 330.2: 0.3, 76.2: 0.2})  # 76.2: halfway 3-4
    np.testing.assert_allclose(by_position.heat_w, by_node.heat_w, rtol=1e-12)


def test_truth_network_accepts_heat_at_the_shafts() -> None:
    from daemon.model import thesis_two_link_geometry_network

    truth = thesis_two_link_geometry_network(node_spacing_mm=5.0)
    model = ThermalModel(truth, "exact", 1.0)
    model.set_heat_at_position({25.4: 0.5, 330.2: 0.5})
    heat = model.heat_w
    assert heat[truth.node_index("left-shaft")] == 0.5
    assert heat[truth.node_index("middle-shaft")] == 0.5
    model.advance_to(600.0)
    assert model.deformation_um().shape == (3,)
    assert model.deformation_um_scalar() > 0.0


def test_holes_become_named_nodes() -> None:
    segment = Segment(100.0, 20.0, 5.0, material("6061-T6"), 10.0, 2.0)
    network = build_geometry_network(
        "bar", [segment], [Hole("a", 33.0), Hole("b", 71.0, 6.0, material("430 SS"))]
    )
    assert network.positions_mm[network.node_index("a")] == 33.0
    assert network.positions_mm[network.node_index("b")] == 71.0
    assert network.reference_nodes == ("a", "b")


def test_large_exact_steps_equal_the_augmented_matrix_exponential() -> None:
    """Above EXPM_NODE_LIMIT the exact step is built from the modes; it must be the same
    zero-order hold as expm([[A, C^-1], [0, 0]] dt), evaluated here directly."""
    from scipy.linalg import expm

    from daemon.model.model import EXPM_NODE_LIMIT

    segment = Segment(300.0, 20.0, 5.0, material("6061-T6"), 300.0 / EXPM_NODE_LIMIT, 4.0)
    network = build_geometry_network("long", [segment], [Hole("heater", 40.0)])
    count = network.node_count
    assert count > EXPM_NODE_LIMIT
    dt_s = 2.0
    inverse_c = 1.0 / network.capacitance_j_per_c
    augmented = np.zeros((2 * count, 2 * count))
    augmented[:count, :count] = -inverse_c[:, None] * network.conductance_matrix.toarray()
    augmented[:count, count:] = np.diag(inverse_c)
    exponential = expm(augmented * dt_s)
    heat = np.zeros(count)
    heat[network.node_index("heater")] = 3.0
    drive = heat + network.ambient_conductance_w_per_c * AMBIENT_C
    expected = np.full(count, AMBIENT_C)
    for _ in range(5):
        expected = exponential[:count, :count] @ expected + exponential[:count, count:] @ drive
    model = ThermalModel(network, "exact", dt_s, AMBIENT_C)
    model.set_heat({"heater": 3.0})
    model.advance_to(5 * dt_s)
    np.testing.assert_allclose(model.temperatures_c, expected, rtol=1e-12)
