"""Heat of each joint's motor and gearbox from the motion (issue 20; thesis 1.3 "Step 2:
calculate work and losses ... using the efficiency of the motors").

A joint is a motor (torque constant ``k_t``, winding resistance ``R``, rotor inertia ``J_r``)
driving the link through a gearbox of ratio ``N`` (motor turns per joint turn) and efficiency
``eta``. With the joint-side torque ``tau`` and speed ``omega`` (what :func:`torques_nm` and the
duty cycle give), the motor side turns at ``omega_m = N omega`` and delivers

    tau_m = tau / (N eta)   when it drives the load (tau omega >= 0),
    tau_m = tau eta / N     when the load drives it (braking, lowering against gravity),

so its current is ``I = tau_m / k_t`` and the heat released in the joint is

    P = R I^2                                   copper (Joule) loss
      + b omega_m^2 + tau_c |omega_m|            viscous and Coulomb friction (motor side)
      + |tau omega - tau_m omega_m|              the gearbox's loss (zero when eta = 1).

These are the datasheet conventions of DC/EC servo motors (maxon, "Key information on maxon
DC and EC motors": terminal resistance ``R``, torque constant ``k_M``, Joule loss ``R I^2``,
friction torque; a gearbox by its maximum efficiency). The friction torques are part of the
torque the motor supplies: :func:`torques_nm` adds them to ``tau``, so the friction work is
counted once, as heat. Kinetic and potential energy are not heat: the inertia and gravity
terms only heat the joint through ``R I^2``.

Where a robot reports its motor currents or electrical power, the heat comes from the
measurement instead: :func:`heat_from_current_w` and :func:`heat_from_power_w`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

from daemon.arm.description import Arm, ArmError, Motor
from daemon.arm.types import FloatArray, JointSample

#: Standard gravity (m/s^2), ISO 80000-3.
GRAVITY_M_S2 = 9.80665
MM = 1e-3  # m per mm


@dataclass(frozen=True, slots=True)
class MotorParameters:
    """One joint's motor and gearbox, datasheet conventions (see the module docstring).

    ``gear_ratio``: motor turns per joint turn (``N``, > 0). ``torque_constant_nm_per_a``:
    ``k_t``. ``resistance_ohm``: winding (terminal) resistance ``R``. ``viscous_nm_s_per_rad``
    and ``coulomb_nm``: friction at the motor side (``b``, ``tau_c``). ``gear_efficiency``:
    ``eta`` in (0, 1]. ``rotor_inertia_kg_m2``: rotor + gearbox input, motor side (``J_r``);
    it appears at the joint as ``N^2 J_r``. ``housing_mass_kg``: motor + gearbox mass, for
    the joint's heat capacity and the gravity load (0: unknown).
    """

    gear_ratio: float
    torque_constant_nm_per_a: float
    resistance_ohm: float
    viscous_nm_s_per_rad: float = 0.0
    coulomb_nm: float = 0.0
    gear_efficiency: float = 1.0
    rotor_inertia_kg_m2: float = 0.0
    housing_mass_kg: float = 0.0

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if not math.isfinite(value) or value < 0.0:
                raise ValueError(f"motor {item.name} must be finite and >= 0, got {value}")
        for name in ("gear_ratio", "torque_constant_nm_per_a"):
            if getattr(self, name) <= 0.0:
                raise ValueError(f"motor {name} must be positive, got {getattr(self, name)}")
        if not 0.0 < self.gear_efficiency <= 1.0:
            raise ValueError(f"gear efficiency must be in (0, 1], got {self.gear_efficiency}")


def _column(name: str) -> cached_property[FloatArray]:
    """A MotorTable property: the MotorParameters field ``name`` of every joint, as an array
    (computed once)."""

    def column(table: MotorTable) -> FloatArray:
        return np.array([getattr(joint, name) for joint in table.joints], dtype=np.float64)

    column.__name__ = name
    return cached_property(column)


@dataclass(frozen=True, eq=False)
class MotorTable:
    """The parameters of several joints as arrays (one element per joint), for vector math."""

    joints: tuple[MotorParameters, ...]

    ratio = _column("gear_ratio")
    k_t = _column("torque_constant_nm_per_a")
    resistance = _column("resistance_ohm")
    viscous = _column("viscous_nm_s_per_rad")
    coulomb = _column("coulomb_nm")
    efficiency = _column("gear_efficiency")
    rotor_inertia = _column("rotor_inertia_kg_m2")

    @classmethod
    def of(cls, params: MotorParameters | Sequence[MotorParameters] | MotorTable) -> MotorTable:
        if isinstance(params, MotorTable):
            return params
        if isinstance(params, MotorParameters):
            return cls((params,))
        return cls(tuple(params))


def motor_torque_nm(
    params: MotorParameters | Sequence[MotorParameters] | MotorTable,
    qd_rad_s: ArrayLike,
    torque_nm: ArrayLike,
) -> FloatArray:
    """The motor-side torque ``tau_m`` for a joint torque ``tau`` (module docstring)."""
    table = MotorTable.of(params)
    tau = np.asarray(torque_nm, dtype=np.float64)
    omega = np.asarray(qd_rad_s, dtype=np.float64)
    driving = tau * omega >= 0.0
    result: FloatArray = np.where(
        driving, tau / (table.ratio * table.efficiency), tau * table.efficiency / table.ratio
    )
    return result


def friction_torque_nm(
    params: MotorParameters | Sequence[MotorParameters] | MotorTable, qd_rad_s: ArrayLike
) -> FloatArray:
    """The joint-side torque the motor spends on its own friction: ``N (b N omega + tau_c
    sign(omega))`` (zero at rest: static friction does no work)."""
    table = MotorTable.of(params)
    omega = np.asarray(qd_rad_s, dtype=np.float64)
    result: FloatArray = table.ratio * (
        table.viscous * table.ratio * omega + table.coulomb * np.sign(omega)
    )
    return result


def motor_heat_w(
    params: MotorParameters | Sequence[MotorParameters] | MotorTable,
    qd_rad_s: ArrayLike,
    torque_nm: ArrayLike,
) -> FloatArray:
    """Heat released in each joint (W) at joint speed ``qd_rad_s`` and joint torque
    ``torque_nm`` (friction included, as :func:`torques_nm` gives it): copper loss, motor
    friction and gearbox loss (module docstring). Element-wise over joints (and broadcasts
    over leading axes, e.g. a whole cycle of samples × joints)."""
    table = MotorTable.of(params)
    tau = np.asarray(torque_nm, dtype=np.float64)
    omega = np.asarray(qd_rad_s, dtype=np.float64)
    tau_m = motor_torque_nm(table, omega, tau)
    omega_m = table.ratio * omega
    current = tau_m / table.k_t
    copper = table.resistance * current**2
    friction = table.viscous * omega_m**2 + table.coulomb * np.abs(omega_m)
    gearbox = np.abs(tau * omega - tau_m * omega_m)
    heat: FloatArray = copper + friction + gearbox
    return heat


def heat_from_current_w(
    params: MotorParameters | Sequence[MotorParameters] | MotorTable,
    qd_rad_s: ArrayLike,
    current_a: ArrayLike,
) -> FloatArray:
    """Heat from a measured motor current (a robot's per-joint current feed): ``R I^2`` plus
    the motor friction at the measured speed. The gearbox's loss is not observable from the
    current alone and is left out (``eta = 1``)."""
    table = MotorTable.of(params)
    current = np.asarray(current_a, dtype=np.float64)
    omega_m = table.ratio * np.asarray(qd_rad_s, dtype=np.float64)
    heat: FloatArray = (
        table.resistance * current**2 + table.viscous * omega_m**2 + table.coulomb * np.abs(omega_m)
    )
    return heat


def heat_from_power_w(
    electrical_power_w: ArrayLike, qd_rad_s: ArrayLike, torque_nm: ArrayLike
) -> FloatArray:
    """Heat from a measured electrical input power per joint: what goes in and does not leave
    as mechanical power ``tau omega`` at the joint. Clipped at zero (a regenerating joint
    returns power to the drive, it does not cool the arm)."""
    power = np.asarray(electrical_power_w, dtype=np.float64)
    mechanical = np.asarray(torque_nm, dtype=np.float64) * np.asarray(qd_rad_s, dtype=np.float64)
    heat: FloatArray = np.clip(power - mechanical, 0.0, None)
    return heat


def gravity_torques_nm(
    joint_origins_mm: FloatArray,
    joint_axes: FloatArray,
    masses_kg: FloatArray,
    centres_mm: FloatArray,
    gravity_m_s2: FloatArray | None = None,
) -> FloatArray:
    """Torque each revolute joint must hold against gravity (N·m).

    Joint ``j`` (origin ``o_j``, unit axis ``z_j``, base frame) carries every mass ``i >= j``
    (mass ``m_i`` at ``p_i``): ``tau_j = -sum_{i >= j} (z_j x (p_i - o_j)) . m_i g``, the
    derivative of the potential energy ``-sum m_i g . p_i`` (Siciliano et al., *Robotics:
    Modelling, Planning and Control*, 2009, Sec. 7.2: ``g(q) = -sum m_i J_P^(i)T g0``).
    ``masses_kg[i]``/``centres_mm[i]`` belong to link ``i``, the one joint ``i`` moves.
    """
    g = np.array([0.0, 0.0, -GRAVITY_M_S2]) if gravity_m_s2 is None else gravity_m_s2
    count = len(joint_origins_mm)
    torques = np.zeros(count)
    for j in range(count):
        arms_m = (centres_mm[j:] - joint_origins_mm[j]) * MM
        lever = np.cross(joint_axes[j], arms_m)  # dp_i / dq_j per unit rotation
        torques[j] = -float(np.sum((lever @ g) * masses_kg[j:]))
    return torques


def inertia_diagonal_kg_m2(
    joint_origins_mm: FloatArray,
    joint_axes: FloatArray,
    masses_kg: FloatArray,
    centres_mm: FloatArray,
) -> FloatArray:
    """The diagonal of the joint-space mass matrix for point masses at the links' centres:
    ``M_jj = sum_{i >= j} m_i |z_j x (p_i - o_j)|^2`` (kg·m²). The links' own rotational
    inertia and the off-diagonal coupling are left out: a duty cycle's heat is dominated by
    gravity and friction, and its accelerations act only for short ramps."""
    count = len(joint_origins_mm)
    result = np.zeros(count)
    for j in range(count):
        arms_m = (centres_mm[j:] - joint_origins_mm[j]) * MM
        lever = np.cross(joint_axes[j], arms_m)
        result[j] = float(np.sum(np.einsum("ij,ij->i", lever, lever) * masses_kg[j:]))
    return result


def joint_torques_nm(
    params: MotorParameters | Sequence[MotorParameters] | MotorTable,
    qd_rad_s: ArrayLike,
    qdd_rad_s2: ArrayLike,
    gravity_nm: ArrayLike,
    link_inertia_kg_m2: ArrayLike,
) -> FloatArray:
    """``tau = g(q) + (M_jj + N^2 J_r) qdd + friction(qd)``: gravity, the links' inertia (the
    diagonal of the mass matrix), the rotor's inertia reflected through the gearbox and the
    motor friction (:func:`friction_torque_nm`)."""
    table = MotorTable.of(params)
    qdd = np.asarray(qdd_rad_s2, dtype=np.float64)
    inertia = np.asarray(link_inertia_kg_m2, dtype=np.float64) + table.ratio**2 * (
        table.rotor_inertia
    )
    torque: FloatArray = (
        np.asarray(gravity_nm, dtype=np.float64)
        + inertia * qdd
        + friction_torque_nm(table, qd_rad_s)
    )
    return torque


def motor_parameters(motor: Motor) -> MotorParameters:
    """An arm file's motor (``description.Motor``: friction given at the joint) as
    :class:`MotorParameters` (friction at the motor side: ``b = B_joint / N^2``,
    ``tau_c = tau_c,joint / N``; the same losses). The arm file has no gearbox efficiency:
    its friction holds the gearbox's losses (``eta = 1``)."""
    ratio = motor.gear_ratio
    return MotorParameters(
        gear_ratio=ratio,
        torque_constant_nm_per_a=motor.torque_constant_nm_per_a,
        resistance_ohm=motor.winding_resistance_ohm,
        viscous_nm_s_per_rad=motor.viscous_friction_nm_s_per_rad / ratio**2,
        coulomb_nm=motor.coulomb_friction_nm / ratio,
        rotor_inertia_kg_m2=motor.rotor_inertia_kg_m2,
    )


