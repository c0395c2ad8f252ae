"""Arm files: the TOML schema of ``config/arms/*.toml`` and the builders from it.

docs/reference/files.md "Arm files" lists the fields; ``daemon.arm.description`` holds the values
they build; ``daemon.arm.loading.load_arm`` is the entry point (a DH table here, a URDF through
``daemon.arm.urdf``). Every problem is an :class:`ArmError` with one line
naming the file and the field (or the joint/link) at fault.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from daemon.arm.description import (
    MAX_ARM_JOINTS,
    Arm,
    ArmError,
    FloatArray,
    Joint,
    Link,
    LinkMaterial,
    LinkSection,
    Motor,
    xyz_rpy,
)

#: Bounds of an arm file's numbers (issue 26): far beyond any arm, low enough that no pose,
#: volume or heat computed from them overflows. Lengths in mm (100 m), angles in degrees.
MAX_LENGTH_MM = 100_000.0
MAX_ANGLE_DEG = 360.0
MAX_LIMIT_DEG = 3_600.0  # a multi-turn joint's limits
MAX_LINKS = 64

Length = Annotated[float, Field(ge=-MAX_LENGTH_MM, le=MAX_LENGTH_MM)]
PositiveLength = Annotated[float, Field(gt=0, le=MAX_LENGTH_MM)]
Angle = Annotated[float, Field(ge=-MAX_ANGLE_DEG, le=MAX_ANGLE_DEG)]
Limit = Annotated[float, Field(ge=-MAX_LIMIT_DEG, le=MAX_LIMIT_DEG)]


class _Strict(BaseModel):
    # allow_inf_nan=False: TOML's nan and inf are refused naming the field, never computed with
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class _Placement(_Strict):
    xyz_mm: tuple[Length, Length, Length] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[Angle, Angle, Angle] = (0.0, 0.0, 0.0)


class _Motor(_Strict):
    torque_constant_nm_per_a: float = Field(gt=0)
    winding_resistance_ohm: float = Field(ge=0)
    gear_ratio: float = Field(gt=0)
    viscous_friction_nm_s_per_rad: float = Field(default=0.0, ge=0)
    coulomb_friction_nm: float = Field(default=0.0, ge=0)
    rotor_inertia_kg_m2: float = Field(default=0.0, ge=0)
    heats_link: str | None = None


class _Joint(_Strict):
    name: str
    link: str | None = None  # DH: the link this joint moves (default "<joint name>-link")
    a_mm: Length = 0.0
    alpha_deg: Angle = 0.0
    d_mm: Length = 0.0
    theta_offset_deg: Angle = 0.0
    lower_deg: Limit | None = None
    upper_deg: Limit | None = None
    grows_with: str | None = None  # "" : the base (does not grow)
    motor: _Motor | None = None


class _Material(_Strict):
    name: str = ""
    alpha_per_c: float = Field(ge=0)
    density_kg_per_m3: float = Field(gt=0)
    specific_heat_j_per_kgk: float = Field(gt=0)
    conductivity_w_per_mk: float = Field(gt=0)
    emissivity: float = Field(ge=0, le=1)
    convection_w_per_m2k: float = Field(ge=0)


class _Section(_Strict):
    shape: Literal["round", "rect"]
    outer_width_mm: PositiveLength
    outer_height_mm: PositiveLength | None = None
    wall_mm: Annotated[float, Field(ge=0, le=MAX_LENGTH_MM)] = 0.0


class _Link(_Strict):
    name: str
    mass_kg: float = Field(default=0.0, ge=0)
    com_mm: tuple[Length, Length, Length] = (0.0, 0.0, 0.0)
    length_mm: PositiveLength | None = None
    material: _Material | None = None
    section: _Section | None = None


class ArmFileSpec(_Strict):
    name: str | None = None
    description: str = ""
    convention: Literal["standard", "modified"] | None = None
    urdf: str | None = None  # path relative to this file
    base_link: str | None = None  # URDF: the chain's root (default: the URDF's root)
    tip_link: str | None = None  # URDF: the chain's last link (default: the only leaf)
    base: _Placement = _Placement()
    tool: _Placement = _Placement()
    joints: Annotated[tuple[_Joint, ...], Field(max_length=MAX_ARM_JOINTS)] = ()
    links: Annotated[tuple[_Link, ...], Field(max_length=MAX_LINKS)] = ()


def describe_error(err: ValidationError, data: dict[str, Any]) -> str:
    problems = []
    for problem in err.errors():
        location = list(problem["loc"])
        where = ".".join(str(part) for part in location)
        table = str(location[0]) if location else ""
        if len(location) >= 2 and table in ("joints", "links") and isinstance(location[1], int):
            try:
                name = data[table][location[1]]["name"]
                kind = table[:-1]
                where = f"{kind} {name!r}: " + ".".join(str(part) for part in location[2:])
            except (KeyError, IndexError, TypeError):
                pass
        problems.append(f"{where}: {problem['msg']}")
    return "; ".join(problems)


def placement(spec: _Placement) -> FloatArray:
    roll, pitch, yaw = (math.radians(v) for v in spec.rpy_deg)
    return xyz_rpy(spec.xyz_mm, (roll, pitch, yaw))


def _material(spec: _Material | None) -> LinkMaterial | None:
    if spec is None:
        return None
    return LinkMaterial(
        name=spec.name,
        alpha_per_c=spec.alpha_per_c,
        density_kg_per_m3=spec.density_kg_per_m3,
        specific_heat_j_per_kgk=spec.specific_heat_j_per_kgk,
        conductivity_w_per_mk=spec.conductivity_w_per_mk,
        emissivity=spec.emissivity,
        convection_w_per_m2k=spec.convection_w_per_m2k,
    )


def _section(spec: _Section | None) -> LinkSection | None:
    if spec is None:
        return None
    height = spec.outer_height_mm
    if spec.shape == "round":
        height = spec.outer_width_mm
    elif height is None:
        raise ArmError("section: a rect section needs outer_height_mm")
    if spec.wall_mm * 2 >= min(spec.outer_width_mm, height):
        raise ArmError("section: wall_mm is half the outer size or more (give 0 for solid)")
    return LinkSection(spec.shape, spec.outer_width_mm, height, spec.wall_mm)


def build_links(specs: tuple[_Link, ...], names: list[str]) -> tuple[Link, ...]:
    by_name: dict[str, _Link] = {}
    spec: _Link | None
    for spec in specs:
        if spec.name in by_name:
            raise ArmError(f"link {spec.name!r}: listed twice")
        if spec.name not in names:
            raise ArmError(f"link {spec.name!r}: no joint moves it (links: {', '.join(names)})")
        by_name[spec.name] = spec
    links = []
    for name in names:
        spec = by_name.get(name)
        if spec is None:
            links.append(Link(name))
            continue
        try:
            section = _section(spec.section)
        except ArmError as err:
            raise ArmError(f"link {name!r}: {err}") from err
        links.append(
            Link(
                name=name,
                material=_material(spec.material),
                section=section,
                mass_kg=spec.mass_kg,
                com_mm=spec.com_mm,
                length_mm=spec.length_mm,
            )
        )
    return tuple(links)


def build_motor(spec: _Motor | None, default_link: str) -> Motor | None:
    if spec is None:
        return None
    return Motor(
        torque_constant_nm_per_a=spec.torque_constant_nm_per_a,
        winding_resistance_ohm=spec.winding_resistance_ohm,
        gear_ratio=spec.gear_ratio,
        viscous_friction_nm_s_per_rad=spec.viscous_friction_nm_s_per_rad,
        coulomb_friction_nm=spec.coulomb_friction_nm,
        rotor_inertia_kg_m2=spec.rotor_inertia_kg_m2,
        heats_link=spec.heats_link or default_link,
    )


def limit_rad(value_deg: float | None, default_rad: float) -> float:
    return default_rad if value_deg is None else math.radians(value_deg)


def check_links_named(arm: Arm) -> None:
    names = set(arm.link_names)
    for joint in arm.joints:
        if joint.grows_with and joint.grows_with not in names:
            raise ArmError(f"joint {joint.name!r}: grows_with {joint.grows_with!r} is no link")
        if joint.motor is not None and joint.motor.heats_link not in names:
            raise ArmError(
                f"joint {joint.name!r}: motor.heats_link {joint.motor.heats_link!r} is no link"
            )


def dh_arm(spec: ArmFileSpec, name: str) -> Arm:
    if spec.convention is None:
        raise ArmError('convention: give "standard" or "modified" (or urdf = "<file>")')
    if not spec.joints:
        raise ArmError("joints: a DH arm needs [[joints]] rows")
    link_names = [joint.link or f"{joint.name}-link" for joint in spec.joints]
    joints = tuple(
        Joint(
            name=row.name,
            a_mm=row.a_mm,
            alpha_rad=math.radians(row.alpha_deg),
            d_mm=row.d_mm,
            theta_offset_rad=math.radians(row.theta_offset_deg),
            lower_rad=limit_rad(row.lower_deg, -math.pi),
            upper_rad=limit_rad(row.upper_deg, math.pi),
            motor=build_motor(row.motor, link_names[i]),
            grows_with=row.grows_with,
        )
        for i, row in enumerate(spec.joints)
    )
    arm = Arm(
        name=name,
        convention=spec.convention,
        joints=joints,
        links=build_links(spec.links, link_names),
        base=placement(spec.base),
        tool=placement(spec.tool),
        description=spec.description,
    )
    check_links_named(arm)
    return arm
