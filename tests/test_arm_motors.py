"""Motor heat from motion, joint torques and duty-cycle profiles (issue 20), against closed
forms: constant-speed losses, trapezoid integrals, a point mass on a lever."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from daemon.arm.description import ArmError
from daemon.arm.duty import (
    DutyCycle,
    DutyCycleError,
    TaughtPose,
    arm_inverse,
    available_duty_cycles,
    duty_cycle_from_mapping,
    load_duty_cycle,
    trapezoid_timing,
)
from daemon.arm.heat import HeatMeter, JointHeatProfile
from daemon.arm.kinematics import forward, link_frames
from daemon.arm.loading import load_arm
from daemon.arm.motors import (
    GRAVITY_M_S2,
    MotorParameters,
    arm_motors,
    friction_torque_nm,
    gravity_torques_nm,
    heat_from_current_w,
    heat_from_power_w,
    inertia_diagonal_kg_m2,
    joint_heat_batch_w,
    joint_heat_w,
    joint_torques_nm,
    motor_heat_w,
    motor_parameters,
    torques_batch_nm,
    torques_nm,
)
from daemon.arm.types import JointSample

MOTOR = MotorParameters(
    gear_ratio=50.0,
    torque_constant_nm_per_a=0.05,
    resistance_ohm=2.0,
    viscous_nm_s_per_rad=2e-5,
    coulomb_nm=0.01,
    rotor_inertia_kg_m2=3e-6,
)


# -- motor heat -------------------------------------------------------------------------------


def test_constant_speed_heat_is_copper_plus_friction() -> None:
    omega, tau = 1.5, 4.0  # rad/s at the joint, N·m at the joint
    current = tau / (MOTOR.torque_constant_nm_per_a * MOTOR.gear_ratio)
    omega_m = MOTOR.gear_ratio * omega
    expected = (
        MOTOR.resistance_ohm * current**2
        + MOTOR.viscous_nm_s_per_rad * omega_m**2
        + MOTOR.coulomb_nm * omega_m
    )
    assert motor_heat_w(MOTOR, omega, tau) == pytest.approx(expected, rel=1e-12)
    # the sign of the speed or torque does not change the loss of a lossless gearbox
    assert motor_heat_w(MOTOR, -omega, -tau) == pytest.approx(expected, rel=1e-12)
    # at rest, holding a torque costs only the copper loss
    assert motor_heat_w(MOTOR, 0.0, tau) == pytest.approx(MOTOR.resistance_ohm * current**2)


def test_gearbox_efficiency_loses_the_power_it_does_not_pass() -> None:
    lossy = MotorParameters(
        gear_ratio=10.0, torque_constant_nm_per_a=1.0, resistance_ohm=0.0, gear_efficiency=0.8
    )
    # driving 10 N·m at 1 rad/s: the motor supplies 10/0.8 = 12.5 W, 2.5 W stay in the gears
    assert motor_heat_w(lossy, 1.0, 10.0) == pytest.approx(2.5)
    # braking (the load drives the motor): only 80 % of the 10 W reach the motor
    assert motor_heat_w(lossy, 1.0, -10.0) == pytest.approx(2.0)


def test_motor_heat_integrates_to_the_energy_of_a_known_motion() -> None:
    """One joint moves 90° and back on trapezoids under a constant torque: over one cycle
    the Coulomb loss is tau_c N x distance, the viscous loss b N^2 int w^2, the copper loss
    R I^2 x period, whatever the profile's shape."""
    cycle = DutyCycle(
        name="swing",
        poses=(
            TaughtPose("a", (0.0,), speed=0.5, dwell_s=0.5),
            TaughtPose("b", (math.pi / 2,), speed=0.5, dwell_s=0.25),
        ),
        max_speed_rad_s=(2.0,),
        max_accel_rad_s2=(4.0,),
    )
    tau = 3.0
    energy = cycle.cycle_energy_j(
        lambda q, qd, qdd: motor_heat_w(MOTOR, qd, np.full_like(qd, tau)), dt_s=1e-4
    )
    distance = math.pi  # there and back
    duration, blend, peak = trapezoid_timing(math.pi / 2, 1.0, 4.0)  # speed fraction 0.5
    speed_squared_integral = 2 * (peak**2 * (duration - 2 * blend) + 2 * peak**2 * blend / 3)
    current = tau / (MOTOR.torque_constant_nm_per_a * MOTOR.gear_ratio)
    n = MOTOR.gear_ratio
    expected = (
        MOTOR.resistance_ohm * current**2 * cycle.period_s
        + MOTOR.coulomb_nm * n * distance
        + MOTOR.viscous_nm_s_per_rad * n**2 * speed_squared_integral
    )
    assert cycle.period_s == pytest.approx(0.75 + 2 * duration)
    assert energy[0] == pytest.approx(expected, rel=1e-5)


