"""The parameters of a network's identification (issue 9; daemon/model/identify.py fits them):
which groups of the network's values a name scales (``convection``, ``heat``, ``contact``,
``alpha``, ``offset``), their bounds, and the network they make."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from daemon.model.identify_uncertainty import OFFSET_SE_LIMIT_C
from daemon.model.network import FloatArray, NetworkError, ThermalNetwork

ParameterKind = Literal["convection", "heat", "contact", "alpha", "offset"]
PARAMETER_KINDS: tuple[ParameterKind, ...] = ("convection", "heat", "contact", "alpha", "offset")

#: Bounds of a fitted scale factor (its logarithm is fitted) and of an IR offset (degC; the
#: FLIR A40M's accuracy is +-2 degC, thesis 3.2.2).
SCALE_BOUNDS = (0.1, 10.0)
OFFSET_BOUND_C = 5.0


class IdentificationError(ValueError):
    """The run or the parameter list cannot be used for identification."""


@dataclass(frozen=True)
class Parameter:
    """One fitted group: ``kind`` acting on ``targets`` (node indices, or region names)."""

    name: str
    kind: ParameterKind
    targets: tuple[str, ...]
    node_indices: tuple[int, ...] = ()

    @property
    def is_log(self) -> bool:
        return self.kind != "offset"

    @property
    def bounds(self) -> tuple[float, float]:
        if self.is_log:
            return math.log(SCALE_BOUNDS[0]), math.log(SCALE_BOUNDS[1])
        return -OFFSET_BOUND_C, OFFSET_BOUND_C

    @property
    def absolute_se_limit(self) -> float:
        """An offset's largest standard error (degC) to count as identified."""
        return OFFSET_SE_LIMIT_C

    @property
    def unit(self) -> str:
        return " degC"


def default_parameters(network: ThermalNetwork, regions: Mapping[str, Sequence[str]]) -> list[str]:
    """Convection, each heater's heat input, the expansion coefficient and (with IR regions)
    one common IR offset."""
    names = ["convection", *(f"heat:{node}" for node in network.heater_nodes), "alpha"]
    return [*names, "offset"] if regions else names


def parse_parameters(
    specs: Sequence[str],
    network: ThermalNetwork,
    regions: Mapping[str, Sequence[str]],
) -> list[Parameter]:
    """Parameters from their names (module docstring); raises IdentificationError."""
    parsed: list[Parameter] = []
    for spec in specs:
        kind, _, argument = spec.strip().partition(":")
        if kind not in PARAMETER_KINDS:
            raise IdentificationError(
                f"unknown parameter {spec!r}; kinds: {', '.join(PARAMETER_KINDS)}"
            )
        try:
            parsed.append(_parameter(spec.strip(), kind, argument, network, regions))
        except NetworkError as err:
            raise IdentificationError(f"parameter {spec!r}: {err}") from err
    names = [p.name for p in parsed]
    if len(set(names)) != len(names):
        raise IdentificationError(f"a parameter is given twice: {', '.join(names)}")
    if not parsed:
        raise IdentificationError("no parameter to fit")
    return parsed


def _parameter(
    spec: str,
    kind: ParameterKind,
    argument: str,
    network: ThermalNetwork,
    regions: Mapping[str, Sequence[str]],
) -> Parameter:
    every = tuple(range(network.node_count))
    if kind == "offset":
        if not regions:
            raise IdentificationError(f"parameter {spec!r}: the run has no IR region")
        if argument and argument not in regions:
            raise IdentificationError(
                f"parameter {spec!r}: unknown region; regions: {', '.join(regions)}"
            )
        return Parameter(spec, kind, (argument,) if argument else tuple(regions))
    if kind == "alpha":
        if argument:
            raise IdentificationError(f"parameter {spec!r}: alpha takes no argument")
        return Parameter(spec, kind, (), every)
    if kind == "convection":
        if not argument:
            return Parameter(spec, kind, (), every)
        first, sep, last = argument.partition("..")
        if not sep:
            raise IdentificationError(f"parameter {spec!r}: write convection:A..B (node names)")
        low, high = sorted(
            float(network.positions_mm[network.node_index(node)]) for node in (first, last)
        )
        inside = (network.positions_mm >= low) & (network.positions_mm <= high)
        return Parameter(spec, kind, (first, last), tuple(int(i) for i in np.flatnonzero(inside)))
    if kind == "heat":
        nodes = (argument,) if argument else network.heater_nodes
        if not nodes:
            raise IdentificationError(f"parameter {spec!r}: the network names no heater node")
        indices = tuple(network.node_named(n, "heat node") for n in nodes)  # by name (issue 19)
        return Parameter(spec, kind, tuple(nodes), indices)
    if not argument:
        raise IdentificationError(f"parameter {spec!r}: write contact:NODE (a shaft's node)")
    index = network.node_index(argument)
    if not any(index in (r.a, r.b) for r in network.resistances):
        raise IdentificationError(f"parameter {spec!r}: node {argument!r} joins no other node")
    return Parameter(spec, kind, (argument,), (index,))


@dataclass(frozen=True)
class Applied:
    """A parameter vector applied: the scaled network, heat factor per node, offset per
    region."""

    network: ThermalNetwork
    heat_factor: FloatArray
    offsets_c: dict[str, float]


def apply_parameters(
    network: ThermalNetwork,
    parameters: Sequence[Parameter],
    values: FloatArray,
    regions: Mapping[str, Sequence[str]],
) -> Applied:
    """The network with fitted values (log scales and linear offsets) applied."""
    convection = np.ones(network.node_count)
    alpha = np.ones(network.node_count)
    heat = np.ones(network.node_count)
    contact = np.ones(network.node_count)
    offsets = dict.fromkeys(regions, 0.0)
    for parameter, value in zip(parameters, values, strict=True):
        factor = math.exp(value) if parameter.is_log else 1.0
        chosen = list(parameter.node_indices)
        if parameter.kind == "convection":
            convection[chosen] *= factor
        elif parameter.kind == "alpha":
            alpha[chosen] *= factor
        elif parameter.kind == "heat":
            heat[chosen] *= factor
        elif parameter.kind == "contact":
            contact[chosen] *= factor
        else:
            for region in parameter.targets:
                offsets[region] += float(value)
    resistances = tuple(
        dataclasses.replace(r, r_c_per_w=r.r_c_per_w * contact[r.a] * contact[r.b])
        for r in network.resistances
    )
    scaled = dataclasses.replace(
        network,
        r_ambient_c_per_w=network.r_ambient_c_per_w / convection,
        r_end_c_per_w=network.r_end_c_per_w / convection,
        alpha_per_c=network.alpha_per_c * alpha,
        resistances=resistances,
    )
    return Applied(scaled, heat, offsets)


def observation_matrix(
    network: ThermalNetwork, regions: Mapping[str, Sequence[str]]
) -> dict[str, FloatArray]:
    """Each IR region's row: the mean of the nodes it covers (IrRegion.node ties a region to
    a node; a region over several nodes sees their mean)."""
    rows: dict[str, FloatArray] = {}
    for region, nodes in regions.items():
        if not nodes:
            raise IdentificationError(f"region {region!r} is tied to no node")
        row = np.zeros(network.node_count)
        for node in nodes:
            row[network.node_index(node)] += 1.0 / len(nodes)
        rows[region] = row
    return rows
