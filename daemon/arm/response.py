"""What the controller's arm model predicts a calibration cycle measures (issue 20), for
:mod:`daemon.arm.identify`: the cycle's data, the model's make-up, every input's response at
once and the markers' sensitivity to each link's strain and bend.

The arm's network is linear: for a given convection its node temperatures are a sum of one
response per joint (times its heat factor) plus the response to ambient, computed in one pass
of the network's modes (the exact zero-order hold of :class:`daemon.model.model.NetworkModes`)
over the run's heat grid. A link's growth is tiny, so the tool's error is linear in the links'
strains ``alpha * mean rise`` and bends ``alpha * gradient`` (:func:`marker_sensitivity`, from
``kinematics.tool_error`` of the nominal arm).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from daemon.arm import kinematics
from daemon.arm.description import Arm
from daemon.arm.thermal import ArmThermalDescription, build_arm_network
from daemon.arm.types import FloatArray, LinkThermalState
from daemon.model.identify import IdentificationError
from daemon.model.model import NetworkModes

IntArray = NDArray[np.intp]

#: The strain used to read the tool's sensitivity off ``tool_error`` (dimensionless): the size
#: of a warm link's (23e-6 /K x 5 K ~ 1e-4), small enough that the response is linear.
SENSITIVITY_STRAIN = 1e-4


# -- data ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ArmRunData:
    """A calibration cycle as identification sees it.

    ``joint_heat_w`` (S x J): the heat the controller's motor model predicts for each joint,
    mean over each step ``[k dt, (k+1) dt)`` of ``heat_step_s``, from the commanded motion;
    ``ambient_c`` (S,): the air's temperature over each step. Measurements at ``time_s`` (K,
    on the heat grid, from a cold start at ambient): ``pose_index`` (K,) says which measured
    pose, ``marker_displacement_mm`` (K x M x 3) the markers' measured positions minus their
    cold positions at that pose (NaN where missing), ``region_c`` each IR region's mean
    (K,), NaN where missing.

    ``reference_fitted``: the displacements are relative to a pose's reference MEASUREMENT
    (one camera measurement, noisy like any other), not to its true cold pose: the fit then
    takes each pose's reference error as unknown (a constant per pose and axis, projected out
    of the tool's residuals, daemon/arm/identify.py). Taken as exact, that one error is in
    every later sample of its pose, and the fit reads its part along the drift as a scale:
    on the UR5e's followed runs it put alpha 1.3-2.5 % high (1.002-1.082 on five noise seeds of
    one 2-h run, 2-9 of its own standard errors either way; 1.050-1.054 with it fitted)."""

    heat_step_s: float
    joint_heat_w: FloatArray
    ambient_c: FloatArray
    time_s: FloatArray
    pose_index: IntArray
    marker_displacement_mm: FloatArray
    region_c: Mapping[str, FloatArray]
    name: str = "calibration cycle"
    reference_fitted: bool = False

    def __post_init__(self) -> None:
        steps, _ = self.joint_heat_w.shape
        if self.ambient_c.shape != (steps,):
            raise IdentificationError(f"{self.name}: one ambient per heat step")
        count = self.time_s.size
        if count < 2 or self.pose_index.shape != (count,):
            raise IdentificationError(f"{self.name}: needs two or more measurements, one pose each")
        if self.marker_displacement_mm.shape[0] != count:
            raise IdentificationError(f"{self.name}: one marker set per measurement")
        for region, values in self.region_c.items():
            if values.shape != (count,):
                raise IdentificationError(f"{self.name}: region {region!r} has the wrong length")
        if np.any(self.time_s < 0) or np.any(self.time_s > steps * self.heat_step_s + 1e-6):
            raise IdentificationError(f"{self.name}: a measurement lies outside the heat record")

    @property
    def grid_index(self) -> IntArray:
        """Each measurement's index on the heat grid (0 = the start)."""
        return np.asarray(np.rint(self.time_s / self.heat_step_s), dtype=np.intp)


