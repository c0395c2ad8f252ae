"""Thermal networks from TOML: the presets in ``config/networks/`` or any file.

A file lists either the network itself (``[[nodes]]`` and ``[[resistances]]`` tables) or a
geometry (``[[segments]]`` and ``[[holes]]``) that :mod:`daemon.model.geometry` turns into
one. ``config/networks/thesis-two-link.toml`` shows the first form, ``thesis-single-link.toml``
the second. An identified network (``thermocomp identify --out/--save``) adds an
``[identification]`` table (daemon.model.calibration): its source runs, date, parameter
uncertainties and IR offsets.

Networks are found by name among the presets and, when a run's data directory is given, among
the identified networks saved in its ``networks/`` folder (``identify --save NAME``); a name is
never a path there (:func:`check_network_name`), so an API client cannot make the daemon read
an arbitrary file. A path (``*.toml``) is for the command line only.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import re
from collections.abc import Collection
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from config.inputs import InputError, no_such_name
from config.settings import read_toml
from daemon.model.calibration import CalibratedParameter, Calibration
from daemon.model.geometry import Hole, Segment, build_geometry_network
from daemon.model.materials import Material, material, rule_of_mixtures
from daemon.model.network import MAX_NETWORK_NODES, NetworkError, Resistance, ThermalNetwork

PRESET_PACKAGE = "config"
PRESET_FOLDER = "networks"
#: Identified networks saved by ``identify --save`` live in this folder of the data directory.
SAVED_FOLDER = "networks"
#: A network name (preset or saved): letters, digits, '.', '_', '-'; no path, at most 64.
NETWORK_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


#: Most [[resistances]] a network file may list: a dense network of MAX_NETWORK_NODES nodes
#: joins each node to a few neighbours.
MAX_RESISTANCES = 8 * MAX_NETWORK_NODES


class NetworkNotFoundError(InputError, LookupError):
    """A well-formed network name that names no preset and no saved network."""


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


class _Parameter(_Strict):
    name: str
    value: float
    standard_error: float | None = None
    relative_error: float | None = None
    identifiable: bool = True
    reason: str = ""


class _Identification(_Strict):
    base_network: str
    source_runs: tuple[str, ...]
    identified_at: str
    parameters: tuple[_Parameter, ...] = ()
    ir_offsets_c: dict[str, float] = Field(default_factory=dict)
    ir_offset_sigma_c: dict[str, float] = Field(default_factory=dict)
    temperature_rms_c: float | None = None
    deformation_rms_um: float | None = None
    validation_runs: tuple[str, ...] = ()
    validation_deformation_rms_um: float | None = None

    def calibration(self) -> Calibration:
        return Calibration(
            base_network=self.base_network,
            source_runs=self.source_runs,
            identified_at=self.identified_at,
            parameters=tuple(CalibratedParameter(**p.model_dump()) for p in self.parameters),
            ir_offsets_c=dict(self.ir_offsets_c),
            ir_offset_sigma_c=dict(self.ir_offset_sigma_c),
            temperature_rms_c=self.temperature_rms_c,
            deformation_rms_um=self.deformation_rms_um,
            validation_runs=self.validation_runs,
            validation_deformation_rms_um=self.validation_deformation_rms_um,
        )


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
    identification: _Identification | None = None


def networks_dir() -> Path:
    """Where the presets live (installed with the ``config`` package)."""
    return Path(str(resources.files(PRESET_PACKAGE).joinpath(PRESET_FOLDER)))


def available_presets() -> list[str]:
    return sorted(path.stem for path in networks_dir().glob("*.toml"))


def check_network_name(name: str) -> str:
    """``name`` if it can name a preset or a saved network (never a path), else ValueError."""
    if not NETWORK_NAME.fullmatch(name) or name.endswith(".toml"):
        raise InputError(
            f"network {name!r} is not a network name (letters, digits, '.', '_', '-', at most "
            "64, no path): give a preset or an identified network saved in the data directory"
        )
    return name


def saved_networks_dir(data_dir: Path) -> Path:
    """Where ``identify --save`` keeps the identified networks of a data directory."""
    return Path(data_dir) / SAVED_FOLDER


def new_saved_path(name: str, folder: Path, presets: Collection[str], preset_kind: str) -> Path:
    """Where ``identify --save NAME`` writes in ``folder`` (a network's or an arm model's,
    daemon/arm/arm_model.py), its name already checked: ``NAME.toml``; ValueError when one of
    ``presets`` (``preset_kind``, e.g. "a preset") has that name or the file exists (a saved
    model is never overwritten)."""
    if name in presets:
        raise ValueError(f"--save {name!r}: {preset_kind} has that name; choose another")
    path = folder / f"{name}.toml"
    if path.exists():
        raise ValueError(f"--save {name!r}: {path} exists; choose another name")
    return path


def available_saved(data_dir: Path | None) -> list[str]:
    """Names of the identified networks saved in ``data_dir`` (none: no data directory)."""
    if data_dir is None:
        return []
    folder = saved_networks_dir(data_dir)
    if not folder.is_dir():
        return []
    return sorted(p.stem for p in folder.glob("*.toml") if NETWORK_NAME.fullmatch(p.stem))


def named_network_path(name: str, data_dir: Path | None = None) -> Path:
    """The file of a preset or (with ``data_dir``) a saved network called ``name``: a preset
    wins; ValueError for a malformed name, NetworkNotFoundError for an unknown one."""
    check_network_name(name)
    preset = networks_dir() / f"{name}.toml"
    if preset.is_file():
        return preset
    if data_dir is not None:
        saved = saved_networks_dir(data_dir) / f"{name}.toml"
        if saved.exists():  # anything there (a folder, a pipe): the loader says what it is
            return saved
    presets = available_presets()
    listed = f"presets: {', '.join(presets)}"
    if data_dir is None:
        raise NetworkNotFoundError(no_such_name("network preset", name, presets, listed))
    names = available_saved(data_dir)
    listed += f"; saved in {saved_networks_dir(data_dir)}: {', '.join(names) or 'none'}"
    raise NetworkNotFoundError(
        no_such_name("network preset or saved network", name, [*presets, *names], listed)
    )


def network_file(name_or_path: str | Path, data_dir: Path | None = None) -> Path:
    """The file :func:`load_network` reads for ``name_or_path``; NetworkError if none."""
    text = str(name_or_path)
    path = Path(text)
    if not (text.endswith(".toml") or path.is_file()):
        try:
            path = named_network_path(text, data_dir)
        except (ValueError, NetworkNotFoundError) as err:
            raise NetworkError(str(err)) from err
    return path


def load_network(name_or_path: str | Path, data_dir: Path | None = None) -> ThermalNetwork:
    """A preset by name (``"thesis-two-link"``), an identified network saved in ``data_dir``
    by name, or a TOML file by path; raises :class:`NetworkError` with a message naming the
    file and the faulty node or key."""
    path = network_file(name_or_path, data_dir)
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
    for key, most in (
        ("nodes", MAX_NETWORK_NODES),
        ("segments", MAX_NETWORK_NODES),
        ("holes", MAX_NETWORK_NODES),
        ("resistances", MAX_RESISTANCES),
    ):
        given = data.get(key)
        if isinstance(given, list) and len(given) > most:  # refused before it is validated
            raise NetworkError(f"{key}: {len(given)} {key}: at most {most}")
    try:
        spec = _NetworkFile.model_validate(data)
    except ValidationError as err:
        raise NetworkError(_describe(err, data)) from err
    name = spec.name or default_name
    calibration = spec.identification.calibration() if spec.identification else None
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
        built = build_geometry_network(
            name,
            segments,
            holes,
            reference_nodes=spec.reference_nodes,
            heater_nodes=spec.heater_nodes,
            direction=spec.direction,
            convection_scale=spec.convection_scale,
            description=spec.description,
        )
        return dataclasses.replace(built, calibration=calibration) if calibration else built
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
        calibration=calibration,
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
