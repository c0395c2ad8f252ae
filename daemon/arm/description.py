"""What an arm is: its kinematic chain, its links' materials and sections, its joints' motors.

An arm is described in one TOML file (``config/arms/*.toml``; docs/reference/files.md "Arm files"):
either a Denavit-Hartenberg table (standard or modified convention) or a URDF file that the
TOML names (its kinematics parsed with yourdfpy, without meshes), plus per-link material and
section and per-joint motor/gearbox parameters. A bare ``.urdf`` loads too (kinematics only).

Conventions (``daemon.arm.types``): mm, rad, s, °C, W inside the core; the files give angles in
degrees (``*_deg``) because published DH tables and joint limits are in degrees.

The chain is held in one form for all three sources: joint ``i`` contributes
``pre_i · Rot(axis_i, q_i + theta_offset_i) · post_i`` (4×4), where

- standard DH (Denavit & Hartenberg 1955; Spong, Hutchinson & Vidyasagar, *Robot Modeling and
  Control*, 2006, Eq. 3.10): ``pre = I``, ``axis = z``, ``post = Tz(d)·Tx(a)·Rx(alpha)``;
- modified DH (Craig, *Introduction to Robotics*, 3rd ed., Eq. 3.6): ``pre = Rx(alpha)·Tx(a)``,
  ``axis = z``, ``post = Tz(d)``;
- URDF (ROS URDF ``<joint>``): ``pre = origin`` (xyz + rpy), ``axis = <axis>``, ``post = I``.

``link i`` is the body joint ``i`` moves (the frame after joint ``i``, ``link_frames[i + 1]``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from config.inputs import InputError

FloatArray = NDArray[np.float64]

Convention = Literal["standard", "modified", "urdf"]

#: URDF lengths are metres (REP 103); the core works in mm.
MM_PER_M = 1000.0


#: Moving joints an arm may have (issue 26): a 6-DOF tool correction needs a few, and the
#: arm's thermal network, kinematics and duty cycle grow with each (3,000 crashed).
MIN_ARM_JOINTS = 1
MAX_ARM_JOINTS = 32


class ArmError(InputError):
    """A bad arm file, an unknown link or joint, an unreachable pose. The message is one line
    that names the file and the field (or the link/joint) at fault."""


# ---------------------------------------------------------------------------------------------
# Values


def _frozen(array: FloatArray) -> FloatArray:
    array = np.array(array, dtype=np.float64)
    array.setflags(write=False)
    return array


def rot_x(angle_rad: float) -> FloatArray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]], dtype=np.float64)


def rot_z(angle_rad: float) -> FloatArray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)


def translation(x_mm: float, y_mm: float, z_mm: float) -> FloatArray:
    out = np.eye(4)
    out[:3, 3] = (x_mm, y_mm, z_mm)
    return out


def rot_axis(axis: FloatArray, angle_rad: float) -> FloatArray:
    """4×4 rotation by ``angle_rad`` about the unit vector ``axis`` (Rodrigues' formula)."""
    x, y, z = axis
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    v = 1.0 - c
    out = np.eye(4)
    out[:3, :3] = (
        (x * x * v + c, x * y * v - z * s, x * z * v + y * s),
        (x * y * v + z * s, y * y * v + c, y * z * v - x * s),
        (x * z * v - y * s, y * z * v + x * s, z * z * v + c),
    )
    return out


def xyz_rpy(xyz_mm: tuple[float, float, float], rpy_rad: tuple[float, float, float]) -> FloatArray:
    """The URDF ``<origin>`` transform: translate by ``xyz``, rotate by fixed-axis roll (x),
    pitch (y), yaw (z): ``R = Rz(yaw)·Ry(pitch)·Rx(roll)`` (URDF specification, ``<origin>``)."""
    from scipy.spatial.transform import Rotation

    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("xyz", rpy_rad).as_matrix()
    out[:3, 3] = xyz_mm
    return out


@dataclass(frozen=True, slots=True)
class LinkMaterial:
    """Bulk properties of a link's material (SI units, as ``daemon.model.materials``).

    ``alpha_per_c``: linear thermal expansion coefficient, 1/°C (the link grows
    ``alpha_per_c · ΔT`` per unit length). ``density_kg_per_m3``, ``specific_heat_j_per_kgk``
    (J/(kg·K)) and ``conductivity_w_per_mk`` (W/(m·K)) give the link's heat capacity and
    conduction; ``emissivity`` (0..1) its radiation and ``convection_w_per_m2k`` (W/(m²·K)) its
    natural convection to the ambient air."""

    name: str
    alpha_per_c: float
    density_kg_per_m3: float
    specific_heat_j_per_kgk: float
    conductivity_w_per_mk: float
    emissivity: float
    convection_w_per_m2k: float


@dataclass(frozen=True, slots=True)
class LinkSection:
    """A link's cross-section, constant along it: ``shape`` "round" (a tube of outer diameter
    ``outer_width_mm``) or "rect" (a box ``outer_width_mm`` × ``outer_height_mm``), with wall
    ``wall_mm`` (0: solid)."""

    shape: Literal["round", "rect"]
    outer_width_mm: float
    outer_height_mm: float
    wall_mm: float

    @property
    def area_mm2(self) -> float:
        """Metal cross-section (conduction along the link)."""
        w, h, t = self.outer_width_mm, self.outer_height_mm, self.wall_mm
        if self.shape == "round":
            inner = max(w - 2 * t, 0.0) if t > 0 else 0.0
            return math.pi / 4 * (w * w - inner * inner)
        inner_area = max(w - 2 * t, 0.0) * max(h - 2 * t, 0.0) if t > 0 else 0.0
        return w * h - inner_area

    @property
    def perimeter_mm(self) -> float:
        """Outer perimeter (the surface per unit length that convects and radiates)."""
        if self.shape == "round":
            return math.pi * self.outer_width_mm
        return 2.0 * (self.outer_width_mm + self.outer_height_mm)


@dataclass(frozen=True, slots=True)
class Link:
    """One moving link (the body its joint moves). ``mass_kg`` and ``com_mm`` (centre of mass
    in the link's frame, ``link_frames(arm, q)[i + 1]``) give gravity torques; ``length_mm``
    the length its thermal network spans (``None``: the lengths of the geometry that grows
    with it, ``Arm.link_length_mm``). ``material``/``section`` are ``None`` when the file gives only
    kinematics (the thermal model then refuses the arm)."""

    name: str
    material: LinkMaterial | None = None
    section: LinkSection | None = None
    mass_kg: float = 0.0
    com_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    length_mm: float | None = None


@dataclass(frozen=True, slots=True)
class Motor:
    """A joint's motor and gearbox (all friction and inertia figures as named).

    ``torque_constant_nm_per_a``: motor torque per ampere (motor side), N·m/A.
    ``winding_resistance_ohm``: phase-to-phase winding resistance, Ω (copper loss R·I²).
    ``gear_ratio``: motor turns per joint turn (joint torque = ratio × motor torque).
    ``viscous_friction_nm_s_per_rad``: viscous friction at the joint, N·m·s/rad.
    ``coulomb_friction_nm``: Coulomb (dry) friction at the joint, N·m.
    ``rotor_inertia_kg_m2``: rotor (+ gearbox input) inertia on the motor side, kg·m²
    (seen at the joint as ratio² × it).
    ``heats_link``: the link whose thermal network receives this motor's heat.
    """

    torque_constant_nm_per_a: float
    winding_resistance_ohm: float
    gear_ratio: float
    viscous_friction_nm_s_per_rad: float
    coulomb_friction_nm: float
    rotor_inertia_kg_m2: float
    heats_link: str


_IDENTITY = _frozen(np.eye(4))
_Z_AXIS = _frozen(np.array([0.0, 0.0, 1.0]))


@dataclass(frozen=True, eq=False)
class Joint:
    """A revolute joint and the fixed geometry around it (see the module docstring).

    DH parameters (``a_mm``, ``alpha_rad``, ``d_mm``, ``theta_offset_rad``) are those of the
    arm's convention; for a URDF arm ``origin`` (4×4, mm) and ``axis`` hold the geometry and the
    DH fields are zero. ``lower_rad``/``upper_rad``: joint limits. ``grows_with``: the link
    whose temperature scales this joint's lengths (DH ``a`` and ``d``, or the URDF origin's
    translation); by default the joint's own link for DH, the parent link for URDF (the origin
    lies in the parent). ``deflection``: the small rigid displacement a warm, bent link gives
    the distal end of this joint's geometry (identity for a cold arm; set by
    ``kinematics.warm_arm``).
    """

    name: str
    a_mm: float = 0.0
    alpha_rad: float = 0.0
    d_mm: float = 0.0
    theta_offset_rad: float = 0.0
    lower_rad: float = -math.pi
    upper_rad: float = math.pi
    motor: Motor | None = None
    grows_with: str | None = None
    origin: FloatArray = field(default_factory=lambda: _IDENTITY)
    axis: FloatArray = field(default_factory=lambda: _Z_AXIS)
    deflection: FloatArray = field(default_factory=lambda: _IDENTITY)

    def __post_init__(self) -> None:
        object.__setattr__(self, "origin", _frozen(self.origin))
        axis = np.array(self.axis, dtype=np.float64)
        norm = float(np.linalg.norm(axis))
        if axis.shape != (3,) or not norm > 0:
            raise ArmError(f"joint {self.name!r}: axis must be a non-zero 3-vector")
        object.__setattr__(self, "axis", _frozen(axis / norm))
        object.__setattr__(self, "deflection", _frozen(self.deflection))
        for label, value in (
            ("a_mm", self.a_mm),
            ("alpha", self.alpha_rad),
            ("d_mm", self.d_mm),
            ("theta_offset", self.theta_offset_rad),
        ):
            if not math.isfinite(value):  # NaN or inf would reach every pose (issue 26)
                raise ArmError(f"joint {self.name!r}: {label} is {value}, not a finite number")
        for label, matrix in (("origin", self.origin), ("axis", self.axis)):
            if not np.all(np.isfinite(matrix)):
                raise ArmError(f"joint {self.name!r}: {label} has a value that is not finite")
        if math.isnan(self.lower_rad) or math.isnan(self.upper_rad):
            raise ArmError(f"joint {self.name!r}: a joint limit is not a number")
        if not self.lower_rad <= self.upper_rad:
            raise ArmError(f"joint {self.name!r}: lower limit above upper limit")


@dataclass(frozen=True, eq=False)
class Arm:
    """A serial arm: ``joints[i]`` moves ``links[i]``; ``base`` places frame 0 in the world
    (base) frame, ``tool`` the tool on the last frame (flange). Frozen: ``warm_arm`` returns a
    new one."""

    name: str
    convention: Convention
    joints: tuple[Joint, ...]
    links: tuple[Link, ...]
    base: FloatArray = field(default_factory=lambda: _IDENTITY)
    tool: FloatArray = field(default_factory=lambda: _IDENTITY)
    description: str = ""
    # Each joint's fixed transforms, computed once (forward kinematics runs per step).
    _pre: tuple[FloatArray, ...] = field(init=False, repr=False, default=())
    _post: tuple[FloatArray, ...] = field(init=False, repr=False, default=())

    def __post_init__(self) -> None:
        if not MIN_ARM_JOINTS <= len(self.joints) <= MAX_ARM_JOINTS:
            count = len(self.joints)
            raise ArmError(
                f"arm {self.name!r}: {count} joint{'s' if count != 1 else ''}: an arm has "
                f"{MIN_ARM_JOINTS} to {MAX_ARM_JOINTS} moving joints"
            )
        for label, transform in (("base", self.base), ("tool", self.tool)):
            if not np.all(np.isfinite(np.asarray(transform, dtype=np.float64))):
                raise ArmError(f"arm {self.name!r}: {label} has a value that is not finite")
        object.__setattr__(self, "_pre", tuple(_frozen(_pre(self, i)) for i in range(self.dof)))
        object.__setattr__(self, "_post", tuple(_frozen(_post(self, i)) for i in range(self.dof)))
        object.__setattr__(self, "base", _frozen(self.base))
        object.__setattr__(self, "tool", _frozen(self.tool))
        if self.base.shape != (4, 4) or self.tool.shape != (4, 4):
            raise ArmError(f"arm {self.name!r}: base and tool must be 4×4 transforms")
        if not self.joints:
            raise ArmError(f"arm {self.name!r}: no joints")
        if len(self.links) != len(self.joints):
            raise ArmError(f"arm {self.name!r}: one link per joint, got {len(self.links)} links")
        names = [link.name for link in self.links]
        if len(set(names)) != len(names):
            raise ArmError(f"arm {self.name!r}: duplicate link names")
        joint_names = [joint.name for joint in self.joints]
        if len(set(joint_names)) != len(joint_names):
            raise ArmError(f"arm {self.name!r}: duplicate joint names")

    @property
    def dof(self) -> int:
        return len(self.joints)

    @property
    def link_names(self) -> tuple[str, ...]:
        return tuple(link.name for link in self.links)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(joint.name for joint in self.joints)

    @property
    def lower_rad(self) -> FloatArray:
        return np.array([joint.lower_rad for joint in self.joints])

    @property
    def upper_rad(self) -> FloatArray:
        return np.array([joint.upper_rad for joint in self.joints])

    def link_index(self, name: str) -> int:
        try:
            return self.link_names.index(name)
        except ValueError:
            raise ArmError(
                f"arm {self.name!r}: no link {name!r} (links: {', '.join(self.link_names)})"
            ) from None

    def link(self, name: str) -> Link:
        return self.links[self.link_index(name)]

    def joint(self, name: str) -> Joint:
        for joint in self.joints:
            if joint.name == name:
                return joint
        raise ArmError(
            f"arm {self.name!r}: no joint {name!r} (joints: {', '.join(self.joint_names)})"
        )

    def grows_with(self, joint_index: int) -> str | None:
        """The link whose temperature scales joint ``joint_index``'s lengths (``None``: the
        arm's base, which does not grow)."""
        joint = self.joints[joint_index]
        if joint.grows_with is not None:
            return joint.grows_with or None
        if self.convention == "urdf":
            return self.links[joint_index - 1].name if joint_index > 0 else None
        return self.links[joint_index].name

    def pre(self, joint_index: int) -> FloatArray:
        """The fixed transform before joint ``joint_index``'s rotation (module docstring)."""
        return self._pre[joint_index]

    def post(self, joint_index: int) -> FloatArray:
        """The fixed transform after joint ``joint_index``'s rotation, with its deflection."""
        return self._post[joint_index]

    def geometry_mm(self, joint_index: int) -> FloatArray:
        """The straight segment joint ``joint_index``'s fixed geometry spans (its lengths that
        grow with temperature), from the previous frame's origin to the point where its
        deflection applies, in the frame at that point, at zero joint angle (with the offset):
        the beam that bends (``kinematics.warm_arm``)."""
        joint = self.joints[joint_index]
        if self.convention == "urdf":
            full = joint.origin
        else:
            full = (
                self.pre(joint_index)
                @ rot_z(joint.theta_offset_rad)
                @ _strip_deflection(self, joint_index)
            )
        rotation, offset = full[:3, :3], full[:3, 3]
        return np.asarray(rotation.T @ offset, dtype=np.float64)

    def geometry_length_mm(self, joint_index: int) -> float:
        return float(np.linalg.norm(self.geometry_mm(joint_index)))

    def link_length_mm(self, name: str) -> float:
        """The length a link's thermal network spans: its ``length_mm`` when the file gives
        one, else the sum of the geometry lengths that grow with it (``grows_with``)."""
        link = self.link(name)
        if link.length_mm is not None:
            return link.length_mm
        return sum(
            self.geometry_length_mm(i) for i in range(self.dof) if self.grows_with(i) == name
        )


def _pre(arm: Arm, joint_index: int) -> FloatArray:
    joint = arm.joints[joint_index]
    if arm.convention == "standard":
        return _IDENTITY
    if arm.convention == "modified":
        return rot_x(joint.alpha_rad) @ translation(joint.a_mm, 0.0, 0.0)
    return joint.origin @ joint.deflection


def _post(arm: Arm, joint_index: int) -> FloatArray:
    joint = arm.joints[joint_index]
    if arm.convention == "urdf":
        return _IDENTITY
    return _strip_deflection(arm, joint_index) @ joint.deflection


def _strip_deflection(arm: Arm, joint_index: int) -> FloatArray:
    joint = arm.joints[joint_index]
    if arm.convention == "standard":
        return (
            translation(0.0, 0.0, joint.d_mm)
            @ translation(joint.a_mm, 0.0, 0.0)
            @ rot_x(joint.alpha_rad)
        )
    return translation(0.0, 0.0, joint.d_mm)