class PoseReferences:
    """Each measured pose's reference error as an unknown of the fit, when ``run`` says its
    displacements are relative to a reference measurement (ArmRunData.reference_fitted): one
    constant per pose and axis, eliminated by taking the tool's residuals (and so their
    derivatives: variable projection) relative to their mean over that pose's samples.
    ``mask`` (K x 3M): the samples measured."""

    def __init__(self, run: ArmRunData, mask: NDArray[np.bool_]) -> None:
        self.mask = mask
        poses = np.unique(run.pose_index) if run.reference_fitted else np.zeros(0, np.intp)
        self.rows = [rows for p in poses if (rows := run.pose_index == p).any()]

    @property
    def count(self) -> int:
        """The constants eliminated (a pose and axis with a sample): degrees of freedom lost."""
        return sum(int(self.mask[rows].any(axis=0).sum()) for rows in self.rows)

    def centred(self, values: FloatArray) -> FloatArray:
        """``values`` (K x 3M) less their mean over the measured samples of each pose and
        axis; unchanged when the references are exact."""
        if not self.rows:
            return values
        out = values.copy()
        for rows in self.rows:
            mask, block = self.mask[rows], out[rows]
            mean = np.where(mask, block, 0.0).sum(axis=0) / np.maximum(mask.sum(axis=0), 1)
            out[rows] = block - mean
        return out


@dataclass(frozen=True)
class ArmModelSpec:
    """The controller's arm model as identification sees it: its thermal description and node
    spacing, which node(s) each IR region covers, and for each measured pose the markers'
    displacement (M*3, flattened x, y, z per marker) per unit strain of each link, and with
    ``across_link`` per unit ``alpha * gradient`` across it (:func:`marker_sensitivity`)."""

    description: ArmThermalDescription
    node_spacing_mm: float
    regions: Mapping[str, Sequence[int]]
    sensitivities: Sequence[FloatArray]
    #: two rows of nodes per link and their bending (sensitivities then have 3 columns per
    #: link: strain, then alpha times the gradient across it in y and z)
    across_link: bool = False


def marker_sensitivity(
    arm: Arm, q_rad: FloatArray, markers_tool_mm: FloatArray, bending: bool = False
) -> FloatArray:
    """The markers' displacement (M*3) per unit strain of each link (one column per link, the
    arm's link order) at ``q_rad``; with ``bending`` three columns per link: strain, then
    ``alpha * gradient`` across it in y and in z (per mm). ``kinematics.tool_error`` with one
    link strained (or bent) by SENSITIVITY_STRAIN, the markers moved by the error's
    translation and rotation: the error is linear in both at these sizes."""
    cold = np.asarray(kinematics.forward(arm, q_rad), dtype=np.float64)
    lever = markers_tool_mm @ cold[:3, :3].T  # each marker from the tool point, world axes
    names = arm.link_names
    cases: list[tuple[str, float, tuple[float, float]]] = []
    for name in names:
        cases.append((name, 1.0, (0.0, 0.0)))
        if bending:
            cases += [(name, 0.0, (1.0, 0.0)), (name, 0.0, (0.0, 1.0))]
    columns = []
    for strained, rise, gradient in cases:
        states = [
            LinkThermalState(
                name,
                rise if name == strained else 0.0,
                SENSITIVITY_STRAIN,
                gradient if name == strained else (0.0, 0.0),
            )
            for name in names
        ]
        error = kinematics.tool_error(arm, q_rad, states, bending=bending)
        moved = error.translation_mm + np.cross(error.rotation_rad, lever)
        columns.append(moved.reshape(-1) / SENSITIVITY_STRAIN)
    return np.column_stack(columns)


