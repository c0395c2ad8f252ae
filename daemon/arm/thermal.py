"""The arm's temperatures over time (issue 20): :class:`ArmThermalModel` steps the network of
:mod:`daemon.arm.arm_network` (links as RC chains, joints as heat sources, the base's path to
ambient) with the joints' heat and a varying ambient, and gives each link's thermal state for
``kinematics.warm_arm``.

The network is a chain (two rows per link with ``across_link``), so
:class:`~daemon.model.model.ThermalModel` steps it exactly (zero-order hold through its matrix
exponential or modes): an 8-hour run at 1 s of a ~100-node arm takes about a second.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
from numpy.typing import ArrayLike

from daemon.arm.arm_network import (
    DEFAULT_NODE_SPACING_MM,
    ArmThermalDescription,
    IntArray,
    JointBody,
    LinkBody,
    build_arm_network,
    describe_arm,
    radiation_h_w_per_m2k,
    tube_section,
)
from daemon.arm.description import Arm
from daemon.arm.kinematics import link_frames
from daemon.arm.types import FloatArray, LinkThermalState
from daemon.model.model import ModelError, Stepper, ThermalModel
from daemon.model.network import steady_state_c

AmbientInput = float | Callable[[float], float]
#: A link's two faces when the model resolves the temperature across it: "plus" carries the
#: motor housings (arm_network's plus_share side), "minus" is the opposite face.
FACES = ("plus", "minus")


class ArmThermalModel:
    """The arm's temperatures over time, from its joints' heat and a varying ambient.

    ``ArmThermalModel(arm)`` builds the network from an :class:`~daemon.arm.description.Arm`
    (or an :class:`ArmThermalDescription`). ``ambient_c`` is a temperature or a schedule
    ``t_s -> °C`` (sampled at the start of each step and held over it). Every node starts at
    ambient; ``reference_c`` (default: the initial temperatures) is where the links have
    their cold, kinematic length. ``node_spacing_mm`` sets the discretisation (finer for a
    truth), ``convection_scale`` multiplies every surface's convection, ``across_link``
    resolves the temperature across the links (their gradient, for bending).
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
        across_link: bool = False,
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
        self.across_link = across_link
        self.node_spacing_mm = float(node_spacing_mm)
        self.convection_scale = float(convection_scale)
        self._stepper: Stepper = stepper
        self.network, self._layout = build_arm_network(
            description,
            node_spacing_mm,
            convection_scale=convection_scale,
            ambient_c=start_c,
            across_link=across_link,
        )
        #: the air the links' radiation is linearised at (arm_network.radiation_h_w_per_m2k)
        self.linearised_at_c = start_c
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

    def start_at(self, ambient_c: float) -> None:
        """Before the first step: every node at ``ambient_c``, which becomes the ambient, the
        links' cold reference (a cold arm in equilibrium with the room it was taught in, the
        room a thermometer reads at the run's start) and the air the links' radiation is
        linearised at (:meth:`_relinearise`)."""
        if self.time_s != 0.0:
            raise ModelError(f"the start temperature is set at time 0, not at {self.time_s} s")
        if not np.isfinite(ambient_c):
            raise ModelError(f"ambient must be finite, got {ambient_c}")
        if float(ambient_c) != self.linearised_at_c:
            self._relinearise(float(ambient_c))
        self._schedule = None
        self._model.set_ambient(float(ambient_c))
        self._model.set_temperatures(float(ambient_c))
        self._reference = self._model.temperatures_c.copy()

    def _relinearise(self, ambient_c: float) -> None:
        """The network again with the links' radiation linearised at ``ambient_c`` (at time
        0: nothing has been stepped). ``4 eps sigma T^3`` at the room the run starts in, not at
        a configured one: the truth's air sets the loss, and 17 degC against 22 is 5 % of the
        radiation, 1.6 % of a link's loss under convection x1.5 -- a bias growing with the
        warm-up (issue 29, cold-draughty-room task B: 1.8 um of the drift with every true
        factor given; identification already linearises at its run's first ambient,
        daemon/arm/response.py)."""
        heat = self._heat
        self.network, self._layout = build_arm_network(
            self.description,
            self.node_spacing_mm,
            convection_scale=self.convection_scale,
            ambient_c=ambient_c,
            across_link=self.across_link,
        )
        self._model = ThermalModel(self.network, self._stepper, self._model.dt_s, ambient_c)
        self.linearised_at_c = ambient_c
        self._heat = np.zeros_like(heat)
        self.set_joint_heat(heat)

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

    def link_face_node_indices(self, link: str | int, face: str | None) -> IntArray:
        """A link's nodes on one face: ``"plus"`` (the motor housings' side, whose heat bends
        the link) or ``"minus"`` (the other), the link's row there when the model resolves
        the temperature across it (``across_link``); both rows otherwise or for ``None``."""
        index = link if isinstance(link, int) else self.link_names.index(link)
        if face is None or not self._layout.plus_rows:
            return self._layout.link_nodes[index]
        if face not in FACES:
            raise ValueError(f"a link's face is one of {FACES}, not {face!r}")
        rows = self._layout.plus_rows if face == "plus" else self._layout.minus_rows
        return rows[index]

    def node_positions_mm(self, q_rad: ArrayLike) -> FloatArray:
        """Every node's 3-D position (mm, base frame) with the arm at ``q_rad``: each node
        rides its link's frame (``kinematics.link_frames``); the base node stays put. Needs
        the model to be built from an Arm."""
        if self.arm is None:
            raise ModelError("node positions at a configuration need the model built from an Arm")

        if self._local is None:
            self._local = self._local_positions(self.arm)
        frames = np.array(link_frames(self.arm, np.asarray(q_rad, dtype=np.float64)))
        frame_of, local = self._local
        moved = np.einsum("nij,nj->ni", frames[frame_of], local)
        result: FloatArray = moved[:, :3]
        return result

    def _local_positions(self, arm: Arm) -> tuple[IntArray, FloatArray]:
        """Each node's frame index and its position in that frame (homogeneous)."""
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
        order of the arm's links, and, when the model resolves it (``across_link``), the mean
        temperature gradient across the link (°C/mm, the difference between its two rows over
        the distance between their centres, half the thickness) in the bending frame's (y, z);
        a chain of nodes does not resolve it: (0, 0)."""
        rise = self._model.temperatures_c - self._reference
        states = []
        for index, (link, nodes, lengths) in enumerate(
            zip(self.description.links, self._layout.link_nodes, self._layout.link_lengths,
                strict=True)
        ):  # fmt: skip
            mean = float(lengths @ rise[nodes] / lengths.sum())
            gradient = (0.0, 0.0)
            if self._layout.plus_rows:
                plus, minus = self._layout.plus_rows[index], self._layout.minus_rows[index]
                weights = lengths[0::2]
                difference = float(weights @ (rise[plus] - rise[minus]) / weights.sum())
                per_mm = difference / (link.thickness_mm / 2.0)
                y, z = link.across_yz if link.across_yz is not None else link.across()[1:]
                gradient = (per_mm * float(y), per_mm * float(z))
            states.append(LinkThermalState(link.name, mean, link.alpha_per_c, gradient))
        return tuple(states)

    def joint_temperatures_c(self) -> FloatArray:
        result: FloatArray = self._model.temperatures_c[self._layout.joint_nodes]
        return result


def steady_link_rise_c(
    description: ArmThermalDescription,
    joint_heat_w: ArrayLike,
    node_spacing_mm: float = DEFAULT_NODE_SPACING_MM,
    ambient_c: float = 22.0,
) -> Mapping[str, float]:
    """Each link's steady mean temperature rise for constant joint heats (a direct solve)."""
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
    "DEFAULT_NODE_SPACING_MM",
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
