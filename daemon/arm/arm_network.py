"""The arm's thermal network (issue 20): every link an RC chain along its geometry, the joints'
motors and gearboxes as heat sources between links, a path through the base to ambient.

Thesis 5.4 generalised from one bar to a serial arm. Each link is a tube of its material and
cross-section along the geometry whose lengths grow with it (the straight segment whose length
``warm_arm`` scales by ``1 + alpha dT``), cut into nodes at most ``node_spacing_mm`` apart.
Between neighbouring nodes ``R = dx / (k A)``; each node has ``C = rho c A l`` (or the link's
whole mass, when known, spread along it) and loses heat to ambient through
``R_inf = 1 / (h_eff P l)`` with ``h_eff = h + 4 eps sigma T_amb^3`` (convection plus
linearised radiation, Incropera, *Fundamentals of Heat and Mass Transfer*, Eq. 1.9). Joint
``j`` is one node (its motor and gearbox housing: capacitance from its mass, its own surface
to ambient) joined across its two flanges to the last node of link ``j-1`` (or the base) and
to the first node of link ``j``: bolted on the housing's side, through the bearings on the
other. The base is one node of the base casting with a path to ambient (its own surface and
the mounting table). Every node carries its link and 3-D position (the arm at its zero
configuration). ``across_link`` splits each link into two rows of nodes to resolve the
temperature across it (:func:`build_arm_network`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from daemon.arm.description import Arm, ArmError
from daemon.arm.kinematics import link_frames
from daemon.arm.types import FloatArray
from daemon.model.network import Resistance, ThermalNetwork

MM = 1e-3  # m per mm
#: Stefan-Boltzmann constant (W/m^2K^4), CODATA 2018.
STEFAN_BOLTZMANN = 5.670374419e-8
KELVIN = 273.15
IntArray = NDArray[np.intp]
#: Default node spacing along a link; the bench's truth uses a finer one.
DEFAULT_NODE_SPACING_MM = 50.0
#: A link's direction components along its bending frame's y and z closer than this are a
#: tie (its rows split across z): 0.01 is 0.6 degrees, far above an arm's geometry errors
#: (the bench truth's 0.2 mrad) and far below a link truly nearer one axis.
ACROSS_TIE = 1e-2
#: A link with no length (a wrist whose DH a and d are 0) still holds metal: this much.
MIN_LINK_LENGTH_MM = 40.0
#: Estimates where an arm file gives none: motor + gearbox housing of a small arm's joint
#: (mostly steel and copper, c ~ 480 J/kgK), its surface, the contact resistance across a
#: bolted joint flange, and the base casting (aluminium) with its mounting to the table.
DEFAULT_JOINT_MASS_KG = 0.8
JOINT_SPECIFIC_HEAT_J_PER_KGK = 480.0
DEFAULT_JOINT_AREA_M2 = 0.02
DEFAULT_CONTACT_R_C_PER_W = 0.5
DEFAULT_BEARING_R_C_PER_W = 2.0
DEFAULT_BASE_MASS_KG = 6.0
BASE_SPECIFIC_HEAT_J_PER_KGK = 896.0  # 6061-T6 (thesis Table 3.1)
DEFAULT_BASE_R_AMBIENT_C_PER_W = 0.8
#: Free convection on a slowly moving arm (thesis 3.4 measured 7.75 W/m^2K on a moving link).
DEFAULT_H_W_PER_M2K = 7.75


@dataclass(frozen=True, slots=True)
class LinkBody:
    """One link as the thermal model sees it: a tube from ``start_mm`` to ``end_mm`` (base
    frame, arm at its zero configuration) of one material and a cross-section of area
    ``area_m2`` and outer perimeter ``perimeter_m``."""

    name: str
    start_mm: tuple[float, float, float]
    end_mm: tuple[float, float, float]
    area_m2: float
    perimeter_m: float
    conductivity_w_per_mk: float
    density_kg_per_m3: float
    specific_heat_j_per_kgk: float
    alpha_per_c: float
    emissivity: float = 0.9
    h_w_per_m2k: float = DEFAULT_H_W_PER_M2K
    thermal_length_mm: float | None = None  # the metal's length if not start-to-end
    #: the link's whole mass when known (flanges, housings, covers: more than the tube);
    #: its heat capacity is then ``mass c`` spread along the link, else the tube's.
    mass_kg: float | None = None
    #: for a model that resolves the temperature across links (``across_link=True``): the
    #: section's size along ``across_axis`` (a unit vector across the link, base frame at the
    #: zero configuration; default: the "up" side), its wall (0: solid), and that axis's
    #: components along the y and z axes of the frame ``kinematics.warm_arm`` bends the link
    #: in (default: the base frame's).
    thickness_mm: float = 0.0
    wall_mm: float = 0.0
    across_axis: tuple[float, float, float] | None = None
    across_yz: tuple[float, float] | None = None

    def across(self) -> FloatArray:
        """The unit vector across the link that separates its two rows of nodes."""
        along = np.subtract(self.end_mm, self.start_mm).astype(np.float64)
        norm = float(np.linalg.norm(along))
        along = along / norm if norm > 0.0 else np.array([1.0, 0.0, 0.0])
        candidates = [self.across_axis] if self.across_axis is not None else []
        candidates += [(0.0, 0.0, 1.0), (1.0, 0.0, 0.0)]
        for candidate in candidates:
            vector = np.asarray(candidate, dtype=np.float64)
            vector = vector - float(vector @ along) * along
            size = float(np.linalg.norm(vector))
            if size > 1e-6:
                result: FloatArray = vector / size
                return result
        raise ValueError(f"link {self.name!r}: no axis across it")

    def heat_capacity_per_mm(self, length_mm: float) -> float:
        """J/°C per mm of link: the tube's, or the whole mass's if that is more."""
        tube = self.density_kg_per_m3 * self.area_m2 * MM
        per_mm = tube if self.mass_kg is None else max(tube, self.mass_kg / length_mm)
        return per_mm * self.specific_heat_j_per_kgk

    @property
    def length_mm(self) -> float:
        if self.thermal_length_mm is not None:
            return self.thermal_length_mm
        return float(np.linalg.norm(np.subtract(self.end_mm, self.start_mm)))


@dataclass(frozen=True, slots=True)
class JointBody:
    """A joint's motor and gearbox: its heat capacity, its surface to ambient (W/°C), the
    resistance across its flange to the proximal link (or the base) and to the distal link,
    and the link its housing is mounted on (``None``: the proximal one). The housing side is
    bolted (a contact resistance); the other side is reached through the bearings and the
    output shaft (:func:`describe_arm` makes it :data:`DEFAULT_BEARING_R_C_PER_W`)."""

    name: str
    capacitance_j_per_c: float = DEFAULT_JOINT_MASS_KG * JOINT_SPECIFIC_HEAT_J_PER_KGK
    ambient_conductance_w_per_c: float = DEFAULT_H_W_PER_M2K * DEFAULT_JOINT_AREA_M2
    proximal_r_c_per_w: float = DEFAULT_CONTACT_R_C_PER_W
    distal_r_c_per_w: float = DEFAULT_CONTACT_R_C_PER_W
    link: str | None = None
    #: with ``across_link``: the share of each flange's conductance that reaches the links'
    #: "+" row (the housing's side); 0.5 heats both sides alike (no gradient).
    plus_share: float = 0.5


@dataclass(frozen=True, slots=True)
class ArmThermalDescription:
    """Everything the thermal model needs of an arm: its links (base to tool), one joint before
    each link, and the base (capacitance, resistance to ambient)."""

    name: str
    links: tuple[LinkBody, ...]
    joints: tuple[JointBody, ...]
    base_capacitance_j_per_c: float = DEFAULT_BASE_MASS_KG * BASE_SPECIFIC_HEAT_J_PER_KGK
    base_r_ambient_c_per_w: float = DEFAULT_BASE_R_AMBIENT_C_PER_W

    def __post_init__(self) -> None:
        if not self.links:
            raise ValueError(f"arm {self.name!r}: no links")
        if len(self.joints) != len(self.links):
            raise ValueError(
                f"arm {self.name!r}: {len(self.joints)} joints for {len(self.links)} links "
                "(one joint before each link)"
            )


def tube_section(outer_mm: float, wall_mm: float) -> tuple[float, float]:
    """(area m^2, outer perimeter m) of a round tube; ``wall_mm >= outer_mm / 2`` is solid."""
    if not (outer_mm > 0.0 and wall_mm > 0.0):
        raise ValueError(f"section: outer size {outer_mm} and wall {wall_mm} mm must be > 0")
    inner = max(0.0, outer_mm - 2.0 * wall_mm)
    area = math.pi / 4.0 * (outer_mm**2 - inner**2) * MM * MM
    return area, math.pi * outer_mm * MM


def radiation_h_w_per_m2k(emissivity: float, ambient_c: float) -> float:
    """Linearised radiation coefficient ``4 eps sigma T^3`` (W/m^2K) at ambient."""
    return 4.0 * emissivity * STEFAN_BOLTZMANN * (ambient_c + KELVIN) ** 3


@dataclass(frozen=True, slots=True)
class _Layout:
    """Where each link's and joint's nodes are in the network."""

    link_nodes: tuple[IntArray, ...]  # indices of each link's nodes
    link_lengths: tuple[FloatArray, ...]  # the length each of those nodes stands for (mm)
    joint_nodes: IntArray  # index of each joint's node
    base_node: int
    #: with ``across_link``: each link's "+" and "-" row (indices), else empty
    plus_rows: tuple[IntArray, ...] = ()
    minus_rows: tuple[IntArray, ...] = ()


def _flange(
    resistances: list[Resistance], joint: int, rows: Sequence[int], r: float, share: float
) -> None:
    """Join a joint's node to a link end: one node, or the "+" / "-" pair splitting the
    flange's conductance ``1/r`` by ``share`` (parallel: still ``r`` in all)."""
    if len(rows) == 1:
        resistances.append(Resistance(joint, rows[0], r))
        return
    for row, part in zip(rows, (share, 1.0 - share), strict=True):
        if part > 0.0:
            resistances.append(Resistance(joint, row, r / part))