# -- the forward model ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Responses:
    """Node temperatures on the measurements' grid points: ``per_joint[j]`` (K x N) for 1 W in
    joint j (at its predicted profile), ``ambient`` (K x N) from the ambient alone, and what
    the links' mean rises are made of (``link_rows``: L x N, weights of each link's mean)."""

    per_joint: FloatArray  # J x K x N
    ambient: FloatArray  # K x N
    link_rows: FloatArray  # L x N
    reference_c: float
    #: with ``across_link``: each link's gradient across it (°C/mm, y then z) as weights over
    #: the nodes (2L x N, rows y1, z1, y2, z2, ...), as ArmThermalModel.link_states computes it
    gradient_rows: FloatArray | None = None


def responses(
    description: ArmThermalDescription,
    node_spacing_mm: float,
    convection_scale: float,
    run: ArmRunData,
    across_link: bool = False,
) -> Responses:
    """The network's response to each input, on the run's grid (module docstring)."""
    network, layout = build_arm_network(
        description,
        node_spacing_mm,
        convection_scale=convection_scale,
        ambient_c=float(run.ambient_c[0]),
        across_link=across_link,
    )
    modes = NetworkModes(network)
    dt = run.heat_step_s
    decay = np.exp(-modes.rates * dt)
    gain = -np.expm1(-modes.rates * dt) / modes.rates
    joints = run.joint_heat_w.shape[1]
    joint_nodes = np.asarray(layout.joint_nodes, dtype=np.intp)
    # modal forcing per unit input: each joint's heat, and the ambient through g_amb
    channels = np.zeros((network.node_count, joints + 1))
    channels[joint_nodes, np.arange(joints)] = 1.0
    channels[:, joints] = network.ambient_conductance_w_per_c
    forcing = modes.vectors.T @ (channels / modes.root_c[:, None])  # N x (J+1)
    inputs = np.column_stack([run.joint_heat_w, run.ambient_c])  # S x (J+1)
    wanted = run.grid_index
    last = int(wanted.max())
    z = np.zeros((network.node_count, joints + 1))
    start = np.full(network.node_count, float(run.ambient_c[0]))
    z[:, joints] = modes.vectors.T @ (modes.root_c * start)
    states = np.empty((last + 1, network.node_count, joints + 1))
    states[0] = z
    for k in range(last):
        z = decay[:, None] * z + gain[:, None] * forcing * inputs[k][None, :]
        states[k + 1] = z
    chosen = states[wanted]  # K x N(modes) x (J+1)
    temperatures = np.einsum("nm,kmc->ckn", modes.vectors, chosen) / modes.root_c
    rows = np.zeros((len(layout.link_nodes), network.node_count))
    for link, (nodes, lengths) in enumerate(
        zip(layout.link_nodes, layout.link_lengths, strict=True)
    ):
        rows[link, np.asarray(nodes, dtype=np.intp)] = lengths / lengths.sum()
    gradient_rows = None
    if across_link and layout.plus_rows:
        gradient_rows = np.zeros((2 * len(layout.link_nodes), network.node_count))
        for link, body in enumerate(description.links):
            weights = layout.link_lengths[link][0::2]
            difference = np.zeros(network.node_count)
            difference[layout.plus_rows[link]] += weights / weights.sum()
            difference[layout.minus_rows[link]] -= weights / weights.sum()
            per_mm = difference / (body.thickness_mm / 2.0)
            across = body.across_yz if body.across_yz is not None else body.across()[1:]
            gradient_rows[2 * link] = per_mm * float(across[0])
            gradient_rows[2 * link + 1] = per_mm * float(across[1])
    return Responses(
        per_joint=temperatures[:joints],
        ambient=temperatures[joints],
        link_rows=rows,
        reference_c=float(run.ambient_c[0]),
        gradient_rows=gradient_rows,
    )


__all__ = [
    "SENSITIVITY_STRAIN",
    "ArmModelSpec",
    "ArmRunData",
    "IntArray",
    "PoseReferences",
    "Responses",
    "marker_sensitivity",
    "responses",
]
