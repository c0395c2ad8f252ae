"""Thermal networks from TOML: the presets in ``config/networks/`` or any file.

A file lists either the network itself (``[[nodes]]`` and ``[[resistances]]`` tables) or a
geometry (``[[segments]]`` and ``[[holes]]``) that :mod:`daemon.model.geometry` turns into
one. ``config/networks/thesis-two-link.toml`` shows the first form, ``thesis-single-link.toml``
the second.
"""

from __future__ import annotations

import contextlib
import math
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from config.settings import read_toml
from daemon.model.geometry import Hole, Segment, build_geometry_network
from daemon.model.materials import Material, material, rule_of_mixtures
from daemon.model.network import NetworkError, Resistance, ThermalNetwork

PRESET_PACKAGE = "config"
PRESET_FOLDER = "networks"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class _Node(_Strict):
    name: str
    position_mm: float
    capacitance_j_per_c: float
    alpha_per_c: float | None = None
    r_ambient_c_per_w: float = math.inf
    r_end_c_per_w: float = math.inf
    heat_w: float = 0.0
    link: str | None = None  # issue 20: the link the node belongs to
    position_3d_mm: tuple[float, float, float] | None = None  # and where it is (mm)


class _Link(_Strict):
    between: tuple[str, str]
    r_c_per_w: float


class _Mixture(_Strict):
    fibre: str
    matrix: str
    fibre_volume_fraction: float = Field(ge=0.0, le=1.0)


class _Segment(_Strict):
    length_mm: float
    width_mm: float
    thickness_mm: float
    material: str | _Mixture
    node_spacing_mm: float
    h_w_per_m2k: float


class _Hole(_Strict):
    name: str
    position_mm: float
    diameter_mm: float = 0.0
    insert_material: str | None = None
    insert_length_mm: float | None = None


class _NetworkFile(_Strict):
    name: str | None = None
    description: str = ""
    reference_nodes: tuple[str, str] | None = None
    heater_nodes: tuple[str, ...] = ()
    direction: tuple[float, float, float] = (1.0, 0.0, 0.0)
    alpha_per_c: float | None = None  # default for nodes that give none
    bar_ends_mm: tuple[float, float] | None = None
    nodes: tuple[_Node, ...] = ()
    resistances: tuple[_Link, ...] = ()
    segments: tuple[_Segment, ...] = ()
    holes: tuple[_Hole, ...] = ()
    convection_scale: float = 1.0


def networks_dir() -> Path:
    """Where the presets live (installed with the ``config`` package)."""
    return Path(str(resources.files(PRESET_PACKAGE).joinpath(PRESET_FOLDER)))


def available_presets() -> list[str]:
    return sorted(path.stem for path in networks_dir().glob("*.toml"))


def load_network(name_or_path: str | Path) -> ThermalNetwork:
    """A preset by name (``"thesis-two-link"``) or a TOML file by path; raises
    :class:`NetworkError` with a message naming the file and the faulty node or key."""
    text = str(name_or_path)
    path = Path(text)
    if not (text.endswith(".toml") or path.is_file()):
        path = networks_dir() / f"{text}.toml"
        if not path.is_file():
            raise NetworkError(
                f"no network preset {text!r} (presets: {', '.join(available_presets())}) "
                "and no such file"
            )
    data = read_toml(path, NetworkError)
    try:
        return network_from_mapping(data, default_name=path.stem)
    except NetworkError as err:
        raise NetworkError(f"{path}: {err}") from err


def _describe(err: ValidationError, data: dict[str, Any]) -> str:
    lines = []
    for problem in err.errors():
        location = problem["loc"]
        where = ".".join(str(part) for part in location)
        if len(location) >= 2 and location[0] == "nodes" and isinstance(location[1], int):
            with contextlib.suppress(KeyError, IndexError, TypeError):
                where = f"node {data['nodes'][location[1]]['name']!r}: " + ".".join(
                    str(part) for part in location[2:]
                )
        lines.append(f"{where}: {problem['msg']}")
    return "; ".join(lines)


def _material(spec: str | _Mixture) -> Material:
    if isinstance(spec, str):
        return material(spec)
    return rule_of_mixtures(material(spec.fibre), material(spec.matrix), spec.fibre_volume_fraction)