def test_measured_current_and_power_feeds() -> None:
    omega = np.array([0.0, 2.0])
    current = np.array([1.0, -3.0])
    omega_m = MOTOR.gear_ratio * omega
    expected = (
        MOTOR.resistance_ohm * current**2
        + MOTOR.viscous_nm_s_per_rad * omega_m**2
        + MOTOR.coulomb_nm * np.abs(omega_m)
    )
    np.testing.assert_allclose(heat_from_current_w([MOTOR, MOTOR], omega, current), expected)
    # 50 W in, 20 N·m at 2 rad/s out: 10 W of heat; regenerating does not cool
    np.testing.assert_allclose(
        heat_from_power_w([50.0, -5.0], [2.0, 1.0], [20.0, 10.0]), [10.0, 0.0]
    )


def test_motor_parameters_are_validated() -> None:
    with pytest.raises(ValueError, match="gear_ratio"):
        MotorParameters(gear_ratio=0.0, torque_constant_nm_per_a=1.0, resistance_ohm=1.0)
    with pytest.raises(ValueError, match="efficiency"):
        MotorParameters(
            gear_ratio=1.0, torque_constant_nm_per_a=1.0, resistance_ohm=1.0, gear_efficiency=1.5
        )


# -- torques ----------------------------------------------------------------------------------


