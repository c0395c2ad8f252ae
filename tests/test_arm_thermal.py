"""The arm's thermal network (issue 20) against closed forms, the refusal of branched 1-D
network files, and the speed of an 8-hour run."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest

from daemon.arm.duty import load_duty_cycle
from daemon.arm.heat import JointHeatProfile
from daemon.arm.kinematics import link_frames, tool_error
from daemon.arm.loading import load_arm
from daemon.arm.thermal import (
    ArmThermalDescription,
    ArmThermalModel,
    JointBody,
    LinkBody,
    build_arm_network,
    describe_arm,
    radiation_h_w_per_m2k,
    steady_link_rise_c,
    tube_section,
)
from daemon.model import NetworkError, ThermalModel, load_network, material, steady_state_c

ALUMINIUM = material("6061-T6")
AREA_M2, PERIMETER_M = tube_section(60.0, 4.0)


def link(
    name: str,
    start: tuple[float, float, float],
    end: tuple[float, float, float],
    conductivity: float = ALUMINIUM.conductivity_w_per_mk,
) -> LinkBody:
    return LinkBody(
        name,
        start,
        end,
        AREA_M2,
        PERIMETER_M,
        conductivity,
        ALUMINIUM.density_kg_per_m3,
        ALUMINIUM.specific_heat_j_per_kgk,
        ALUMINIUM.expansion_per_k,
        emissivity=0.9,
        h_w_per_m2k=5.0,
    )


def six_link_arm() -> ArmThermalDescription:
    points = [
        (0, 0, 0),
        (0, 0, 330),
        (300, 0, 330),
        (600, 0, 330),
        (600, 0, 330),
        (600, 0, 330),
        (600, 0, 400),
    ]
    links = tuple(link(f"link{i + 1}", points[i], points[i + 1]) for i in range(6))
    return ArmThermalDescription("six", links, tuple(JointBody(f"J{i + 1}") for i in range(6)))


# -- closed forms -----------------------------------------------------------------------------


def test_uniform_heat_on_one_link_reaches_the_fin_steady_state() -> None:
    """A link isolated from its joint (contact resistance ~ infinite) heated uniformly
    (q' W per metre): no conduction along it, each node at T_amb + q' / (h_eff P)."""
    isolated = ArmThermalDescription(
        "one",
        (link("bar", (0, 0, 0), (500, 0, 0)),),
        (JointBody("J1", proximal_r_c_per_w=1e12, distal_r_c_per_w=1e12),),
    )
    network, layout = build_arm_network(isolated, node_spacing_mm=20.0, ambient_c=20.0)
    nodes = layout.link_nodes[0]
    assert len(nodes) == 26
    per_metre = 8.0  # W/m
    heat = np.zeros(network.node_count)
    heat[nodes] = per_metre * layout.link_lengths[0] * 1e-3
    h_eff = 5.0 + radiation_h_w_per_m2k(0.9, 20.0)
    expected = per_metre / (h_eff * PERIMETER_M)
    steady = steady_state_c(network, heat, 20.0)
    np.testing.assert_allclose(steady[nodes] - 20.0, expected, rtol=1e-6)
    # the time stepper gets there too: time constant rho c A / (h_eff P)
    tau = ALUMINIUM.volumetric_heat_capacity_j_per_m3k * AREA_M2 / (h_eff * PERIMETER_M)
    model = ThermalModel(network, "exact", 60.0, 20.0)
    model.set_heat({network.node_names[i]: float(heat[i]) for i in nodes})
    model.advance_to(tau)
    np.testing.assert_allclose(
        model.temperatures_c[nodes] - 20.0, expected * (1 - math.exp(-1.0)), rtol=1e-6
    )


def test_joint_heat_through_a_lumped_link_matches_the_circuit() -> None:
    """A very conductive link is one temperature; joint heat Q splits into the joint's own
    surface, the base path (proximal flange + base) and the link (distal flange + its
    surface)."""
    joint = JointBody(
        "J1",
        capacitance_j_per_c=400.0,
        ambient_conductance_w_per_c=0.05,
        proximal_r_c_per_w=0.9,
        distal_r_c_per_w=0.7,
    )
    description = ArmThermalDescription(
        "lumped",
        (link("bar", (0, 0, 0), (0, 0, 400), conductivity=1e9),),
        (joint,),
        base_capacitance_j_per_c=2000.0,
        base_r_ambient_c_per_w=1.5,
    )
    model = ArmThermalModel(description, node_spacing_mm=50.0, ambient_c=21.0, dt_s=10.0)
    h_eff = 5.0 + radiation_h_w_per_m2k(0.9, 21.0)
    g_link = h_eff * PERIMETER_M * 0.4
    r_p, r_d, r_b = 0.9, 0.7, 1.5
    q = 12.0
    g_total = 0.05 + 1 / (r_p + r_b) + 1 / (r_d + 1 / g_link)
    theta_joint = q / g_total
    theta_link = theta_joint * (1 / g_link) / (r_d + 1 / g_link)
    model.advance_to(400_000.0, [q])  # ~30 slowest time constants
    (state,) = model.link_states()
    assert state.link == "bar"
    assert state.mean_rise_c == pytest.approx(theta_link, rel=1e-6)
    assert state.alpha_per_c == ALUMINIUM.expansion_per_k
    assert state.gradient_c_per_mm == (0.0, 0.0)
    assert model.joint_temperatures_c()[0] - 21.0 == pytest.approx(theta_joint, rel=1e-6)


def test_ambient_is_an_input_that_may_vary() -> None:
    model = ArmThermalModel(
        six_link_arm(), ambient_c=lambda t: 20.0 if t < 100.0 else 25.0, dt_s=1000.0
    )
    model.advance_to(100.0, np.zeros(6))
    np.testing.assert_allclose(model.temperatures_c, 20.0)
    model.advance_to(1_000_000.0)  # the schedule's 25 °C, held for ~250 h
    np.testing.assert_allclose(model.temperatures_c, 25.0, atol=1e-6)
    assert all(s.mean_rise_c == pytest.approx(5.0, abs=1e-6) for s in model.link_states())
    model.set_ambient(22.0)
    assert model.ambient_c == 22.0
    model.advance_to(2_000_000.0)
    np.testing.assert_allclose(model.temperatures_c, 22.0, atol=1e-6)


def test_nodes_carry_their_link_and_position() -> None:
    description = six_link_arm()
    model = ArmThermalModel(description, node_spacing_mm=30.0)
    network = model.network
    assert network.is_spatial and network.positions_3d_mm is not None
    assert len(model.node_names) == len(model.node_links) == network.node_count
    upper_arm = model.link_node_indices("link2")
    assert {model.node_links[i] for i in upper_arm} == {"link2"}
    positions = network.positions_3d_mm[upper_arm]
    np.testing.assert_allclose(positions[0], (0, 0, 330))
    np.testing.assert_allclose(positions[-1], (300, 0, 330))
    assert np.max(np.diff(positions[:, 0])) <= 30.0 + 1e-9
    assert model.joint_node_names == ("J1", "J2", "J3", "J4", "J5", "J6")
    assert [s.link for s in model.link_states()] == [f"link{i}" for i in range(1, 7)]


# -- branched network files -------------------------------------------------------------------

T_NETWORK = """
name = "tee"
alpha_per_c = 2e-5
[[nodes]]
name = "a"
position_mm = 0
capacitance_j_per_c = 1
r_ambient_c_per_w = 10
{a}
[[nodes]]
name = "b"
position_mm = 100
capacitance_j_per_c = 1
{b}
[[nodes]]
name = "c"
position_mm = 200
capacitance_j_per_c = 1
{c}
[[nodes]]
name = "d"
position_mm = 100
capacitance_j_per_c = 1
{d}
[[resistances]]
between = ["a", "b"]
r_c_per_w = 1
[[resistances]]
between = ["b", "c"]
r_c_per_w = 1
[[resistances]]
between = ["b", "d"]
r_c_per_w = 1
"""


def test_a_branched_network_without_links_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "tee.toml"
    path.write_text(T_NETWORK.format(a="", b="", c="", d=""))
    with pytest.raises(NetworkError) as caught:
        load_network(path)
    message = str(caught.value)
    assert "\n" not in message
    assert "node 'b' joins 3 nodes (a branched network)" in message
    assert "link" in message and "position_3d_mm" in message


def test_a_branched_network_with_links_and_positions_loads(tmp_path: Path) -> None:
    spatial = {
        "a": 'link = "upper"\nposition_3d_mm = [0, 0, 0]',
        "b": 'link = "upper"\nposition_3d_mm = [100, 0, 0]',
        "c": 'link = "upper"\nposition_3d_mm = [200, 0, 0]',
        "d": 'link = "side"\nposition_3d_mm = [100, 50, 0]',
    }
    path = tmp_path / "tee.toml"
    path.write_text(T_NETWORK.format(**spatial))
    network = load_network(path)
    assert network.node_links == ("upper", "upper", "upper", "side")
    assert network.positions_3d_mm is not None
    np.testing.assert_allclose(network.positions_3d_mm[3], (100, 50, 0))
    # a node without them, when the others have them, is named
    spatial["c"] = ""
    path.write_text(T_NETWORK.format(**spatial))
    with pytest.raises(NetworkError, match="node 'c': no link"):
        load_network(path)


def test_a_chain_folding_back_is_refused(tmp_path: Path) -> None:
    """Nodes a - b - c where c sits back beside a: a bent bar read as a straight one."""
    folded = T_NETWORK.replace("position_mm = 200", "position_mm = 50")
    folded = folded.split('[[nodes]]\nname = "d"')[0] + (
        '[[resistances]]\nbetween = ["a", "b"]\nr_c_per_w = 1\n'
        '[[resistances]]\nbetween = ["b", "c"]\nr_c_per_w = 1\n'
    )
    path = tmp_path / "folded.toml"
    path.write_text(folded.format(a="", b="", c=""))
    with pytest.raises(NetworkError, match="both on the same side of it"):
        load_network(path)


def test_existing_presets_still_load_as_one_dimensional() -> None:
    for name in ("thesis-two-link", "thesis-single-link", "thesis-single-link-moving"):
        network = load_network(name)
        assert network.one_dimensional_problem() is None
        assert not network.is_spatial and network.node_links == ()


# -- speed ------------------------------------------------------------------------------------


def test_an_eight_hour_run_at_one_second_is_fast_and_reaches_the_steady_state() -> None:
    """28,800 steps of a ~120-node arm with heat that changes every step. The bound is
    generous for a loaded 2-core machine (measured ~0.4 s unloaded); the run must also land
    on the steady state of the mean heat, since every time constant is well below 8 h."""
    description = six_link_arm()
    model = ArmThermalModel(description, node_spacing_mm=10.0, ambient_c=22.0)
    assert 100 <= model.network.node_count <= 150
    mean_heat = np.array([6.0, 9.0, 5.0, 2.0, 2.0, 1.0])
    start = time.perf_counter()
    for k in range(1, 28_801):
        model.advance_to(float(k), mean_heat * (1.0 + 0.5 * math.sin(2 * math.pi * k / 7.0)))
    elapsed = time.perf_counter() - start
    assert elapsed < 20.0
    steady = steady_link_rise_c(description, mean_heat, node_spacing_mm=10.0, ambient_c=22.0)
    for state in model.link_states():
        assert state.mean_rise_c == pytest.approx(steady[state.link], rel=0.03)


# -- on the A465 preset -----------------------------------------------------------------------


def test_an_arm_file_gives_links_in_order_and_nodes_that_ride_their_links() -> None:
    arm = load_arm("crs-a465")
    model = ArmThermalModel(arm, node_spacing_mm=25.0)
    assert model.link_names == arm.link_names
    assert [s.link for s in model.link_states()] == list(arm.link_names)
    assert model.joint_node_names == arm.joint_names
    # the upper arm spans the elbow's a (304.8 mm) from the shoulder to the elbow
    upper = model.link_node_indices("upper-arm")
    assert len(upper) == math.ceil(304.8 / 25.0) + 1
    q = np.radians([30.0, 40.0, -20.0, 10.0, 35.0, 0.0])
    frames = link_frames(arm, q)
    positions = model.node_positions_mm(q)
    np.testing.assert_allclose(positions[upper[0]], frames[2][:3, 3], atol=1e-9)
    np.testing.assert_allclose(positions[upper[-1]], frames[3][:3, 3], atol=1e-9)
    zero = model.node_positions_mm(np.zeros(arm.dof))
    assert model.network.positions_3d_mm is not None
    np.testing.assert_allclose(zero, model.network.positions_3d_mm, atol=1e-9)
    # each joint's housing is on its motor's link, which its node reports
    for joint in arm.joints:
        assert joint.motor is not None
        index = model.node_names.index(joint.name)
        assert model.node_links[index] == joint.motor.heats_link


def test_the_preset_cycle_drifts_the_a465_tool_over_8_hours_in_seconds() -> None:
    """The issue's 8-hour target on the model alone: 28,800 one-second steps with each step's
    mean motor heat; the tool at the measured poses drifts >= 100 um (the bench's truth
    differs; benchmarks/bench_arm_thermal.py reports the number). The time bound is generous
    for a loaded 2-core machine (measured ~3 s there, well under 1 s idle)."""
    arm = load_arm("crs-a465")
    cycle = load_duty_cycle("a465-pick-and-place")
    profile = JointHeatProfile.from_duty(arm, cycle, resolution_s=0.02)
    model = ArmThermalModel(arm, ambient_c=22.0)
    start = time.perf_counter()
    for k in range(1, 28_801):
        model.advance_to(float(k), profile.step_power_w(k - 1.0, float(k)))
    elapsed = time.perf_counter() - start
    assert elapsed < 30.0
    states = model.link_states()
    drift_um = [
        tool_error(arm, np.array(pose.q_rad), states).translation_norm_mm * 1e3
        for pose in cycle.measured_poses()
    ]
    assert min(drift_um) >= 100.0
    # after 8 h the arm is at (within 2 % of) the steady state of the cycle's mean heat
    steady = steady_link_rise_c(model.description, profile.mean_power_w)
    for state in states:
        assert state.mean_rise_c == pytest.approx(steady[state.link], rel=0.02)


# -- across the links -------------------------------------------------------------------------


def test_two_rows_heated_alike_are_the_chain() -> None:
    """With both sides of every flange heated alike, the model resolving the temperature
    across the links gives the chain's temperatures and no gradient."""
    arm = load_arm("crs-a465")
    heat = np.array([3.0, 20.0, 4.0, 0.5, 0.4, 0.1])
    chain = ArmThermalModel(arm, node_spacing_mm=40.0, dt_s=30.0)
    rows = ArmThermalModel(arm, node_spacing_mm=40.0, dt_s=30.0, across_link=True)
    assert rows.network.node_count == 2 * chain.network.node_count - (arm.dof + 1)
    for t in (600.0, 3600.0, 20_000.0):
        chain.advance_to(t, heat)
        rows.advance_to(t, heat)
        for a, b in zip(chain.link_states(), rows.link_states(), strict=True):
            assert b.mean_rise_c == pytest.approx(a.mean_rise_c, rel=1e-9, abs=1e-12)
            assert b.gradient_c_per_mm == pytest.approx((0.0, 0.0), abs=1e-12)
        np.testing.assert_allclose(
            rows.joint_temperatures_c(), chain.joint_temperatures_c(), rtol=1e-9
        )


def test_heat_entering_one_side_bends_the_links() -> None:
    arm = load_arm("crs-a465")
    heat = np.array([3.0, 20.0, 4.0, 0.5, 0.4, 0.1])
    states = {}
    for share in (0.9, 0.1):
        model = ArmThermalModel(
            describe_arm(arm, plus_share=share),
            node_spacing_mm=40.0,
            dt_s=60.0,
            across_link=True,
        )
        model.advance_to(8 * 3600.0, heat)
        states[share] = model.link_states()
        upper = model.link_node_indices("upper-arm")
        plus = [i for i in upper if model.node_names[i].endswith("+")]
        minus = [i for i in upper if model.node_names[i].endswith("-")]
        hotter = np.mean(model.temperatures_c[plus]) - np.mean(model.temperatures_c[minus])
        assert hotter * (share - 0.5) > 0.0  # the housing's side is the warmer one
    for hot, cold in zip(states[0.9], states[0.1], strict=True):
        # mirror images: the same growth, opposite gradients
        assert hot.mean_rise_c == pytest.approx(cold.mean_rise_c, rel=1e-9)
        np.testing.assert_allclose(
            hot.gradient_c_per_mm, -np.array(cold.gradient_c_per_mm), rtol=1e-9, atol=1e-15
        )
    upper_state = states[0.9][arm.link_index("upper-arm")]
    assert np.hypot(*upper_state.gradient_c_per_mm) > 1e-4
    q = np.radians([0.0, 35.0, 55.0, 0.0, 0.0, 0.0])
    straight = tool_error(arm, q, states[0.9])
    bent = tool_error(arm, q, states[0.9], bending=True)
    assert straight.rotation_angle_rad == pytest.approx(0.0, abs=1e-12)
    assert bent.rotation_angle_rad > 1e-6