def build_arm_network(
    description: ArmThermalDescription,
    node_spacing_mm: float = DEFAULT_NODE_SPACING_MM,
    *,
    convection_scale: float = 1.0,
    ambient_c: float = 22.0,
    across_link: bool = False,
) -> tuple[ThermalNetwork, _Layout]:
    """The arm's chain network (module docstring) and where its parts are in it.

    ``across_link`` resolves the temperature across each link: two rows of nodes, the halves
    of the section on either side of ``LinkBody.across()`` ("+" and "-"; each with half the
    heat capacity, conduction area and surface), joined across by conduction through the
    section's side walls (path half the thickness, area ``2 wall dx``, or ``thickness dx``
    when solid); a joint's flanges reach the "+" row with ``plus_share`` of their
    conductance. With ``plus_share = 0.5`` both rows stay equal and the model is the chain.
    """
    if not (math.isfinite(node_spacing_mm) and node_spacing_mm > 0.0):
        raise ValueError(f"node spacing must be positive, got {node_spacing_mm} mm")
    names: list[str] = ["base"]
    links_of: list[str] = ["base"]
    arc: list[float] = [0.0]
    spatial: list[FloatArray] = [np.zeros(3)]
    capacitance: list[float] = [description.base_capacitance_j_per_c]
    alpha: list[float] = [description.links[0].alpha_per_c]
    ambient_g: list[float] = [1.0 / description.base_r_ambient_c_per_w]
    resistances: list[Resistance] = []
    link_nodes: list[IntArray] = []
    link_lengths: list[FloatArray] = []
    plus_rows: list[IntArray] = []
    minus_rows: list[IntArray] = []
    joint_nodes: list[int] = []
    previous_end: list[int] = [0]  # the node(s) the next joint's proximal flange touches
    position = 0.0
    for link, joint in zip(description.links, description.joints, strict=True):
        start, end = np.asarray(link.start_mm, np.float64), np.asarray(link.end_mm, np.float64)
        if start.shape != (3,) or end.shape != (3,):
            raise ValueError(f"link {link.name!r}: start and end must be 3-D points")
        if not 0.0 <= joint.plus_share <= 1.0:
            raise ValueError(f"joint {joint.name!r}: plus_share must be in [0, 1]")
        # the joint's node, proximal flange on the previous link (or the base)
        joint_index = len(names)
        names.append(joint.name)
        links_of.append(joint.link or links_of[previous_end[0]])
        arc.append(position)
        spatial.append(start.copy())
        capacitance.append(joint.capacitance_j_per_c)
        alpha.append(link.alpha_per_c)
        ambient_g.append(joint.ambient_conductance_w_per_c * convection_scale)
        _flange(resistances, joint_index, previous_end, joint.proximal_r_c_per_w, joint.plus_share)
        joint_nodes.append(joint_index)
        # the link's nodes, evenly spaced over its (effective) length, both ends included
        length = max(link.length_mm, MIN_LINK_LENGTH_MM)
        intervals = max(1, math.ceil(length / node_spacing_mm - 1e-9))
        count = intervals + 1
        dx = length / intervals
        shares = np.full(count, dx)
        shares[0] = shares[-1] = dx / 2.0
        h = convection_scale * link.h_w_per_m2k + radiation_h_w_per_m2k(link.emissivity, ambient_c)
        sides: tuple[tuple[str, float], ...] = (("", 0.0),)
        if across_link:
            if not link.thickness_mm > 0.0:
                raise ValueError(f"link {link.name!r}: across_link needs its thickness_mm")
            sides = (("+", 1.0), ("-", -1.0))
        fraction = 1.0 / len(sides)
        offset = link.across() * link.thickness_mm / 4.0 if across_link else np.zeros(3)
        first = len(names)
        for k in range(count):
            for suffix, sign in sides:
                names.append(f"{link.name}.{k + 1}{suffix}")
                links_of.append(link.name)
                arc.append(position + k * dx)
                spatial.append(start + (end - start) * (k / intervals) + sign * offset)
                capacitance.append(link.heat_capacity_per_mm(length) * shares[k] * fraction)
                alpha.append(link.alpha_per_c)
                ambient_g.append(h * link.perimeter_m * shares[k] * MM * fraction)
            here = first + k * len(sides)
            if k > 0:
                axial = dx * MM / (link.conductivity_w_per_mk * link.area_m2 * fraction)
                for side in range(len(sides)):
                    resistances.append(Resistance(here - len(sides) + side, here + side, axial))
            if across_link:
                wall = link.wall_mm if link.wall_mm > 0.0 else link.thickness_mm / 2.0
                across_m2 = 2.0 * wall * shares[k] * MM * MM
                resistances.append(
                    Resistance(
                        here,
                        here + 1,
                        link.thickness_mm / 2.0 * MM / (link.conductivity_w_per_mk * across_m2),
                    )
                )
        rows = np.arange(first, first + count * len(sides), dtype=np.intp)
        _flange(resistances, joint_index, rows[: len(sides)].tolist(), joint.distal_r_c_per_w,
                joint.plus_share)  # fmt: skip
        link_nodes.append(rows)
        link_lengths.append(np.repeat(shares, len(sides)) * fraction)
        if across_link:
            plus_rows.append(rows[0::2])
            minus_rows.append(rows[1::2])
        previous_end = rows[-len(sides) :].tolist()
        position += length
    network = ThermalNetwork(
        name=f"{description.name}-arm({node_spacing_mm:g} mm{', across' if across_link else ''})",
        node_names=tuple(names),
        positions_mm=np.array(arc),
        capacitance_j_per_c=np.array(capacitance),
        alpha_per_c=np.array(alpha),
        r_ambient_c_per_w=1.0 / np.array(ambient_g),
        r_end_c_per_w=np.full(len(names), math.inf),
        resistances=tuple(resistances),
        reference_nodes=(names[0], names[-1]),
        heater_nodes=tuple(names[i] for i in joint_nodes),
        description=f"Thermal network of arm {description.name!r} (issue 20).",
        node_links=tuple(links_of),
        positions_3d_mm=np.array(spatial),
    )
    layout = _Layout(
        link_nodes=tuple(link_nodes),
        link_lengths=tuple(link_lengths),
        joint_nodes=np.array(joint_nodes, dtype=np.intp),
        base_node=0,
        plus_rows=tuple(plus_rows),
        minus_rows=tuple(minus_rows),
    )
    return network, layout