def arm_motors(arm: Arm) -> MotorTable:
    """Every joint's motor from the arm file; an arm with a joint without one cannot say how
    its motion heats it."""
    missing = [joint.name for joint in arm.joints if joint.motor is None]
    if missing:
        raise ArmError(f"arm {arm.name!r}: joint {missing[0]!r} has no motor parameters")
    return MotorTable(tuple(motor_parameters(joint.motor) for joint in arm.joints if joint.motor))


def _rotations(axis: FloatArray, angles: FloatArray) -> FloatArray:
    """(S, 4, 4) rotations about one unit ``axis`` by each angle: Rodrigues' formula
    ``R = c I + s [a]x + (1 - c) a a^T``, as ``description.rot_axis``."""
    x, y, z = axis
    skew = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    c, s = np.cos(angles)[:, None, None], np.sin(angles)[:, None, None]
    out = np.zeros((len(angles), 4, 4))
    out[:, :3, :3] = c * np.eye(3) + s * skew + (1.0 - c) * np.outer(axis, axis)
    out[:, 3, 3] = 1.0
    return out


@dataclass(frozen=True, eq=False)
class _MassModel:
    """Per sample (first axis): joint origins and axes, the links' centres, and the masses."""

    origins_mm: FloatArray  # (S, N, 3)
    axes: FloatArray  # (S, N, 3)
    centres_mm: FloatArray  # (S, N, 3)
    masses_kg: FloatArray  # (N,)