def test_gravity_on_a_horizontal_two_link_arm() -> None:
    """Two joints about y at x = 0 and x = 300 mm; masses 2 kg at 150 mm and 1 kg at 450 mm:
    the shoulder holds (2 x 0.15 + 1 x 0.45) g, the elbow 1 x 0.15 g (sign: the torque that
    lifts the masses, about +y, is negative for masses at +x under -z gravity)."""
    origins = np.array([[0.0, 0.0, 0.0], [300.0, 0.0, 0.0]])
    axes = np.array([[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    masses = np.array([2.0, 1.0])
    centres = np.array([[150.0, 0.0, 0.0], [450.0, 0.0, 0.0]])
    torques = gravity_torques_nm(origins, axes, masses, centres)
    g = GRAVITY_M_S2
    np.testing.assert_allclose(torques, [-(2 * 0.15 + 0.45) * g, -0.15 * g], rtol=1e-12)
    # a vertical axis carries no gravity torque
    vertical = gravity_torques_nm(origins, np.array([[0, 0, 1.0], [0, 0, 1.0]]), masses, centres)
    np.testing.assert_allclose(vertical, 0.0, atol=1e-12)
    inertia = inertia_diagonal_kg_m2(origins, axes, masses, centres)
    np.testing.assert_allclose(inertia, [2 * 0.15**2 + 0.45**2, 0.15**2], rtol=1e-12)


def test_joint_torque_adds_inertia_rotor_and_friction() -> None:
    torque = joint_torques_nm([MOTOR], [0.5], [2.0], [1.0], [0.3])
    n = MOTOR.gear_ratio
    expected = (
        1.0
        + (0.3 + n**2 * MOTOR.rotor_inertia_kg_m2) * 2.0
        + n * (MOTOR.viscous_nm_s_per_rad * n * 0.5 + MOTOR.coulomb_nm)
    )
    assert torque[0] == pytest.approx(expected)
    assert friction_torque_nm(MOTOR, 0.0)[()] == 0.0  # static friction does no work


# -- duty cycles ------------------------------------------------------------------------------


def test_trapezoids_reach_each_pose_within_the_limits_synchronised() -> None:
    speed = (1.0, 2.0, 0.5)
    accel = (2.0, 8.0, 1.0)
    poses = (
        TaughtPose("a", (0.0, 0.0, 0.0), dwell_s=0.3),
        TaughtPose("b", (1.2, -0.4, 0.05), speed=0.8, accel=0.5, dwell_s=0.2),
        TaughtPose("c", (0.2, 0.1, 0.05), dwell_s=0.1),
    )
    cycle = DutyCycle("test", poses, speed, accel)
    dt = 1e-3
    q, qd, qdd = cycle.state(np.arange(0.0, cycle.period_s, dt))
    # limits, scaled by each move's fractions (0.8 / 0.5 for the move into b, 1 otherwise)
    assert np.all(np.abs(qd) <= np.array(speed) * (1 + 1e-9))
    assert np.all(np.abs(qdd) <= np.array(accel) * (1 + 1e-9))
    # speed is the derivative of position (the profile is consistent)
    np.testing.assert_allclose(np.gradient(q, dt, axis=0)[1:-1], qd[1:-1], atol=3e-3)
    # the arm is at rest at each pose when it arrives, and stays for the dwell
    for pose, arrival in zip(poses, cycle.arrival_times_s(), strict=True):
        at, speed_at, _ = cycle.state([arrival, arrival + pose.dwell_s * 0.99])
        np.testing.assert_allclose(at, [pose.q_rad, pose.q_rad], atol=1e-12)
        np.testing.assert_allclose(speed_at, 0.0, atol=1e-12)
    # synchronised: the move a -> b is led by joint 0 (1.2 rad at 0.8 rad/s): every joint's
    # normalised progress is the same at every instant
    move = cycle.moves[0]
    local = move.t0 + np.linspace(0.0, move.duration, 50)
    q_move, _, _ = cycle.state(local)
    progress = (q_move - move.start) / move.delta
    np.testing.assert_allclose(progress, progress[:, :1].repeat(3, axis=1), atol=1e-12)
    lead_duration, _, _ = trapezoid_timing(1.2, 0.8 * 1.0, 0.5 * 2.0)
    assert move.duration == pytest.approx(lead_duration)
    # periodic
    later, _, _ = cycle.state(np.array([0.77, 0.77 + 5 * cycle.period_s]))
    np.testing.assert_allclose(later[0], later[1], atol=1e-9)


def test_short_move_is_triangular() -> None:
    duration, blend, peak = trapezoid_timing(0.1, 1.0, 1.0)  # v^2 / a = 1 > 0.1
    assert duration == pytest.approx(2 * math.sqrt(0.1))
    assert peak == pytest.approx(math.sqrt(0.1)) and peak < 1.0
    assert blend == pytest.approx(duration / 2)


def test_samples_on_a_fixed_step() -> None:
    cycle = load_duty_cycle("a465-pick-and-place")
    samples = list(cycle.samples(0.5, 10.0))
    assert [s.time_s for s in samples] == pytest.approx(np.arange(21) * 0.5)
    assert all(s.q_rad.shape == (6,) for s in samples)
    q, _, _ = cycle.state([s.time_s for s in samples])
    np.testing.assert_array_equal(q, np.array([s.q_rad for s in samples]))
    assert [p.name for p in cycle.measured_poses()] == ["camera", "place"]
    assert "a465-pick-and-place" in available_duty_cycles()


def test_duty_file_errors_name_the_pose() -> None:
    base = {"max_speed_deg_s": 90.0, "max_accel_deg_s2": 180.0}
    with pytest.raises(DutyCycleError, match="'b': give joints_deg or tool_mm"):
        duty_cycle_from_mapping(
            {**base, "poses": [{"name": "a", "joints_deg": [0, 0]}, {"name": "b"}]}
        )
    with pytest.raises(DutyCycleError, match="'b': a tool pose needs the arm's kinematics"):
        duty_cycle_from_mapping(
            {
                **base,
                "poses": [{"name": "a", "joints_deg": [0, 0]}, {"name": "b", "tool_mm": [1, 2, 3]}],
            }
        )
    with pytest.raises(DutyCycleError, match="'b': 3 joint angles for 2 joints"):
        duty_cycle_from_mapping(
            {
                **base,
                "poses": [
                    {"name": "a", "joints_deg": [0, 0]},
                    {"name": "b", "joints_deg": [0, 0, 1]},
                ],
            }
        )
    # tool poses go through the arm's inverse kinematics, seeded with the previous pose
    seeds = []

    def inverse(pose: np.ndarray, seed: np.ndarray) -> np.ndarray:
        seeds.append(seed.copy())
        return np.array([pose[0, 3], pose[1, 3]]) / 100.0

    cycle = duty_cycle_from_mapping(
        {
            **base,
            "poses": [{"name": "a", "joints_deg": [10, 20]}, {"name": "b", "tool_mm": [50, 60, 0]}],
        },
        inverse=inverse,
    )
    assert cycle.poses[1].q_rad == pytest.approx((0.5, 0.6))
    np.testing.assert_allclose(seeds[0], np.radians([10, 20]))


# -- on the A465 preset -----------------------------------------------------------------------


def test_gravity_torque_is_the_gradient_of_potential_energy() -> None:
    """torques_nm at rest = dV/dq with V = g sum m_i z_i (centres from link_frames): an
    independent check of the axes, levers and signs, payload included."""
    arm = load_arm("crs-a465")
    payload = 1.5
    q = np.radians([20.0, 35.0, 40.0, 30.0, -25.0, 10.0])

    def potential(angles: np.ndarray) -> float:
        frames = link_frames(arm, angles)
        energy = 0.0
        for i, link in enumerate(arm.links):
            centre = frames[i + 1] @ np.array([*link.com_mm, 1.0])
            energy += link.mass_kg * GRAVITY_M_S2 * centre[2] * 1e-3
        tool = (frames[-1] @ arm.tool)[2, 3]
        return float(energy + payload * GRAVITY_M_S2 * tool * 1e-3)

    step = 1e-6
    gradient = np.array(
        [(potential(q + step * e) - potential(q - step * e)) / (2 * step) for e in np.eye(arm.dof)]
    )
    rest = JointSample(0.0, q, np.zeros(6), np.zeros(6))
    torque = torques_nm(arm, rest, payload_kg=payload)
    np.testing.assert_allclose(torque, gradient, atol=1e-6)
    assert abs(torque[1]) > 10.0  # the shoulder carries the arm
    # heat at rest is the copper loss of holding that torque
    table = arm_motors(arm)
    current = torque / (table.k_t * table.ratio)
    np.testing.assert_allclose(
        joint_heat_w(arm, rest, payload_kg=payload), table.resistance * current**2, rtol=1e-12
    )


def test_arm_motor_friction_at_the_joint_is_the_same_loss() -> None:
    arm = load_arm("crs-a465")
    motor = arm.joints[0].motor
    assert motor is not None
    params = motor_parameters(motor)
    omega = 1.3
    expected = motor.viscous_friction_nm_s_per_rad * omega**2 + motor.coulomb_friction_nm * omega
    heat = motor_heat_w(params, omega, friction_torque_nm(params, omega))
    copper = (
        params.resistance_ohm
        * (
            friction_torque_nm(params, omega)
            / (params.torque_constant_nm_per_a * params.gear_ratio)
        )
        ** 2
    )
    assert heat - copper == pytest.approx(expected, rel=1e-12)


def test_heat_profile_integrates_one_cycle_and_repeats() -> None:
    arm = load_arm("crs-a465")
    cycle = load_duty_cycle("a465-pick-and-place")
    profile = JointHeatProfile.from_duty(arm, cycle, resolution_s=0.02)
    table = arm_motors(arm)

    def power(q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        return np.array(
            [
                joint_heat_w(
                    arm,
                    JointSample(0.0, q[k], qd[k], qdd[k]),
                    motors=table,
                    payload_kg=cycle.payload_kg,
                )
                for k in range(len(q))
            ]
        )

    np.testing.assert_allclose(profile.cycle_energy_j, cycle.cycle_energy_j(power, 0.02), rtol=1e-9)
    period = cycle.period_s
    # whole cycles: the mean power; energy is additive over any split of an interval
    np.testing.assert_allclose(profile.step_power_w(3 * period, 5 * period), profile.mean_power_w)
    split = profile.energy_at_j(100.3) - profile.energy_at_j(0.0)
    parts = sum(profile.step_power_w(a, b) * (b - a) for a, b in ((0.0, 41.7), (41.7, 100.3)))
    np.testing.assert_allclose(split, parts, rtol=1e-12)
    assert np.all(profile.mean_power_w >= 0.0) and profile.mean_power_w[1] > 5.0


def test_tool_poses_in_a_duty_file_go_through_the_arms_inverse_kinematics() -> None:
    arm = load_arm("crs-a465")
    q_taught = np.radians([25.0, 40.0, 35.0, 0.0, 15.0, 10.0])
    pose = forward(arm, q_taught)
    zyx = Rotation.from_matrix(pose[:3, :3]).as_euler("ZYX", degrees=True)
    data = {
        "max_speed_deg_s": 90.0,
        "max_accel_deg_s2": 180.0,
        "poses": [
            {"name": "home", "joints_deg": [20.0, 35.0, 40.0, 0.0, 10.0, 0.0]},
            {"name": "taught", "tool_mm": pose[:3, 3].tolist(), "tool_zyx_deg": zyx.tolist()},
        ],
    }
    cycle = duty_cycle_from_mapping(data, inverse=arm_inverse(arm))
    reached = forward(arm, np.array(cycle.poses[1].q_rad))
    np.testing.assert_allclose(reached, pose, atol=1e-6)

    def unreachable(pose: np.ndarray, seed: np.ndarray) -> np.ndarray:
        raise ArmError("pose out of reach within the joint limits")

    with pytest.raises(DutyCycleError, match=r"pose 'taught': pose out of reach"):
        duty_cycle_from_mapping(data, inverse=unreachable)


def test_batch_torques_are_the_per_sample_torques() -> None:
    arm = load_arm("crs-a465")
    rng = np.random.default_rng(7)
    q = rng.uniform(arm.lower_rad, arm.upper_rad, size=(5, arm.dof))
    qd = rng.normal(0.0, 1.0, size=(5, arm.dof))
    qdd = rng.normal(0.0, 3.0, size=(5, arm.dof))
    batch = torques_batch_nm(arm, q, qd, qdd, payload_kg=0.7)
    for k in range(5):
        single = torques_nm(arm, JointSample(0.0, q[k], qd[k], qdd[k]), payload_kg=0.7)
        np.testing.assert_allclose(batch[k], single, rtol=1e-12, atol=1e-12)
    heat = joint_heat_batch_w(arm, q, qd, qdd, payload_kg=0.7)
    np.testing.assert_allclose(heat, motor_heat_w(arm_motors(arm), qd, batch), rtol=1e-12)
    # point masses: the diagonal inertia is what the acceleration alone adds, less the rotor
    rest = torques_batch_nm(arm, q[:1], np.zeros((1, 6)), np.zeros((1, 6)))
    push = torques_batch_nm(arm, q[:1], np.zeros((1, 6)), np.eye(6)[1:2])
    table = arm_motors(arm)
    assert (push - rest)[0, 1] > table.ratio[1] ** 2 * table.rotor_inertia[1]


def test_heat_meter_means_the_performed_motion_between_takes() -> None:
    """Readings of the heat of the motion performed (here the preset cycle on a 10 ms grid)
    averaged per 1 s step: the whole run's mean equals the cycle's mean heat."""
    arm = load_arm("crs-a465")
    cycle = load_duty_cycle("a465-pick-and-place")
    times = np.arange(0.0, 5 * cycle.period_s + 1e-9, 0.01)
    q, qd, qdd = cycle.state(times)
    power = joint_heat_batch_w(arm, q, qd, qdd, payload_kg=cycle.payload_kg)
    meter = HeatMeter(arm.dof)
    means = []
    for k, t in enumerate(times):
        meter.add(float(t), power[k])
        if k and k % 100 == 0:
            means.append(meter.take_mean_w())
    means.append(meter.take_mean_w())
    spans = np.diff(np.concatenate([[0.0], times[100::100], [times[-1]]]))
    run_mean = np.average(means, axis=0, weights=spans)
    profile = JointHeatProfile.from_duty(arm, cycle, resolution_s=0.01)
    np.testing.assert_allclose(run_mean, profile.mean_power_w, rtol=2e-3, atol=1e-6)
    with pytest.raises(ValueError, match="before the last one"):
        meter.add(0.0, power[0])