def network_from_mapping(data: dict[str, Any], default_name: str = "network") -> ThermalNetwork:
    """The network a parsed TOML document describes."""
    try:
        spec = _NetworkFile.model_validate(data)
    except ValidationError as err:
        raise NetworkError(_describe(err, data)) from err
    name = spec.name or default_name
    if spec.segments and spec.nodes:
        raise NetworkError("give either [[nodes]] or [[segments]], not both")
    if spec.segments:
        try:
            segments = [
                Segment(
                    length_mm=s.length_mm,
                    width_mm=s.width_mm,
                    thickness_mm=s.thickness_mm,
                    material=_material(s.material),
                    node_spacing_mm=s.node_spacing_mm,
                    h_w_per_m2k=s.h_w_per_m2k,
                )
                for s in spec.segments
            ]
            holes = [
                Hole(
                    name=h.name,
                    position_mm=h.position_mm,
                    diameter_mm=h.diameter_mm,
                    insert_material=material(h.insert_material) if h.insert_material else None,
                    insert_length_mm=h.insert_length_mm,
                )
                for h in spec.holes
            ]
        except ValueError as err:
            raise NetworkError(str(err)) from err
        return build_geometry_network(
            name,
            segments,
            holes,
            reference_nodes=spec.reference_nodes,
            heater_nodes=spec.heater_nodes,
            direction=spec.direction,
            convection_scale=spec.convection_scale,
            description=spec.description,
        )
    if not spec.nodes:
        raise NetworkError("a network needs [[nodes]] (or a geometry of [[segments]])")
    index = {node.name: i for i, node in enumerate(spec.nodes)}
    alphas = []
    for node in spec.nodes:
        alpha = node.alpha_per_c if node.alpha_per_c is not None else spec.alpha_per_c
        if alpha is None:
            raise NetworkError(f"node {node.name!r}: no alpha_per_c (nor a default for all)")
        alphas.append(alpha)
    resistances = []
    for link in spec.resistances:
        for end in link.between:
            if end not in index:
                raise NetworkError(f"resistance {list(link.between)}: unknown node {end!r}")
        resistances.append(
            Resistance(index[link.between[0]], index[link.between[1]], link.r_c_per_w)
        )
    names = [node.name for node in spec.nodes]
    node_links, positions_3d = _spatial(spec.nodes)
    network = ThermalNetwork(
        name=name,
        node_names=tuple(names),
        positions_mm=np.array([node.position_mm for node in spec.nodes]),
        capacitance_j_per_c=np.array([node.capacitance_j_per_c for node in spec.nodes]),
        alpha_per_c=np.array(alphas),
        r_ambient_c_per_w=np.array([node.r_ambient_c_per_w for node in spec.nodes]),
        r_end_c_per_w=np.array([node.r_end_c_per_w for node in spec.nodes]),
        heat_w=np.array([node.heat_w for node in spec.nodes]),
        resistances=tuple(resistances),
        reference_nodes=spec.reference_nodes or (names[0], names[-1]),
        heater_nodes=spec.heater_nodes,
        direction=np.array(spec.direction),
        bar_ends_mm=spec.bar_ends_mm,
        description=spec.description,
        node_links=node_links,
        positions_3d_mm=positions_3d,
    )
    problem = network.one_dimensional_problem()
    if problem is not None:
        raise NetworkError(
            f"{problem}: a branched or bent network needs every node's link and "
            "position_3d_mm, else its links would be treated as collinear"
        )
    return network


def _spatial(nodes: tuple[_Node, ...]) -> tuple[tuple[str, ...], np.ndarray | None]:
    """Each node's link and 3-D position (issue 20): given for every node or for none."""
    links = [node.link for node in nodes]
    spatial = [node.position_3d_mm for node in nodes]
    for values, key in ((links, "link"), (spatial, "position_3d_mm")):
        missing = [node.name for node, value in zip(nodes, values, strict=True) if value is None]
        if missing and len(missing) < len(nodes):
            raise NetworkError(f"node {missing[0]!r}: no {key} (give it for every node or none)")
    node_links = tuple(link for link in links if link is not None)
    if spatial[0] is None:
        return node_links, None
    return node_links, np.array(spatial, dtype=np.float64)