def _mass_model(arm: Arm, q_rad: FloatArray, payload_kg: float) -> _MassModel:
    """The chain of ``kinematics.link_frames`` (pivot ``frame_i pre_i``, rotation about the
    joint's axis, ``post_i``) for many configurations at once (rows of ``q_rad``)."""
    q = np.atleast_2d(np.asarray(q_rad, dtype=np.float64))
    count = len(q)
    current = np.broadcast_to(arm.base, (count, 4, 4))
    origins, axes, centres = [], [], []
    for i, joint in enumerate(arm.joints):
        pivot = current @ arm.pre(i)
        origins.append(pivot[:, :3, 3])
        axes.append(pivot[:, :3, :3] @ joint.axis)
        current = pivot @ _rotations(joint.axis, q[:, i] + joint.theta_offset_rad) @ arm.post(i)
        centres.append((current @ np.array([*arm.links[i].com_mm, 1.0]))[:, :3])
    masses = np.array([link.mass_kg for link in arm.links], dtype=np.float64)
    centre = np.stack(centres, axis=1)
    if payload_kg > 0.0:  # the payload at the tool point, carried by the last link
        tool_point = (current @ arm.tool)[:, :3, 3]
        last = masses[-1] + payload_kg
        centre[:, -1] = (masses[-1] * centre[:, -1] + payload_kg * tool_point) / last
        masses[-1] = last
    return _MassModel(np.stack(origins, axis=1), np.stack(axes, axis=1), centre, masses)


