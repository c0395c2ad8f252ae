"""The arm's thermal network (issue 20): every link an RC chain along its geometry, the joints'
motors and gearboxes as heat sources between links, a path through the base to ambient.

Thesis 5.4 generalised from one bar to a serial arm. Each link is a tube of its material and
cross-section, from the origin of its proximal joint frame to that of its distal one (the
straight segment whose length ``warm_arm`` scales by ``1 + alpha dT``), cut into nodes at most
``node_spacing_mm`` apart. Between neighbouring nodes ``R = dx / (k A)``; each node has
``C = rho c A l`` and loses heat to ambient through ``R_inf = 1 / (h_eff P l)`` with
``h_eff = h + 4 eps sigma T_amb^3`` (convection plus linearised radiation, Incropera,
*Fundamentals of Heat and Mass Transfer*, Eq. 1.9). Joint ``j`` is one node (its motor and
gearbox housing: capacitance from its mass, its own surface to ambient) joined by a contact
resistance to the last node of link ``j-1`` (or the base) and to the first node of link
``j``; the base is one node of the base casting with a path to ambient (its own surface and
the mounting table). The network is a chain, so :class:`~daemon.model.model.ThermalModel`
steps it exactly (zero-order hold, its matrix exponential or modes); every node carries its
link and 3-D position (the arm at its zero configuration).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from daemon.arm.description import Arm
from daemon.arm.types import FloatArray, LinkThermalState
from daemon.model.model import ModelError, Stepper, ThermalModel
from daemon.model.network import Resistance, ThermalNetwork

MM = 1e-3  # m per mm
#: Stefan-Boltzmann constant (W/m^2K^4), CODATA 2018.
STEFAN_BOLTZMANN = 5.670374419e-8
KELVIN = 273.15
IntArray = NDArray[np.intp]
#: Default node spacing along a link; the bench's truth uses a finer one.
DEFAULT_NODE_SPACING_MM = 50.0
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


def build_arm_network(
    description: ArmThermalDescription,
    node_spacing_mm: float = DEFAULT_NODE_SPACING_MM,
    *,
    convection_scale: float = 1.0,
    ambient_c: float = 22.0,
) -> tuple[ThermalNetwork, _Layout]:
    """The arm's chain network (module docstring) and where its parts are in it."""
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
    joint_nodes: list[int] = []
    previous_last = 0  # the node the next joint's proximal flange touches
    position = 0.0
    for link, joint in zip(description.links, description.joints, strict=True):
        start, end = np.asarray(link.start_mm, np.float64), np.asarray(link.end_mm, np.float64)
        if start.shape != (3,) or end.shape != (3,):
            raise ValueError(f"link {link.name!r}: start and end must be 3-D points")
        # the joint's node, proximal flange on the previous link (or the base)
        joint_index = len(names)
        names.append(joint.name)
        links_of.append(joint.link or links_of[previous_last])
        arc.append(position)
        spatial.append(start.copy())
        capacitance.append(joint.capacitance_j_per_c)
        alpha.append(link.alpha_per_c)
        ambient_g.append(joint.ambient_conductance_w_per_c * convection_scale)
        resistances.append(Resistance(previous_last, joint_index, joint.proximal_r_c_per_w))
        joint_nodes.append(joint_index)
        # the link's nodes, evenly spaced over its (effective) length, both ends included
        length = max(link.length_mm, MIN_LINK_LENGTH_MM)
        intervals = max(1, math.ceil(length / node_spacing_mm - 1e-9))
        count = intervals + 1
        dx = length / intervals
        shares = np.full(count, dx)
        shares[0] = shares[-1] = dx / 2.0
        h = convection_scale * link.h_w_per_m2k + radiation_h_w_per_m2k(link.emissivity, ambient_c)
        first = len(names)
        for k in range(count):
            names.append(f"{link.name}.{k + 1}")
            links_of.append(link.name)
            arc.append(position + k * dx)
            spatial.append(start + (end - start) * (k / intervals))
            part_m = shares[k] * MM
            capacitance.append(link.heat_capacity_per_mm(length) * shares[k])
            alpha.append(link.alpha_per_c)
            ambient_g.append(h * link.perimeter_m * part_m)
            if k > 0:
                resistances.append(
                    Resistance(
                        first + k - 1,
                        first + k,
                        dx * MM / (link.conductivity_w_per_mk * link.area_m2),
                    )
                )
        resistances.append(Resistance(joint_index, first, joint.distal_r_c_per_w))
        link_nodes.append(np.arange(first, first + count, dtype=np.intp))
        link_lengths.append(shares)
        previous_last = first + count - 1
        position += length
    network = ThermalNetwork(
        name=f"{description.name}-arm({node_spacing_mm:g} mm)",
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
    )
    return network, layout


AmbientInput = float | Callable[[float], float]


