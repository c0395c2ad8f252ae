"""The arm model's outputs on a calibration cycle's measurements, for a fast identification
(issue 29): only what the fit compares, each link's mean rise, its gradient across, each IR
region's mean, per input (each joint's heat, the ambient), for one set of the network's
factors (convection, the joints' capacity, the bending shares).

Between changes of those factors the model is linear and time-invariant: the node temperatures
are ``T_k = sum_j h_j R_j,k + R_amb,k`` (daemon/arm/response.py), so a change of a heat factor,
of alpha or of an IR offset needs no new simulation (their derivatives are the responses
themselves), and a change of a network factor needs ONE pass of the network's modes (an
eigendecomposition of an N x N matrix and a recursion over the heat grid). The outputs are
projected through the modes (``W = O C^-1/2 V``, P outputs x N modes) before the states are
kept, so a pass stores P, not N, numbers per input and measurement. daemon/arm/response.py's
:func:`~daemon.arm.response.responses` is the node-by-node form of the same solution (and the
oracle of this one in the tests).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from daemon.arm.arm_network import ArmThermalDescription, IntArray, build_arm_network
from daemon.arm.response import ArmRunData
from daemon.arm.types import FloatArray
from daemon.model.model import NetworkModes


@dataclass(frozen=True)
class NetworkFactors:
    """The factors that change the network: convection (every surface), the joints' heat
    capacity, and each joint's bending share (None: the description's)."""

    convection: float = 1.0
    capacity: float = 1.0
    shares: tuple[float, ...] | None = None


def factored_description(
    description: ArmThermalDescription, capacity: float, shares: Sequence[float] | None
) -> ArmThermalDescription:
    """``description`` with every joint's capacity times ``capacity`` and its bending share
    ``shares[j]`` (unchanged for None)."""
    if capacity == 1.0 and shares is None:
        return description
    joints = tuple(
        dataclasses.replace(
            joint,
            capacitance_j_per_c=joint.capacitance_j_per_c * capacity,
            plus_share=joint.plus_share if shares is None else float(shares[j]),
        )
        for j, joint in enumerate(description.joints)
    )
    return dataclasses.replace(description, joints=joints)


@dataclass(frozen=True)
class OutputResponses:
    """The outputs at each measurement per input: ``per_input[c]`` (K x P) for 1 W in joint
    c (c < J) and, last, the ambient's part; P = L link mean rises (above the run's starting
    ambient), then with ``across_link`` 2L gradients (degC/mm, y1, z1, y2, ...), then R IR
    region means (degC, absolute in the ambient's part)."""

    per_input: FloatArray  # (J+1) x K x P
    links: int
    gradients: bool
    regions: tuple[str, ...]

    @property
    def link_means(self) -> FloatArray:
        return self.per_input[:, :, : self.links]

    @property
    def link_gradients(self) -> FloatArray | None:
        if not self.gradients:
            return None
        return self.per_input[:, :, self.links : 3 * self.links]

    @property
    def region_means(self) -> FloatArray:
        start = 3 * self.links if self.gradients else self.links
        return self.per_input[:, :, start:]


def output_rows(
    description: ArmThermalDescription,
    regions: Mapping[str, Sequence[int]],
    *,
    across_link: bool,
    node_count: int,
    layout_links: Sequence[IntArray],
    layout_lengths: Sequence[FloatArray],
    plus_rows: Sequence[IntArray],
    minus_rows: Sequence[IntArray],
) -> FloatArray:
    """The outputs as weights over the nodes (P x N), as ArmThermalModel.link_states and the
    IR regions compute them."""
    rows = []
    for nodes, lengths in zip(layout_links, layout_lengths, strict=True):
        row = np.zeros(node_count)
        row[np.asarray(nodes, dtype=np.intp)] = lengths / lengths.sum()
        rows.append(row)
    if across_link:
        for link, body in enumerate(description.links):
            weights = layout_lengths[link][0::2]
            difference = np.zeros(node_count)
            difference[np.asarray(plus_rows[link], np.intp)] += weights / weights.sum()
            difference[np.asarray(minus_rows[link], np.intp)] -= weights / weights.sum()
            per_mm = difference / (body.thickness_mm / 2.0)
            across = body.across_yz if body.across_yz is not None else body.across()[1:]
            rows += [per_mm * float(across[0]), per_mm * float(across[1])]
    for covered in regions.values():
        row = np.zeros(node_count)
        row[list(covered)] = 1.0 / len(covered)
        rows.append(row)
    return np.array(rows)


def output_responses(
    description: ArmThermalDescription,
    node_spacing_mm: float,
    factors: NetworkFactors,
    run: ArmRunData,
    regions: Mapping[str, Sequence[int]],
    *,
    across_link: bool = False,
) -> OutputResponses:
    """Every input's outputs at the run's measurements for the network of ``factors``
    (module docstring)."""
    network, layout = build_arm_network(
        factored_description(description, factors.capacity, factors.shares),
        node_spacing_mm,
        convection_scale=factors.convection,
        ambient_c=float(run.ambient_c[0]),
        across_link=across_link,
    )
    modes = NetworkModes(network)
    rows = output_rows(
        description,
        regions,
        across_link=across_link and bool(layout.plus_rows),
        node_count=network.node_count,
        layout_links=layout.link_nodes,
        layout_lengths=layout.link_lengths,
        plus_rows=layout.plus_rows,
        minus_rows=layout.minus_rows,
    )
    projection = (rows / modes.root_c[None, :]) @ modes.vectors  # P x N(modes)
    dt = run.heat_step_s
    decay = np.exp(-modes.rates * dt)
    gain = -np.expm1(-modes.rates * dt) / modes.rates
    joints = run.joint_heat_w.shape[1]
    channels = np.zeros((network.node_count, joints + 1))
    channels[np.asarray(layout.joint_nodes, dtype=np.intp), np.arange(joints)] = 1.0
    channels[:, joints] = network.ambient_conductance_w_per_c
    driven = gain[:, None] * (modes.vectors.T @ (channels / modes.root_c[:, None]))  # N x (J+1)
    wanted = run.grid_index
    last = int(wanted.max())
    inputs = np.column_stack([run.joint_heat_w, run.ambient_c])[: max(last, 1)]  # S x (J+1)
    start = np.zeros((network.node_count, joints + 1))
    start[:, joints] = modes.vectors.T @ (modes.root_c * float(run.ambient_c[0]))
    # Each mode is a first-order recursion z[k+1] = d z[k] + g f u[k]: SciPy's lfilter runs it
    # in C (one call per mode; a Python loop over the grid was most of a pass).
    kept = np.empty((wanted.size, network.node_count, joints + 1))
    for n in range(network.node_count):
        states = lfilter(
            [1.0], [1.0, -decay[n]], inputs * driven[n], axis=0, zi=decay[n] * start[n][None, :]
        )[0]  # states[k] = z[k+1]
        kept[:, n] = np.where((wanted > 0)[:, None], states[np.maximum(wanted - 1, 0)], start[n])
    outputs = np.moveaxis(np.matmul(projection, kept), 2, 0)  # (J+1) x K x P
    links = len(layout.link_nodes)
    outputs[joints, :, :links] -= float(run.ambient_c[0])  # link means as rises
    return OutputResponses(
        per_input=outputs,
        links=links,
        gradients=across_link and bool(layout.plus_rows),
        regions=tuple(regions),
    )


__all__ = [
    "NetworkFactors",
    "OutputResponses",
    "factored_description",
    "output_responses",
    "output_rows",
]
