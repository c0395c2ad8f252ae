"""The simulated arm bench (drivers.sim.arm_bench) and the arm's identification
(daemon.arm.identify): seeded determinism, physics where it should be, measurement within its
noise, known parameters recovered."""

from __future__ import annotations

import dataclasses
import hashlib
import math

import numpy as np
import pytest

from daemon.arm import kinematics
from daemon.arm.duty import DutyCycle, TaughtPose
from daemon.arm.identify import (
    ArmModelSpec,
    ArmRunData,
    IdentificationError,
    apply_values,
    identify_arm,
    parse_parameters,
    responses,
)
from daemon.arm.thermal import (
    ArmThermalDescription,
    ArmThermalModel,
    JointBody,
    LinkBody,
    tube_section,
)
from daemon.arm.types import JointSample
from daemon.model import material
from drivers.sim.arm_bench import ArmBench, ArmBenchConfig
from drivers.sim.arm_markers import CameraRig
from drivers.sim.arm_motion import DutyCycleMotion, MotorEnergy, StillMotion

ALUMINIUM = material("6061-T6")


# -- motor heat from motion --------------------------------------------------------------------


class Sine:
    """q = A sin(w t) on every joint: a periodic motion with a closed-form energy."""

    def __init__(self, amplitude: float, omega: float, joints: int = 2) -> None:
        self.amplitude, self.omega, self.joints = amplitude, omega, joints

    @property
    def period_s(self) -> float:
        return 2 * math.pi / self.omega

    def state(self, times: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        t = np.atleast_1d(np.asarray(times, dtype=np.float64))[:, None]
        a, w = self.amplitude, self.omega
        ones = np.ones((1, self.joints))
        return (
            a * np.sin(w * t) * ones,
            a * w * np.cos(w * t) * ones,
            -a * w * w * np.sin(w * t) * ones,
        )


def viscous_power(damping: np.ndarray) -> object:
    def power(sample: JointSample) -> np.ndarray:
        return np.asarray(damping * sample.qd_rad_s**2)

    return power


def test_motor_energy_is_the_integral_of_the_motions_power() -> None:
    """P = b qd^2 with qd = A w cos(w t): E(t) = b A^2 w^2 (t/2 + sin(2 w t) / (4 w))."""
    amplitude, omega = 0.8, 2 * math.pi / 7.5
    damping = np.array([2.0, 0.5])
    source = DutyCycleMotion(Sine(amplitude, omega))
    energy = MotorEnergy(source, viscous_power(damping), 2, motion_step_s=0.01)  # type: ignore[arg-type]
    for t in (0.0, 3.3, 7.5, 100.0, 8 * 3600.0 + 1.234):
        exact = damping * amplitude**2 * omega**2 * (t / 2 + math.sin(2 * omega * t) / (4 * omega))
        np.testing.assert_allclose(energy.energy_j(t), exact, rtol=2e-5, atol=1e-6)

    # a non-periodic source integrates forward on the same grid: the same energy
    class Forward:
        def joint_sample(self, t_s: float) -> JointSample:
            return source.joint_sample(t_s)

    forward = MotorEnergy(Forward(), viscous_power(damping), 2, motion_step_s=0.01)  # type: ignore[arg-type]
    np.testing.assert_allclose(forward.energy_j(100.0), energy.energy_j(100.0), rtol=1e-6)
    np.testing.assert_allclose(
        forward.mean_power_w(100.0, 107.5) * 7.5,
        energy.energy_j(107.5) - energy.energy_j(100.0),
        rtol=1e-6,
    )
    with pytest.raises(ValueError, match="backwards"):
        forward.energy_j(50.0)


def test_an_arm_on_its_brakes_makes_no_heat_and_a_holding_one_does() -> None:
    braked = MotorEnergy(StillMotion([0.1, 0.2], holding=False), lambda s: np.ones(2), 2, 0.1)
    np.testing.assert_array_equal(braked.energy_j(3600.0), 0.0)
    holding = MotorEnergy(StillMotion([0.1, 0.2]), lambda s: np.array([1.0, 2.0]), 2, 0.1)
    np.testing.assert_allclose(holding.energy_j(10.0), [10.0, 20.0])


# -- identification on a synthetic arm ---------------------------------------------------------


def two_link_description() -> ArmThermalDescription:
    area, perimeter = tube_section(60.0, 4.0)

    def link(
        name: str, start: tuple[float, float, float], end: tuple[float, float, float]
    ) -> LinkBody:
        return LinkBody(
            name, start, end, area, perimeter, ALUMINIUM.conductivity_w_per_mk,
            ALUMINIUM.density_kg_per_m3, ALUMINIUM.specific_heat_j_per_kgk,
            ALUMINIUM.expansion_per_k, emissivity=0.9, h_w_per_m2k=6.0,
        )  # fmt: skip

    return ArmThermalDescription(
        "two",
        (link("link1", (0, 0, 0), (0, 0, 300)), link("link2", (0, 0, 300), (350, 0, 300))),
        (JointBody("J1"), JointBody("J2")),
    )


def synthetic_run(
    truth: np.ndarray, names: list[str], noise_mm: float, noise_c: float, seed: int = 3
) -> tuple[ArmRunData, ArmModelSpec]:
    """A 4-hour cycle of the two-link arm simulated by the forward model itself at known
    parameter values, with Gaussian noise on markers and IR."""
    rng = np.random.default_rng(seed)
    step, steps = 20.0, 720
    heat = np.column_stack([8.0 + 2.0 * np.sin(np.arange(steps) / 30.0), np.full(steps, 4.0)])
    ambient = 22.0 + 0.5 * np.sin(np.arange(steps) * step / 20_000.0)
    times = np.arange(1, steps, 6, dtype=np.float64) * step
    poses = np.arange(times.size) % 2
    # two poses, 3 markers: displacement per unit strain of each link (mm), fixed numbers
    sensitivities = [
        np.array([[300.0, 0], [0, 350], [10, 20], [300, 5], [0, 300], [40, 0], [0, 0],
                  [300, 350], [5, 5]]),
        np.array([[0.0, 350], [300, 0], [0, 10], [0, 300], [300, 0], [20, 40], [300, 0],
                  [0, 0], [350, 5]]),
    ]  # fmt: skip
    description = two_link_description()
    model = ArmThermalModel(description)
    regions = {
        "r1": (int(model.link_node_indices("link1")[2]),),
        "r2": (int(model.link_node_indices("link2")[4]),),
    }
    spec = ArmModelSpec(description, 50.0, regions, sensitivities)
    blank = ArmRunData(
        step, heat, ambient, times, poses, np.zeros((times.size, 3, 3)),
        {"r1": np.zeros(times.size), "r2": np.zeros(times.size)},
    )  # fmt: skip
    specs = parse_parameters(names, 2, regions)
    values = np.array(
        [t if s.kind == "offset" else math.log(t) for s, t in zip(specs, truth, strict=True)]
    )
    scales = apply_values(specs, values, 2, list(regions))
    response = responses(description, 50.0, scales.convection, blank)
    temperatures = response.ambient + np.einsum("j,jkn->kn", scales.heat, response.per_joint)
    rises = (temperatures - response.reference_c) @ response.link_rows.T
    alphas = np.array([link.alpha_per_c for link in description.links])
    strains = scales.alpha * rises * alphas
    markers = np.einsum("kml,kl->km", np.stack([sensitivities[p] for p in poses]), strains)
    markers = markers + rng.normal(0.0, noise_mm, markers.shape)
    region_c = {
        name: temperatures[:, nodes[0]]
        + scales.offsets_c[name]
        + rng.normal(0, noise_c, times.size)
        for name, nodes in regions.items()
    }
    run = dataclasses.replace(
        blank, marker_displacement_mm=markers.reshape(times.size, 3, 3), region_c=region_c
    )
    return run, spec


def test_identification_recovers_known_parameters() -> None:
    names = ["heat:1", "heat:2", "convection", "alpha", "offset:r1", "offset:r2"]
    # scale factors as themselves (> 0), offsets in degC (the helper maps them to fit values)
    truth = np.array([1.3, 0.8, 0.75, 1.06, -0.4, 0.3])
    run, spec = synthetic_run(truth, names, noise_mm=0.002, noise_c=0.05)
    result = identify_arm(run, spec, names)
    assert result.success
    fitted = {p.name: p for p in result.parameters}
    for name, expected in zip(names, truth, strict=True):
        parameter = fitted[name]
        assert parameter.identifiable, parameter.reason
        assert abs(parameter.value - expected) < max(4 * parameter.standard_error, 1e-3), name
        assert parameter.standard_error < 0.05 * max(abs(expected), 1.0)
    assert result.fit.marker_rms_mm is not None and result.fit.marker_rms_mm < 0.003
    assert result.fit.temperature_rms_c is not None and result.fit.temperature_rms_c < 0.07


def test_a_joint_that_never_heats_is_reported_unidentifiable() -> None:
    names = ["heat:1", "heat:2", "convection", "alpha"]
    truth = np.array([1.2, 1.0, 0.9, 1.0])
    run, spec = synthetic_run(truth, names, noise_mm=0.002, noise_c=0.05)
    heat = run.joint_heat_w.copy()
    heat[:, 1] = 0.0  # joint 2 never moves
    silent = dataclasses.replace(run, joint_heat_w=heat)
    result = identify_arm(silent, spec, names)
    fitted = {p.name: p for p in result.parameters}
    assert not fitted["heat:2"].identifiable
    assert "heat:2" in " ".join(result.warnings)
    assert fitted["heat:1"].identifiable


def test_identification_refuses_bad_parameters() -> None:
    run, spec = synthetic_run(np.array([1.0, 1.0]), ["heat:1", "heat:2"], 0.002, 0.05)
    with pytest.raises(IdentificationError, match="numbered"):
        identify_arm(run, spec, ["heat:7"])
    with pytest.raises(IdentificationError, match="unknown parameter"):
        identify_arm(run, spec, ["contact:J1"])


# -- the bench ---------------------------------------------------------------------------------

QUIET_RIG = CameraRig(count=3)


def bench_config(**changes: object) -> ArmBenchConfig:
    base = ArmBenchConfig(
        seed=5,
        stations_q_rad=(STATION,),
        ir_regions=(("upper", "upper-arm", 0.5), ("fore", "forearm", 0.5)),
        truth_step_s=10.0,
    )
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


STATION = (0.0, math.radians(10.0), math.radians(80.0), 0.0, 0.0, 0.0)
SWING = DutyCycle(
    name="swing",
    poses=(
        TaughtPose("a", STATION, dwell_s=0.5, measure=True),
        TaughtPose("b", (math.radians(60), math.radians(30), math.radians(70), 0.3, 0.2, 0.5)),
    ),
    max_speed_rad_s=(3.0,) * 6,
    max_accel_rad_s2=(6.0,) * 6,
)


def observe(bench: ArmBench, t_s: float) -> list[str]:
    """Digest of what the bench shows at ``t_s``: each camera's windows, the IR reading."""
    bench.advance_to(t_s)
    seen = []
    for index in range(len(bench.cameras)):
        for window in bench.render_windows(index, STATION):
            seen.append(hashlib.sha256(window.image.tobytes()).hexdigest())
    seen.append(repr(sorted(bench.ir_read().items())))
    return seen


@pytest.mark.slow
def test_same_seed_same_run_other_seed_other_run() -> None:
    first = [observe(ArmBench(bench_config(), DutyCycleMotion(SWING)), t) for t in (0.0, 600.0)]
    again = [observe(ArmBench(bench_config(), DutyCycleMotion(SWING)), t) for t in (0.0, 600.0)]
    assert first == again
    other = ArmBench(bench_config(seed=6), DutyCycleMotion(SWING))
    assert observe(other, 0.0) != first[0]
    # the same arm measured with other noise: same truth, other frames
    noisy = ArmBench(bench_config(noise_seed=99), DutyCycleMotion(SWING))
    reference = ArmBench(bench_config(), DutyCycleMotion(SWING))
    np.testing.assert_array_equal(noisy.heat_scales, reference.heat_scales)
    np.testing.assert_array_equal(noisy.tool_pose_cold(STATION), reference.tool_pose_cold(STATION))
    assert observe(noisy, 0.0)[:-1] != first[0][:-1]


def test_the_true_arm_is_not_the_nominal_one() -> None:
    bench = ArmBench(bench_config())
    nominal = kinematics.forward(bench.nominal_arm, STATION)
    offset = np.linalg.norm(bench.tool_pose_cold(STATION)[:3, 3] - nominal[:3, 3])
    assert 0.05 < offset < 5.0  # mm: a small arm's uncalibrated geometric error
    assert not np.allclose(bench.heat_scales, 1.0)


def test_zero_motion_and_uniform_ambient_give_zero_drift() -> None:
    bench = ArmBench(bench_config())  # on its brakes at the station: no motor heat
    cold = bench.tool_pose_cold(STATION)
    bench.advance_to(4 * 3600.0)
    np.testing.assert_array_equal(bench.heat_delivered_j, 0.0)
    np.testing.assert_allclose(bench.thermal.temperatures_c, 22.0, atol=1e-9)
    np.testing.assert_allclose(bench.tool_pose_true(STATION), cold, atol=1e-9)
    # and what the cameras see has not moved either, within their noise
    measured = bench.measure_tool(0, STATION)
    error = measured.pose[:3, 3] - cold[:3, 3]
    assert float(error @ np.linalg.solve(measured.covariance[:3, :3], error)) < 25.0


def test_motor_heat_in_the_truth_is_the_integral_of_the_motions_power() -> None:
    bench = ArmBench(bench_config(), DutyCycleMotion(SWING))
    duration = 20 * SWING.period_s + 3.0
    bench.advance_to(duration)
    covered = bench.thermal.time_s

    def power(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        return np.array(
            [bench.power(JointSample(0.0, a, b, c)) for a, b, c in zip(q, qd, qdd, strict=True)]
        )

    per_cycle = SWING.cycle_energy_j(power, 0.002)  # armth's own integral, midpoint rule
    cycles = covered / SWING.period_s
    whole = math.floor(cycles)
    expected = whole * per_cycle + (
        bench.energy.energy_j(covered) - bench.energy.energy_j(whole * SWING.period_s)
    )
    np.testing.assert_allclose(bench.heat_delivered_j, expected, rtol=2e-3)
    assert np.all(per_cycle > 0)
    # and the thermal truth warmed by it
    assert float(np.max(bench.thermal.temperatures_c)) > 22.0 + 1e-3


def test_markers_rendered_and_triangulated_recover_the_true_tool_within_the_noise() -> None:
    bench = ArmBench(bench_config(), DutyCycleMotion(SWING))
    bench.advance_to(1800.0)
    truth = bench.tool_pose_true(STATION)
    chi2 = []
    for _ in range(12):
        measured = bench.measure_tool(0, STATION)
        error = measured.pose[:3, 3] - truth[:3, 3]
        chi2.append(float(error @ np.linalg.solve(measured.covariance[:3, :3], error)))
        np.testing.assert_allclose(measured.points_mm, bench.markers_world_mm(STATION), atol=0.05)
    # chi-squared with 3 degrees of freedom per frame: mean 3
    assert 0.8 < np.mean(chi2) < 8.0


def test_identifications_forward_model_is_the_arm_model() -> None:
    """responses() (all inputs at once through the modes) against ArmThermalModel stepped
    the ordinary way, across the links too: the same temperatures, link rises and gradients."""
    from daemon.arm.loading import load_arm
    from daemon.arm.thermal import describe_arm

    description = describe_arm(load_arm("crs-a465"), plus_share=0.75)
    step, steps = 20.0, 120
    rng = np.random.default_rng(0)
    heat = rng.uniform(0.0, 10.0, (steps, 6))
    ambient = 22.0 + 0.3 * np.sin(np.arange(steps) / 17.0)
    times = np.array([0.0, 200.0, 1000.0, 2400.0])
    run = ArmRunData(
        step, heat, ambient, times, np.zeros(4, dtype=np.intp), np.zeros((4, 1, 3)), {}
    )
    scales = np.array([1.2, 0.8, 1.0, 1.1, 0.9, 1.0])
    response = responses(description, 50.0, 0.7, run, across_link=True)
    assert response.gradient_rows is not None
    model = ArmThermalModel(
        description,
        node_spacing_mm=50.0,
        ambient_c=lambda t: float(ambient[min(int(t // step), steps - 1)]),
        dt_s=step,
        convection_scale=0.7,
        across_link=True,
    )
    for k, t in enumerate(times):
        while model.time_s < t - 1e-9:
            index = round(model.time_s / step)
            model.advance_to(model.time_s + step, heat[index] * scales)
        predicted = response.ambient[k] + scales @ response.per_joint[:, k]
        np.testing.assert_allclose(predicted, model.temperatures_c, atol=1e-8)
        states = model.link_states()
        rise = predicted - response.reference_c
        np.testing.assert_allclose(
            response.link_rows @ rise, [s.mean_rise_c for s in states], atol=1e-9
        )
        np.testing.assert_allclose(
            (response.gradient_rows @ rise).reshape(-1, 2),
            [s.gradient_c_per_mm for s in states],
            atol=1e-9,
        )
    assert max(abs(g) for s in model.link_states() for g in s.gradient_c_per_mm) > 1e-4


def test_an_emulator_like_source_heats_the_truth_as_the_duty_cycle_does() -> None:
    """A source that only answers joint_sample(t) (the C500C emulator in joint space) is
    integrated forward on its own grid: the same heat as the periodic duty cycle, within what
    10 ms trapezoids of a power with steps in it (the trapezoids' accelerations) can tell."""
    periodic = DutyCycleMotion(SWING)

    class Emulator:
        def joint_sample(self, t_s: float) -> JointSample:
            return periodic.joint_sample(t_s)

    duration = 5 * SWING.period_s
    reference = ArmBench(bench_config(), periodic)
    reference.advance_to(duration)
    driven = ArmBench(bench_config(), Emulator())
    for t in np.linspace(0.0, duration, 7)[1:]:
        driven.advance_to(float(t))
    np.testing.assert_allclose(driven.heat_delivered_j, reference.heat_delivered_j, rtol=3e-3)
    rise = reference.thermal.temperatures_c - 22.0
    assert float(np.max(rise)) > 1e-3
    np.testing.assert_allclose(driven.thermal.temperatures_c - 22.0, rise, rtol=3e-3, atol=1e-9)


def test_a_whole_frame_has_every_marker_where_the_camera_sees_it() -> None:
    from daemon.vision.centroid import measure_centroid
    from daemon.vision.multiview import project

    rig = CameraRig(count=2, width_px=800, height_px=600, focal_px=1500.0)
    bench = ArmBench(bench_config(rig=rig, jitter_px=0.0))
    frame = bench.render(1, STATION)
    assert frame.image.shape == (600, 800) and frame.bit_depth == rig.bit_depth
    assert (frame.sequence, bench.render(1, STATION).sequence) == (0, 1)
    pixels = project(bench.cameras[1], bench.markers_world_mm(STATION))
    for x, y in pixels:
        c0, r0 = round(x) - 10, round(y) - 10
        spot = measure_centroid(frame.image[r0 : r0 + 21, c0 : c0 + 21], bit_depth=rig.bit_depth)
        assert abs(spot.x_px + c0 - x) < 0.05 and abs(spot.y_px + r0 - y) < 0.05


def test_ambient_drift_warms_and_cools_a_still_arm() -> None:
    period = 4 * 3600.0
    bench = ArmBench(bench_config(ambient_swing_c=2.0, ambient_swing_period_s=period))
    bench.advance_to(period / 4)  # the air at its warmest
    assert bench.ambient_c(period / 4) == pytest.approx(24.0)
    warm = bench.thermal.temperatures_c.copy()
    assert 22.2 < float(np.mean(warm)) < 24.0  # following, with its lag
    bench.advance_to(3 * period / 4)  # the air at its coldest
    assert float(np.mean(bench.thermal.temperatures_c)) < 22.0 < float(np.mean(warm))
