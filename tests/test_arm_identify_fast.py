"""Issue 29's identification pieces against oracles: the projected responses against the arm's
own thermal model stepped the ordinary way (capacity and bending shares changed), the analytic
Jacobian against central differences, capacity and share recovered from data the model of
known factors made, flags from the final fit, the physical ranges, the calibration program
and the online adaptation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from daemon.arm.adaptation import ArmAdaptation
from daemon.arm.arm_network import describe_arm
from daemon.arm.calibration_program import (
    BLOCK_S,
    HOLD_MIN_SHARE,
    calibration_program,
    duty_cycle_toml,
    hold_pose,
    hold_poses,
)
from daemon.arm.duty import duty_cycle_from_mapping, load_duty_cycle
from daemon.arm.heat import JointHeatProfile
from daemon.arm.identify import _ArmProblem, identify_arm
from daemon.arm.identify_final import identify_arm_final
from daemon.arm.identify_parameters import outside_physical_range, parse_parameters
from daemon.arm.identify_response import NetworkFactors, factored_description, output_responses
from daemon.arm.loading import load_arm
from daemon.arm.motors import joint_heat_batch_w
from daemon.arm.response import ArmModelSpec, ArmRunData
from daemon.arm.thermal import ArmThermalModel
from daemon.model.identify_uncertainty import central_jacobian

STEP_S = 20.0


def a465_description(share: float = 0.75) -> object:
    return describe_arm(load_arm("crs-a465"), plus_share=share)


def a465_spec(regions: dict[str, tuple[int, ...]]) -> ArmModelSpec:
    """The A465's model across its links, two poses of fixed sensitivities (one marker: the
    tool point), numbers of the size kinematics gives (mm per unit strain or alpha*gradient)."""
    rng = np.random.default_rng(7)
    sensitivities = [rng.normal(0.0, 300.0, (3, 18)) for _ in range(2)]
    description = a465_description()
    return ArmModelSpec(description, 50.0, regions, sensitivities, across_link=True)  # type: ignore[arg-type]


def phased_heat(steps: int) -> np.ndarray:
    """Each joint's heat switched on and off on a schedule of its own (a designed program)."""
    k = np.arange(steps)[:, None]
    periods = np.array([90, 70, 110, 50, 130, 60])
    watts = np.array([8.0, 25.0, 8.0, 2.0, 2.0, 1.5])
    return np.where((k // periods) % 2 == 0, watts, 0.2 * watts)


def regions_of(spec_model: ArmThermalModel) -> dict[str, tuple[int, ...]]:
    return {
        "upper": tuple(int(i) for i in spec_model.link_node_indices("upper-arm")[4:6]),
        "fore": tuple(int(i) for i in spec_model.link_node_indices("forearm")[2:4]),
    }


def synthetic(truth: dict[str, float], steps: int = 1080, noise: float = 0.001, seed: int = 1):
    """An 6-hour cycle measured every 3 steps, made by the forward model at ``truth``."""
    model = ArmThermalModel(a465_description(), across_link=True)  # type: ignore[arg-type]
    spec = a465_spec(regions_of(model))
    times = np.arange(3, steps, 3, dtype=np.float64) * STEP_S
    blank = ArmRunData(
        STEP_S, phased_heat(steps), np.full(steps, 22.0), times,
        np.arange(times.size) % 2, np.zeros((times.size, 1, 3)),
        {"upper": np.zeros(times.size), "fore": np.zeros(times.size)},
    )  # fmt: skip
    names = list(truth)
    specs = parse_parameters(names, 6, spec.regions)
    problem = _ArmProblem(blank, spec, specs)
    values = np.array(
        [np.log(v) if s.is_log else v for s, v in zip(specs, truth.values(), strict=True)]
    )
    markers, regions = problem.predictions(values)
    rng = np.random.default_rng(seed)
    run = dataclasses.replace(
        blank,
        marker_displacement_mm=(markers + rng.normal(0, noise, markers.shape)).reshape(-1, 1, 3),
        region_c={
            name: regions[:, k] + rng.normal(0, 0.03, times.size)
            for k, name in enumerate(("upper", "fore"))
        },
    )
    return run, spec


def test_projected_responses_are_the_arm_model_stepped() -> None:
    """output_responses with capacity x1.3, other shares and convection x0.7 against
    ArmThermalModel of that description stepped with the same heat: link rises, gradients
    and region means alike."""
    shares = (0.6, 0.8, 0.7, 0.55, 0.9, 0.65)
    description = a465_description()
    truth = factored_description(description, 1.3, shares)  # type: ignore[arg-type]
    steps, heat = 150, phased_heat(150)
    times = np.array([0.0, 400.0, 1400.0, 2980.0])
    model = ArmThermalModel(truth, dt_s=STEP_S, convection_scale=0.7, across_link=True)
    regions = regions_of(model)
    run = ArmRunData(STEP_S, heat, np.full(steps, 22.0), times, np.zeros(4, np.intp),
                     np.zeros((4, 1, 3)), {})  # fmt: skip
    outputs = output_responses(
        description,
        50.0,
        NetworkFactors(0.7, 1.3, shares),
        run,
        regions,
        across_link=True,  # type: ignore[arg-type]
    )
    scales = np.array([1.2, 0.8, 1.0, 1.1, 0.9, 1.0])
    for k, t in enumerate(times):
        while model.time_s < t - 1e-9:
            model.advance_to(model.time_s + STEP_S, heat[round(model.time_s / STEP_S)] * scales)
        predicted = scales @ outputs.per_input[:6, k] + outputs.per_input[6, k]
        states = model.link_states()
        np.testing.assert_allclose(predicted[:6], [s.mean_rise_c for s in states], atol=1e-8)
        np.testing.assert_allclose(
            predicted[6:18].reshape(-1, 2), [s.gradient_c_per_mm for s in states], atol=1e-10
        )
        temperatures = model.temperatures_c
        expected = [temperatures[list(nodes)].mean() for nodes in regions.values()]
        np.testing.assert_allclose(predicted[18:], expected, atol=1e-8)


def test_the_analytic_jacobian_is_the_central_difference() -> None:
    names = ["heat:1", "heat:2", "alpha", "convection", "capacity", "share", "offset:upper"]
    run, spec = synthetic(dict.fromkeys(names[:6], 1.0) | {"offset:upper": 0.0}, steps=300)
    problem = _ArmProblem(run, spec, parse_parameters(names, 6, spec.regions))
    values = np.array([0.1, -0.2, 0.03, 0.2, -0.1, 0.7, 0.4])
    numeric = central_jacobian(problem.weighted, values, 1e-5, relative=False)
    np.testing.assert_allclose(problem.jacobian(values), numeric, rtol=2e-4, atol=1e-6)
    # the fit's iterations take forward differences of the network factors (one pass each
    # instead of two): first order in the step, still the derivative to ~1e-4 of its scale
    forward = problem.jacobian(values, central=False)
    scale = np.abs(numeric).max(axis=0)
    assert np.all(np.abs(forward - numeric) <= 2e-3 * scale + 1e-6)
    passes = problem.passes
    problem.jacobian(values * 1.01, central=False)
    assert problem.passes - passes == 1 + 3  # the point, then convection, capacity, share


@pytest.mark.slow
def test_capacity_and_share_are_recovered_from_a_designed_cycle() -> None:
    truth = {
        "heat:1": 1.4, "heat:2": 0.7, "heat:3": 1.6, "alpha": 1.06, "convection": 0.8,
        "capacity": 1.25, "share": 0.82, "offset:upper": 0.4, "offset:fore": -0.3,
    }  # fmt: skip
    run, spec = synthetic(truth)
    calibration = identify_arm_final(run, spec, list(truth))
    assert calibration.not_identified == ()
    for p in calibration.parameters():
        assert p.identifiable, p.reason
        assert abs(p.value - truth[p.name]) < max(4 * p.standard_error, 2e-3), p


def test_flags_come_from_the_final_fit_and_a_silent_joint_is_left_out() -> None:
    truth = {"heat:1": 1.2, "heat:2": 0.9, "alpha": 1.0, "convection": 1.0}
    run, spec = synthetic(truth, steps=600)
    heat = run.joint_heat_w.copy()
    heat[:, 3] = 0.0
    silent = dataclasses.replace(run, joint_heat_w=heat)
    calibration = identify_arm_final(silent, spec, [*truth, "heat:4"])
    flags = {p.name: p for p in calibration.parameters()}
    assert not flags["heat:4"].identifiable and "no heat in joint 4" in flags["heat:4"].reason
    assert calibration.final is not None
    assert all(p.identifiable for p in calibration.final.parameters)
    assert "heat:4" in calibration.not_identified


def test_a_value_at_its_bound_is_not_identified() -> None:
    run, spec = synthetic({"heat:1": 1.0, "alpha": 1.0}, steps=300)
    shrunk = dataclasses.replace(run, marker_displacement_mm=run.marker_displacement_mm * 30)
    result = identify_arm(shrunk, spec, ["alpha"])  # 30x the strain: alpha pinned at 10
    assert not result.parameter("alpha").identifiable
    assert "at its bound" in result.parameter("alpha").reason


def test_physical_ranges() -> None:
    assert outside_physical_range("alpha", 1.05) is None
    assert "alpha = 1.85" in (outside_physical_range("alpha", 1.85) or "")
    assert outside_physical_range("convection", 0.1) is not None  # issue 29's pinned 0.10
    assert outside_physical_range("offset:turret", 5.0) is not None
    assert outside_physical_range("share", 0.7) is None
    assert outside_physical_range("share:2", 0.3) is not None


def test_the_calibration_program_works_each_joint_in_turn_and_plays_as_a_duty_cycle() -> None:
    arm = load_arm("crs-a465")
    task = load_duty_cycle("a465-pick-and-place")
    program = calibration_program(
        arm, task.measured_poses(), task.max_speed_rad_s, task.max_accel_rad_s2, payload_kg=1.0
    )
    assert [p.name for p in program.measured_poses()] == [p.name for p in task.measured_poses()]
    q = np.array([p.q_rad for p in program.poses])
    assert np.all(q > arm.lower_rad) and np.all(q < arm.upper_rad)
    # each joint's swing block heats that joint most of all (its own time course)
    for j, joint in enumerate(arm.joints):
        swing = [p for p in program.poses if p.name.startswith(f"{joint.name}-swing")][:2]
        cycle = dataclasses.replace(program, poses=tuple(swing))
        power = JointHeatProfile.from_duty(arm, cycle, resolution_s=0.01).cycle_energy_j
        assert int(np.argmax(power)) == j or j == 1, (joint.name, power)  # shoulder: gravity
    assert hold_pose(arm, 1.0)[1] != 0.0  # the shoulder holds the arm out
    # a hold of its own for each joint that can hold the weight alone: shoulder and elbow,
    # each releasing most of the holding heat in its pose, for a block of minutes
    holds = hold_poses(arm, 1.0)
    assert [j for j, _ in holds][:2] == [1, 2]
    for j, q in holds:
        still = np.zeros((1, arm.dof))
        heat = np.asarray(joint_heat_batch_w(arm, q[None, :], still, still, payload_kg=1.0))[0]
        assert heat[j] > HOLD_MIN_SHARE * heat.sum(), (j, heat)
        block = [p for p in program.poses if p.name == f"{arm.joints[j].name}-hold"]
        assert sum(p.dwell_s for p in block) >= 0.8 * BLOCK_S
    text = duty_cycle_toml(program, "crs-a465")
    import tomllib

    again = duty_cycle_from_mapping(tomllib.loads(text))
    assert len(again.poses) == len(program.poses)
    np.testing.assert_allclose(again.period_s, program.period_s, rtol=1e-9)
    for read, written in zip(again.poses, program.poses, strict=True):
        assert (read.name, read.speed, read.accel, read.dwell_s, read.measure) == (
            written.name, written.speed, written.accel, written.dwell_s, written.measure,
        )  # fmt: skip
        np.testing.assert_allclose(read.q_rad, written.q_rad, atol=1e-7)
    # one line per visit (the format has no repeat; a program visits thousands of poses)
    assert len(text.splitlines()) <= len(program.poses) + 20


@pytest.mark.slow
def test_adaptation_converges_from_the_preset_to_the_truth() -> None:
    """Fed the synthetic run measurement by measurement, the adapted factors reach the truth
    within their own uncertainty, which shrinks from the prior's; the adapted links are the
    truth's thermal model (ArmThermalModel at the true factors)."""
    truth = {"heat:1": 1.3, "heat:2": 0.75, "heat:3": 1.4, "alpha": 1.05, "convection": 0.85,
             "share": 0.8}  # fmt: skip
    run, spec = synthetic(truth, steps=720, seed=4)
    adaptation = ArmAdaptation(
        spec, STEP_S, 22.0, list(truth), marker_sigma_mm=0.001, temperature_sigma_c=0.03,
        update_every_s=2400.0,
    )  # fmt: skip
    grid = run.grid_index
    for k in range(run.joint_heat_w.shape[0]):
        adaptation.add_heat(run.joint_heat_w[k])
        for m in np.flatnonzero(grid == k + 1):
            regions = {name: float(values[m]) for name, values in run.region_c.items()}
            adaptation.observe(int(run.pose_index[m]), run.marker_displacement_mm[m], regions)
    for estimate in adaptation.estimates():
        prior_sigma = 0.5 * estimate.prior if estimate.name != "share" else 0.15
        assert estimate.sigma < 0.2 * prior_sigma, estimate
        assert abs(estimate.value - truth[estimate.name]) < max(4 * estimate.sigma, 5e-3), estimate
    description = factored_description(spec.description, 1.0, (0.8,) * 6)  # type: ignore[arg-type]
    model = ArmThermalModel(description, dt_s=STEP_S, convection_scale=0.85, across_link=True)
    scales = np.array([1.3, 0.75, 1.4, 1.0, 1.0, 1.0])
    for k in range(run.joint_heat_w.shape[0]):
        model.advance_to((k + 1) * STEP_S, run.joint_heat_w[k] * scales)
    for adapted, true in zip(adaptation.link_states(), model.link_states(), strict=True):
        assert abs(adapted.mean_rise_c - true.mean_rise_c) < 0.02 * abs(true.mean_rise_c) + 1e-3
        assert abs(adapted.alpha_per_c / true.alpha_per_c - 1.05) < 0.01


@pytest.mark.slow
def test_a_controller_with_adaptation_approaches_an_arm_it_was_not_told() -> None:
    """arm.adapt on the controller (what an arm run's step feeds it): the truth is the same
    controller given other factors (an arm model); fed the truth's tool displacement and IR
    every 10 minutes, the adapted controller's prediction over the last third is much closer
    to the truth's than the preset's is."""
    from daemon.arm.arm_model import ArmModel
    from daemon.arm.controller import ArmModelOptions
    from daemon.arm.controller_loading import load_controller

    options = ArmModelOptions(bending=True, motor_side_share=0.75, model_dt_s=60.0)
    truth_model = ArmModel(
        "truth", "CRS A465", (1.6, 0.7, 1.5, 1.0, 1.0, 1.0), convection_scale=1.3,
        alpha_scale=0.94, bending_shares=(0.6,) * 6,
    )  # fmt: skip
    arm, task = "config/arms/crs-a465.toml", "a465-pick-and-place"
    truth = load_controller(arm, task, options, truth_model)
    preset = load_controller(arm, task, options)
    adapted = load_controller(arm, task, options)
    poses = adapted.measured_poses()
    adapted.enable_adaptation(poses, 0.002, 0.05)
    from daemon.arm.ir_regions import region_nodes

    regions = region_nodes(truth.thermal, ["upper-arm-mid", "forearm-mid", "turret-mid"])
    assert len(regions) == 3
    errors: dict[str, list[float]] = {"preset": [], "adapted": []}
    hours = 6
    for k in range(1, hours * 6 + 1):
        t = k * 600.0
        for controller in (truth, preset, adapted):
            controller.advance_to(t)
        pose = poses[k % len(poses)]
        true_error = truth.tool_error(pose).translation_mm
        temperatures = truth.thermal.temperatures_c
        reading = {name: float(temperatures[list(n)].mean()) for name, n in regions.items()}
        if k > hours * 4:
            for name, controller in (("preset", preset), ("adapted", adapted)):
                miss = controller.tool_error(pose).translation_mm - true_error
                errors[name].append(float(np.linalg.norm(miss)))
        adapted.adapt(pose, true_error, reading)
    preset_rms = float(np.sqrt(np.mean(np.square(errors["preset"]))))
    adapted_rms = float(np.sqrt(np.mean(np.square(errors["adapted"]))))
    assert adapted_rms < 0.2 * preset_rms, (adapted_rms, preset_rms)
    estimates = adapted.adaptation_estimates()
    assert abs(estimates["heat:2"][0] - 0.7) < 0.1 and abs(estimates["alpha"][0] - 0.94) < 0.03


@pytest.mark.slow
def test_adaptation_follows_the_room_the_controller_follows() -> None:
    """A room warming 0.5 degC an hour: the truth (the controller given other factors) and the
    adapted controller follow the same thermometer. The adaptation's record of the air is the
    room's, so the room is not soaked into the factors: alpha and convection come back, and the
    adapted prediction over the last third is far closer to the truth's than the preset's."""
    from daemon.arm.arm_model import ArmModel
    from daemon.arm.controller import ArmModelOptions
    from daemon.arm.controller_loading import load_controller
    from daemon.arm.ir_regions import region_nodes

    options = ArmModelOptions(bending=True, motor_side_share=0.75, model_dt_s=60.0)
    truth_model = ArmModel(
        "truth", "CRS A465", (1.6, 0.7, 1.5, 1.0, 1.0, 1.0), convection_scale=1.3,
        alpha_scale=0.94, bending_shares=(0.6,) * 6,
    )  # fmt: skip
    arm, task = "config/arms/crs-a465.toml", "a465-pick-and-place"
    truth = load_controller(arm, task, options, truth_model)
    preset = load_controller(arm, task, options)
    adapted = load_controller(arm, task, options)
    poses = adapted.measured_poses()
    adapted.enable_adaptation(poses, 0.002, 0.05)
    regions = region_nodes(truth.thermal, ["upper-arm-mid", "forearm-mid", "turret-mid"])
    errors: dict[str, list[float]] = {"preset": [], "adapted": []}
    hours = 6
    for k in range(0, hours * 6 + 1):
        t = k * 600.0
        room = 21.0 + 0.5 * t / 3600.0
        for controller in (truth, preset, adapted):
            controller.follow_room(room)
            controller.advance_to(t)
        if k == 0:
            continue
        pose = poses[k % len(poses)]
        true_error = truth.tool_error(pose).translation_mm
        temperatures = truth.thermal.temperatures_c
        reading = {name: float(temperatures[list(n)].mean()) for name, n in regions.items()}
        if k > hours * 4:
            for name, controller in (("preset", preset), ("adapted", adapted)):
                miss = controller.tool_error(pose).translation_mm - true_error
                errors[name].append(float(np.linalg.norm(miss)))
        adapted.adapt(pose, true_error, reading)
    preset_rms = float(np.sqrt(np.mean(np.square(errors["preset"]))))
    adapted_rms = float(np.sqrt(np.mean(np.square(errors["adapted"]))))
    assert adapted_rms < 0.1 * preset_rms, (adapted_rms, preset_rms)
    estimates = adapted.adaptation_estimates()
    assert abs(estimates["alpha"][0] - 0.94) < 0.02, estimates
    assert abs(estimates["convection"][0] - 1.3) < 0.15, estimates