class ArmThermalModel:
    """The arm's temperatures over time, from its joints' heat and a varying ambient.

    ``ArmThermalModel(arm)`` builds the network from an :class:`~daemon.arm.description.Arm`
    (or an :class:`ArmThermalDescription`). ``ambient_c`` is a temperature or a schedule
    ``t_s -> °C`` (sampled at the start of each step and held over it). Every node starts at
    ambient; ``reference_c`` (default: the initial temperatures) is where the links have
    their cold, kinematic length.
    """

    def __init__(
        self,
        arm: Arm | ArmThermalDescription,
        *,
        node_spacing_mm: float = DEFAULT_NODE_SPACING_MM,
        ambient_c: AmbientInput = 22.0,
        dt_s: float = 1.0,
        stepper: Stepper = "exact",
        convection_scale: float = 1.0,
        reference_c: float | ArrayLike | None = None,
        initial_c: float | ArrayLike | None = None,
    ) -> None:
        description = arm if isinstance(arm, ArmThermalDescription) else describe_arm(arm)
        self.description = description
        self.arm = None if isinstance(arm, ArmThermalDescription) else arm
        self._schedule: Callable[[float], float] | None = None
        if callable(ambient_c):
            self._schedule = ambient_c
            start_c = float(ambient_c(0.0))
        else:
            start_c = float(ambient_c)
        self.network, self._layout = build_arm_network(
            description, node_spacing_mm, convection_scale=convection_scale, ambient_c=start_c
        )
        self.node_spacing_mm = float(node_spacing_mm)
        self._model = ThermalModel(
            self.network,
            stepper,
            dt_s,
            start_c,
            initial_c=initial_c,
            reference_c=reference_c,
        )
        self._reference = (
            self._model.temperatures_c
            if reference_c is None
            else np.broadcast_to(np.asarray(reference_c, np.float64), (self.network.node_count,))
        )
        self._joint_names = tuple(self.network.node_names[i] for i in self._layout.joint_nodes)
        self._heat = np.zeros(len(self._joint_names))
        self._local: tuple[IntArray, FloatArray] | None = None

    # -- inputs -------------------------------------------------------------------------------

    @property
    def joint_count(self) -> int:
        return len(self._joint_names)

    def set_ambient(self, ambient_c: AmbientInput) -> None:
        """A new ambient temperature (or schedule), from the current time on."""
        if callable(ambient_c):
            self._schedule = ambient_c
            self._model.set_ambient(float(ambient_c(self.time_s)))
        else:
            self._schedule = None
            self._model.set_ambient(float(ambient_c))

    def set_joint_heat(self, joint_heat_w: ArrayLike) -> None:
        """Heat released in each joint (W, one per joint), held from now on."""
        heat = np.asarray(joint_heat_w, dtype=np.float64).reshape(-1)
        if heat.shape != self._heat.shape:
            raise ModelError(f"expected {self.joint_count} joint heats, got {heat.size}")
        if not np.all(np.isfinite(heat)):
            raise ModelError(f"joint heat must be finite, got {heat}")
        if np.array_equal(heat, self._heat):
            return
        self._heat = heat.copy()
        self._model.set_heat(dict(zip(self._joint_names, heat.tolist(), strict=True)))

    def advance_to(self, t_s: float, joint_heat_w: ArrayLike | None = None) -> None:
        """Advance to ``t_s`` with ``joint_heat_w`` (W per joint; default: as before) held
        constant over the interval, and ambient as its schedule gives at the interval's
        start (zero-order hold; exact for piecewise-constant inputs)."""
        if joint_heat_w is not None:
            self.set_joint_heat(joint_heat_w)
        if self._schedule is not None:
            ambient = float(self._schedule(self.time_s))
            if ambient != self._model.ambient_c:
                self._model.set_ambient(ambient)
        self._model.advance_to(t_s)

    # -- state --------------------------------------------------------------------------------

    @property
    def time_s(self) -> float:
        return self._model.time_s

    @property
    def ambient_c(self) -> float:
        return self._model.ambient_c

    @property
    def temperatures_c(self) -> FloatArray:
        return self._model.temperatures_c

    @property
    def node_names(self) -> tuple[str, ...]:
        return self.network.node_names

    @property
    def node_links(self) -> tuple[str, ...]:
        """The link each node belongs to (joint nodes: the link carrying their housing)."""
        return self.network.node_links

    @property
    def link_names(self) -> tuple[str, ...]:
        return tuple(link.name for link in self.description.links)

    @property
    def joint_node_names(self) -> tuple[str, ...]:
        return self._joint_names

    def link_node_indices(self, link: str | int) -> IntArray:
        """Indices (into ``temperatures_c``) of one link's own nodes (joints excluded)."""
        index = link if isinstance(link, int) else self.link_names.index(link)
        return self._layout.link_nodes[index]

    def node_positions_mm(self, q_rad: ArrayLike) -> FloatArray:
        """Every node's 3-D position (mm, base frame) with the arm at ``q_rad``: each node
        rides its link's frame (``kinematics.link_frames``); the base node stays put. Needs
        the model to be built from an Arm."""
        if self.arm is None:
            raise ModelError("node positions at a configuration need the model built from an Arm")
        from daemon.arm.kinematics import link_frames

        if self._local is None:
            self._local = self._local_positions(self.arm)
        frames = np.array(link_frames(self.arm, np.asarray(q_rad, dtype=np.float64)))
        frame_of, local = self._local
        moved = np.einsum("nij,nj->ni", frames[frame_of], local)
        result: FloatArray = moved[:, :3]
        return result

    def _local_positions(self, arm: Arm) -> tuple[IntArray, FloatArray]:
        """Each node's frame index and its position in that frame (homogeneous)."""
        from daemon.arm.kinematics import link_frames

        frames = link_frames(arm, np.zeros(arm.dof))
        index = {name: k + 1 for k, name in enumerate(arm.link_names)}
        frame_of = np.array([index.get(link, 0) for link in self.node_links], dtype=np.intp)
        assert self.network.positions_3d_mm is not None
        points = np.hstack([self.network.positions_3d_mm, np.ones((self.network.node_count, 1))])
        inverse = np.linalg.inv(np.array(frames))
        local = np.einsum("nij,nj->ni", inverse[frame_of], points)
        return frame_of, local

    def set_temperatures(self, temperatures_c: float | ArrayLike) -> None:
        self._model.set_temperatures(temperatures_c)

    @property
    def thermal_model(self) -> ThermalModel:
        """The underlying network model (for observers and identification)."""
        return self._model

    def link_states(self) -> tuple[LinkThermalState, ...]:
        """Each link's mean temperature rise over its length (above ``reference_c``), in the
        order of the arm's links. A chain of nodes does not resolve the temperature across a
        link, so the gradient is (0, 0)."""
        rise = self._model.temperatures_c - self._reference
        states = []
        for link, nodes, lengths in zip(
            self.description.links, self._layout.link_nodes, self._layout.link_lengths,
            strict=True,
        ):  # fmt: skip
            mean = float(lengths @ rise[nodes] / lengths.sum())
            states.append(LinkThermalState(link.name, mean, link.alpha_per_c))
        return tuple(states)

    def joint_temperatures_c(self) -> FloatArray:
        result: FloatArray = self._model.temperatures_c[self._layout.joint_nodes]
        return result


