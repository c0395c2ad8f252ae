"""``GET /networks``: the thermal network presets of config/networks a run may use."""

from __future__ import annotations

import asyncio
import logging
import math

from fastapi import APIRouter
from pydantic import BaseModel

from api.deps import ContextDep, ReadAccess
from daemon.model import NetworkError, available_presets, load_network, network_facts

logger = logging.getLogger(__name__)

router = APIRouter(tags=["networks"], dependencies=[ReadAccess])


class NetworkInfo(BaseModel):
    name: str
    description: str
    node_count: int
    node_names: list[str]
    reference_nodes: tuple[str, str]
    heater_nodes: list[str]
    slowest_time_constant_s: float | None
    steady_deformation_um_per_w: dict[str, float]


class NetworkProblem(BaseModel):
    name: str
    error: str


class NetworkList(BaseModel):
    networks: list[NetworkInfo]
    unreadable: list[NetworkProblem]


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _describe_presets() -> NetworkList:
    """Load every preset (blocking: TOML and an eigenvalue problem each)."""
    networks, problems = [], []
    for name in available_presets():
        try:
            network = load_network(name)
            facts = network_facts(network)
        except NetworkError as err:
            problems.append(NetworkProblem(name=name, error=str(err)))
            continue
        networks.append(
            NetworkInfo(
                name=name,
                description=network.description,
                node_count=len(network.node_names),
                node_names=list(network.node_names),
                reference_nodes=network.reference_nodes,
                heater_nodes=list(network.heater_nodes),
                slowest_time_constant_s=_finite(facts.slowest_time_constant_s),
                steady_deformation_um_per_w={
                    node: value
                    for node, value in facts.steady_deformation_um_per_w.items()
                    if math.isfinite(value)
                },
            )
        )
    return NetworkList(networks=networks, unreadable=problems)


@router.get("/networks")
async def list_networks(context: ContextDep) -> NetworkList:
    """The presets, with their nodes and the facts of their model (computed once, cached:
    the files are part of the installation)."""
    cached = context.extras.get("networks")
    if isinstance(cached, NetworkList):
        return cached
    described = await asyncio.to_thread(_describe_presets)
    context.extras["networks"] = described
    return described
