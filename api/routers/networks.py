"""``GET /networks``: the thermal networks a run may use: the presets of config/networks, and
the identified networks saved in the data directory (``thermocomp identify --save NAME``),
with where they came from (issue 19)."""

from __future__ import annotations

import asyncio
import logging
import math
from pathlib import Path
from typing import Literal

from fastapi import APIRouter
from pydantic import BaseModel

from api.deps import ContextDep, ReadAccess
from daemon.model import (
    NetworkError,
    ThermalNetwork,
    available_presets,
    load_network,
)
from daemon.model.presets import available_saved, network_file, saved_networks_dir
from daemon.storage.network_cache import cached_network_facts

logger = logging.getLogger(__name__)

router = APIRouter(tags=["networks"], dependencies=[ReadAccess])


class IdentifiedParameter(BaseModel):
    name: str
    value: float
    standard_error: float | None
    identifiable: bool
    reason: str


class Identification(BaseModel):
    """Where an identified network came from and how sure identification was."""

    base_network: str
    source_runs: list[str]
    identified_at: str
    identifiable: dict[str, bool]
    parameters: list[IdentifiedParameter]
    ir_offsets_c: dict[str, float]
    ir_offset_sigma_c: dict[str, float | None]
    deformation_rms_um: float | None
    validation_runs: list[str]
    validation_deformation_rms_um: float | None


class NetworkInfo(BaseModel):
    name: str
    source: Literal["preset", "identified"]
    description: str
    node_count: int
    node_names: list[str]
    reference_nodes: tuple[str, str]
    heater_nodes: list[str]
    heat_w: dict[str, float]  # the network's own heat (a run uses it unless it gives heat_w)
    slowest_time_constant_s: float | None
    steady_deformation_um_per_w: dict[str, float]
    identification: Identification | None


class NetworkProblem(BaseModel):
    name: str
    error: str


class NetworkList(BaseModel):
    networks: list[NetworkInfo]
    unreadable: list[NetworkProblem]


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _identification(network: ThermalNetwork) -> Identification | None:
    calibration = network.calibration
    if calibration is None:
        return None
    return Identification(
        base_network=calibration.base_network,
        source_runs=list(calibration.source_runs),
        identified_at=calibration.identified_at,
        identifiable=calibration.identifiable,
        parameters=[
            IdentifiedParameter(
                name=p.name,
                value=p.value,
                standard_error=_finite(p.standard_error),
                identifiable=p.identifiable,
                reason=p.reason,
            )
            for p in calibration.parameters
        ],
        ir_offsets_c=dict(calibration.ir_offsets_c),
        ir_offset_sigma_c={r: _finite(s) for r, s in calibration.ir_offset_sigma_c.items()},
        deformation_rms_um=_finite(calibration.deformation_rms_um),
        validation_runs=list(calibration.validation_runs),
        validation_deformation_rms_um=_finite(calibration.validation_deformation_rms_um),
    )


def _describe(
    names: list[str], source: Literal["preset", "identified"], data_dir: Path | None
) -> NetworkList:
    """Load each network (blocking: TOML and an eigenvalue problem each, the latter cached
    in the data directory by file content when there is one: daemon/storage/network_cache.py)."""
    networks, problems = [], []
    for name in names:
        try:
            network = load_network(name, data_dir)
            facts = cached_network_facts(network_file(name, data_dir), network, data_dir)
        except NetworkError as err:
            problems.append(NetworkProblem(name=name, error=str(err)))
            continue
        networks.append(
            NetworkInfo(
                name=name,
                source=source,
                description=network.description,
                node_count=len(network.node_names),
                node_names=list(network.node_names),
                reference_nodes=network.reference_nodes,
                heater_nodes=list(network.heater_nodes),
                heat_w=network.own_heat_w(),
                slowest_time_constant_s=_finite(facts.slowest_time_constant_s),
                steady_deformation_um_per_w={
                    node: value
                    for node, value in facts.steady_deformation_um_per_w.items()
                    if math.isfinite(value)
                },
                identification=_identification(network),
            )
        )
    return NetworkList(networks=networks, unreadable=problems)


def _saved_signature(data_dir: Path) -> tuple[tuple[str, int, int], ...]:
    """Name, modification time and size of each saved network: a change re-reads them."""
    folder = saved_networks_dir(data_dir)
    signature = []
    for name in available_saved(data_dir):
        try:
            stat = (folder / f"{name}.toml").stat()
        except OSError:
            continue
        signature.append((name, stat.st_mtime_ns, stat.st_size))
    return tuple(signature)


def _describe_saved(
    data_dir: Path, cached: tuple[object, NetworkList] | None
) -> tuple[object, NetworkList]:
    signature = _saved_signature(data_dir)
    if cached is not None and cached[0] == signature:
        return cached
    names = [name for name, _, _ in signature if name not in available_presets()]
    return signature, _describe(names, "identified", data_dir)


@router.get("/networks")
async def list_networks(context: ContextDep) -> NetworkList:
    """The presets, then the identified networks saved in the data directory, with their
    nodes, their own heat, the facts of their model and (identified ones) their provenance:
    source runs, date, each parameter's error and identifiability. Presets are computed once
    (part of the installation); saved networks again whenever their files change."""
    cached = context.extras.get("networks")
    if isinstance(cached, NetworkList):
        presets = cached
    else:
        presets = await asyncio.to_thread(_describe, available_presets(), "preset", None)
        context.extras["networks"] = presets
    previous = context.extras.get("saved-networks")
    saved = await asyncio.to_thread(
        _describe_saved,
        context.settings.storage.data_dir,
        previous if isinstance(previous, tuple) else None,
    )
    context.extras["saved-networks"] = saved
    listed = saved[1]
    return NetworkList(
        networks=[*presets.networks, *listed.networks],
        unreadable=[*presets.unreadable, *listed.unreadable],
    )