def describe_arm(
    arm: Arm,
    *,
    contact_r_c_per_w: float = DEFAULT_CONTACT_R_C_PER_W,
    bearing_r_c_per_w: float = DEFAULT_BEARING_R_C_PER_W,
    joint_capacitance_j_per_c: float = DEFAULT_JOINT_MASS_KG * JOINT_SPECIFIC_HEAT_J_PER_KGK,
    joint_area_m2: float = DEFAULT_JOINT_AREA_M2,
    base_capacitance_j_per_c: float = DEFAULT_BASE_MASS_KG * BASE_SPECIFIC_HEAT_J_PER_KGK,
    base_r_ambient_c_per_w: float = DEFAULT_BASE_R_AMBIENT_C_PER_W,
    plus_share: float = 0.5,
) -> ArmThermalDescription:
    """The thermal description of an arm file (kinematics + link materials and sections +
    motors). Link ``i`` spans the geometry of the joints whose lengths grow with it
    (``Arm.grows_with``), from the first one's frame origin to the last one's end, at the zero
    configuration, over ``Arm.link_length_mm``; a link that holds no length (a wrist) is a
    short lump at its frame's origin. A link's heat capacity is its whole ``mass_kg`` (the
    arm file's, with flanges and covers) when that exceeds its tube's. Each joint's housing
    sits on its motor's ``heats_link`` (bolted: ``contact_r_c_per_w``); its other flange is
    reached through the bearings (``bearing_r_c_per_w``). The joint, base and contact values
    are estimates (module constants) that a finer truth model may change; ``plus_share``
    (every joint's) and the links' section height (``thickness_mm``; the rows split across the
    bending frame's y or z, see below) serve a model built with ``across_link``."""
    frames = link_frames(arm, np.zeros(arm.dof))
    origins = [frame[:3, 3] for frame in frames]
    links = []
    for k, link in enumerate(arm.links):
        if link.material is None or link.section is None:
            raise ArmError(
                f"arm {arm.name!r}: link {link.name!r} has no material or section; the thermal "
                "model needs both"
            )
        own = [j for j in range(arm.dof) if arm.grows_with(j) == link.name]
        start = origins[own[0]] if own else origins[k + 1]
        end = origins[own[-1] + 1] if own else origins[k + 1]
        material = link.material
        links.append(
            LinkBody(
                name=link.name,
                start_mm=(float(start[0]), float(start[1]), float(start[2])),
                end_mm=(float(end[0]), float(end[1]), float(end[2])),
                area_m2=link.section.area_mm2 * MM * MM,
                perimeter_m=link.section.perimeter_mm * MM,
                conductivity_w_per_mk=material.conductivity_w_per_mk,
                density_kg_per_m3=material.density_kg_per_m3,
                specific_heat_j_per_kgk=material.specific_heat_j_per_kgk,
                alpha_per_c=material.alpha_per_c,
                emissivity=material.emissivity,
                h_w_per_m2k=material.convection_w_per_m2k,
                thermal_length_mm=arm.link_length_mm(link.name),
                mass_kg=link.mass_kg if link.mass_kg > 0.0 else None,
                thickness_mm=link.section.outer_height_mm,
                wall_mm=link.section.wall_mm,
            )
        )
        # The frame warm_arm bends the link's geometry in (after its first joint's geometry,
        # Arm.geometry_mm, at the zero configuration) carries a gradient along its y and z
        # only: the rows are split across that frame's y or z, whichever is more nearly
        # perpendicular to the link (z on a tie: "up" for most arms' zero pose). A tie is
        # within ACROSS_TIE: a link along its frame's x (a UR's upper arm and forearm) is
        # perpendicular to both, and an arm measured a fraction of a milliradian off that
        # (the bench truth's geometry errors, drivers/sim/arm_physics.py true_arm) must not
        # have its housings' side turned by 90 degrees (it turned the UR truth's bending
        # into y while the model's stayed in z: issue 31).
        bend_frame = frames[own[0] + 1 if own else k + 1][:3, :3]
        along = np.subtract(end, start)
        size = float(np.linalg.norm(along))
        along = along / size if size > 0.0 else bend_frame[:, 0]
        nearer_y = abs(bend_frame[:, 1] @ along) < abs(bend_frame[:, 2] @ along) - ACROSS_TIE
        axis = 1 if nearer_y else 2
        candidate = bend_frame[:, axis]
        links[-1] = dataclasses.replace(
            links[-1], across_axis=(float(candidate[0]), float(candidate[1]), float(candidate[2]))
        )
        across = links[-1].across()
        links[-1] = dataclasses.replace(
            links[-1],
            across_yz=(float(across @ bend_frame[:, 1]), float(across @ bend_frame[:, 2])),
        )
    joints = []
    for j, joint in enumerate(arm.joints):
        proximal = arm.links[j - 1].name if j > 0 else None
        housing = joint.motor.heats_link if joint.motor is not None else proximal
        on_distal = housing == arm.links[j].name
        joints.append(
            JointBody(
                name=joint.name,
                capacitance_j_per_c=joint_capacitance_j_per_c,
                ambient_conductance_w_per_c=DEFAULT_H_W_PER_M2K * joint_area_m2,
                proximal_r_c_per_w=bearing_r_c_per_w if on_distal else contact_r_c_per_w,
                distal_r_c_per_w=contact_r_c_per_w if on_distal else bearing_r_c_per_w,
                link=housing,
                plus_share=plus_share,
            )
        )
    return ArmThermalDescription(
        arm.name,
        tuple(links),
        tuple(joints),
        base_capacitance_j_per_c=base_capacitance_j_per_c,
        base_r_ambient_c_per_w=base_r_ambient_c_per_w,
    )


__all__ = [
    "DEFAULT_NODE_SPACING_MM",
    "ArmThermalDescription",
    "JointBody",
    "LinkBody",
    "build_arm_network",
    "describe_arm",
    "radiation_h_w_per_m2k",
    "tube_section",
]
