"""The physics of the simulated arm (drivers/sim/arm_bench.py): the true arm -- the preset's
with its seeded geometric and motor errors -- its true thermal description, and the heat its
joints give off for a motion (the bench's module docstring says how large each error is and why).

Pure functions of the arm and the draws given: the bench owns the generators and the state.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from daemon.arm.description import Arm
from daemon.arm.motors import (
    arm_motors,
    joint_heat_batch_w,
    joint_heat_w,
    motor_torque_nm,
    torques_nm,
)
from daemon.arm.thermal import ArmThermalDescription, describe_arm
from daemon.arm.types import FloatArray, JointSample
from drivers.sim.arm_motion import BatchPowerFunction, PowerFunction


def true_arm(
    arm: Arm,
    rng: np.random.Generator,
    length_mm: float,
    angle_rad: float,
    heat_scales: FloatArray,
) -> Arm:
    """The true arm: each DH row's a, d (1-sigma ``length_mm``) and alpha, theta offset
    (``angle_rad``) moved by draws from ``rng``, and each joint's winding resistance and
    friction times its heat factor (its heat for the same motion scales by about that
    factor; module docstring)."""
    rows = []
    for row, factor in zip(arm.joints, heat_scales, strict=True):
        a, d, alpha, theta = rng.normal(0.0, 1.0, 4)
        motor = row.motor
        if motor is not None:
            k = float(factor)
            motor = dataclasses.replace(
                motor,
                winding_resistance_ohm=motor.winding_resistance_ohm * k,
                viscous_friction_nm_s_per_rad=motor.viscous_friction_nm_s_per_rad * k,
                coulomb_friction_nm=motor.coulomb_friction_nm * k,
            )
        rows.append(
            dataclasses.replace(
                row,
                a_mm=row.a_mm + length_mm * a,
                d_mm=row.d_mm + length_mm * d,
                alpha_rad=row.alpha_rad + angle_rad * alpha,
                theta_offset_rad=row.theta_offset_rad + angle_rad * theta,
                motor=motor,
            )
        )
    return dataclasses.replace(arm, name=f"{arm.name} (true)", joints=tuple(rows))


def true_description(
    arm: Arm, alpha_scale: float, capacity_scale: float, plus_share: float = 0.5
) -> ArmThermalDescription:
    """The thermal description of the true arm: its links' alpha and joints' capacity scaled,
    ``plus_share`` of each joint flange's conductance on the links' "+" side."""
    description = describe_arm(arm, plus_share=plus_share)
    return dataclasses.replace(
        description,
        links=tuple(
            dataclasses.replace(link, alpha_per_c=link.alpha_per_c * alpha_scale)
            for link in description.links
        ),
        joints=tuple(
            dataclasses.replace(
                joint, capacitance_j_per_c=joint.capacitance_j_per_c * capacity_scale
            )
            for joint in description.joints
        ),
    )


def motion_power(arm: Arm, payload_kg: float = 0.0) -> PowerFunction:
    """The heat of every joint (W) for a motion sample: :func:`daemon.arm.motors.joint_heat_w`
    (the motors' losses at the torque the sample takes, with the arm's own motors, carrying
    ``payload_kg`` at the tool point)."""
    motors = arm_motors(arm)

    def power(sample: JointSample) -> FloatArray:
        heat: FloatArray = np.asarray(
            joint_heat_w(arm, sample, motors=motors, payload_kg=payload_kg), dtype=np.float64
        )
        return heat

    return power


def motor_current(arm: Arm, payload_kg: float = 0.0) -> PowerFunction:
    """Each joint motor's current (A) for a motion sample: the torque the sample takes
    (:func:`daemon.arm.motors.torques_nm`, with the arm's own motors and friction, carrying
    ``payload_kg``) through the gearbox to the motor side (``motor_torque_nm``) over the torque
    constant: ``I = tau_m / k_t``, signed as the torque. Its ``R I^2`` is the copper loss of
    :func:`motion_power` (daemon/arm/motors.py), so the heat computed back from it with the
    motor's resistance and friction is that sample's heat."""
    motors = arm_motors(arm)

    def current(sample: JointSample) -> FloatArray:
        torque = torques_nm(arm, sample, motors=motors, payload_kg=payload_kg)
        tau_m = motor_torque_nm(motors, sample.qd_rad_s, torque)
        result: FloatArray = np.asarray(tau_m / motors.k_t, dtype=np.float64)
        return result

    return current


def motion_power_batch(arm: Arm, payload_kg: float = 0.0) -> BatchPowerFunction:
    """:func:`motion_power` for many samples at once (``joint_heat_batch_w``)."""
    motors = arm_motors(arm)

    def power(q: FloatArray, qd: FloatArray, qdd: FloatArray) -> FloatArray:
        heat: FloatArray = np.asarray(
            joint_heat_batch_w(arm, q, qd, qdd, motors=motors, payload_kg=payload_kg),
            dtype=np.float64,
        )
        return heat

    return power