def _levers(model: _MassModel) -> FloatArray:
    """``z_j x (p_i - o_j)`` (m per rad) for i >= j, zero below: (S, N joints, N links, 3)."""
    arms_m = (model.centres_mm[:, None, :, :] - model.origins_mm[:, :, None, :]) * MM
    lever = np.cross(model.axes[:, :, None, :], arms_m)
    count = model.masses_kg.size
    carried = np.triu(np.ones((count, count), dtype=bool))  # joint j carries links i >= j
    result: FloatArray = lever * carried[None, :, :, None]
    return result


def torques_batch_nm(
    arm: Arm,
    q_rad: ArrayLike,
    qd_rad_s: ArrayLike,
    qdd_rad_s2: ArrayLike,
    *,
    motors: MotorTable | None = None,
    payload_kg: float = 0.0,
) -> FloatArray:
    """:func:`torques_nm` for many samples at once (rows: samples, columns: joints)."""
    table = arm_motors(arm) if motors is None else motors
    model = _mass_model(arm, np.asarray(q_rad, dtype=np.float64), payload_kg)
    lever = _levers(model)
    g = np.array([0.0, 0.0, -GRAVITY_M_S2])
    gravity = -((lever @ g) @ model.masses_kg)  # -sum_i m_i (z_j x r_ij) . g
    inertia = np.square(lever).sum(axis=-1) @ model.masses_kg  # sum_i m_i |z_j x r_ij|^2
    qd = np.atleast_2d(np.asarray(qd_rad_s, dtype=np.float64))
    qdd = np.atleast_2d(np.asarray(qdd_rad_s2, dtype=np.float64))
    return joint_torques_nm(table, qd, qdd, gravity, inertia)