def describe_arm(
    arm: Arm,
    *,
    contact_r_c_per_w: float = DEFAULT_CONTACT_R_C_PER_W,
    bearing_r_c_per_w: float = DEFAULT_BEARING_R_C_PER_W,
    joint_capacitance_j_per_c: float = DEFAULT_JOINT_MASS_KG * JOINT_SPECIFIC_HEAT_J_PER_KGK,
    joint_area_m2: float = DEFAULT_JOINT_AREA_M2,
    base_capacitance_j_per_c: float = DEFAULT_BASE_MASS_KG * BASE_SPECIFIC_HEAT_J_PER_KGK,
    base_r_ambient_c_per_w: float = DEFAULT_BASE_R_AMBIENT_C_PER_W,
) -> ArmThermalDescription:
    """The thermal description of an arm file (kinematics + link materials and sections +
    motors). Link ``i`` spans the geometry of the joints whose lengths grow with it
    (``Arm.grows_with``), from the first one's frame origin to the last one's end, at the zero
    configuration, over ``Arm.link_length_mm``; a link that holds no length (a wrist) is a
    short lump at its frame's origin. A link's heat capacity is its whole ``mass_kg`` (the
    arm file's, with flanges and covers) when that exceeds its tube's. Each joint's housing
    sits on its motor's ``heats_link`` (bolted: ``contact_r_c_per_w``); its other flange is
    reached through the bearings (``bearing_r_c_per_w``). The joint, base and contact values
    are estimates (module constants) that a finer truth model may change."""
    from daemon.arm.description import ArmError
    from daemon.arm.kinematics import link_frames

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
            )
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
            )
        )
    return ArmThermalDescription(
        arm.name,
        tuple(links),
        tuple(joints),
        base_capacitance_j_per_c=base_capacitance_j_per_c,
        base_r_ambient_c_per_w=base_r_ambient_c_per_w,
    )


def steady_link_rise_c(
    description: ArmThermalDescription,
    joint_heat_w: ArrayLike,
    node_spacing_mm: float = DEFAULT_NODE_SPACING_MM,
    ambient_c: float = 22.0,
) -> Mapping[str, float]:
    """Each link's steady mean temperature rise for constant joint heats (a direct solve)."""
    from daemon.model.network import steady_state_c

    network, layout = build_arm_network(description, node_spacing_mm, ambient_c=ambient_c)
    heat = np.zeros(network.node_count)
    heat[layout.joint_nodes] = np.asarray(joint_heat_w, dtype=np.float64)
    rise = steady_state_c(network, heat, 0.0)
    return {
        link.name: float(lengths @ rise[nodes] / lengths.sum())
        for link, nodes, lengths in zip(
            description.links, layout.link_nodes, layout.link_lengths, strict=True
        )
    }


__all__ = [
    "ArmThermalDescription",
    "ArmThermalModel",
    "JointBody",
    "LinkBody",
    "build_arm_network",
    "describe_arm",
    "radiation_h_w_per_m2k",
    "steady_link_rise_c",
    "tube_section",
]