def torques_nm(
    arm: Arm,
    sample: JointSample,
    *,
    motors: MotorTable | None = None,
    payload_kg: float = 0.0,
) -> FloatArray:
    """The joint torques (N·m) the motors supply at ``sample``: gravity from the links'
    masses and centres of mass (as :func:`gravity_torques_nm`, along the chain of
    ``kinematics.link_frames``), the diagonal inertia of the links as point masses plus the
    rotors' reflected inertia times ``qdd``, and the motors' friction
    (:func:`joint_torques_nm`). Simple on purpose: Coriolis/centrifugal terms and the
    off-diagonal inertia are left out (slow, short moves: their work over a cycle is small
    against gravity's copper loss and friction)."""
    torque = torques_batch_nm(
        arm, sample.q_rad, sample.qd_rad_s, sample.qdd_rad_s2, motors=motors,
        payload_kg=payload_kg,
    )  # fmt: skip
    result: FloatArray = torque[0]
    return result


def joint_heat_batch_w(
    arm: Arm,
    q_rad: ArrayLike,
    qd_rad_s: ArrayLike,
    qdd_rad_s2: ArrayLike,
    *,
    motors: MotorTable | None = None,
    payload_kg: float = 0.0,
) -> FloatArray:
    """:func:`joint_heat_w` for many samples at once (rows: samples, columns: joints)."""
    table = arm_motors(arm) if motors is None else motors
    torque = torques_batch_nm(arm, q_rad, qd_rad_s, qdd_rad_s2, motors=table, payload_kg=payload_kg)
    return motor_heat_w(table, np.atleast_2d(np.asarray(qd_rad_s, np.float64)), torque)


def joint_heat_w(
    arm: Arm,
    sample: JointSample,
    *,
    motors: MotorTable | None = None,
    payload_kg: float = 0.0,
) -> FloatArray:
    """Heat released in each joint (W) at ``sample``: :func:`motor_heat_w` of
    :func:`torques_nm`."""
    table = arm_motors(arm) if motors is None else motors
    torque = torques_nm(arm, sample, motors=table, payload_kg=payload_kg)
    return motor_heat_w(table, sample.qd_rad_s, torque)


__all__ = [
    "GRAVITY_M_S2",
    "MotorParameters",
    "MotorTable",
    "arm_motors",
    "friction_torque_nm",
    "gravity_torques_nm",
    "heat_from_current_w",
    "heat_from_power_w",
    "inertia_diagonal_kg_m2",
    "joint_heat_batch_w",
    "joint_heat_w",
    "joint_torques_nm",
    "motor_heat_w",
    "motor_parameters",
    "motor_torque_nm",
    "torques_batch_nm",
    "torques_nm",
]
