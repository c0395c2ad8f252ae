"""``thermocomp model``: simulate a thermal network, or report its facts.

``thermocomp model simulate --network thesis-two-link --duration 3600 --dt 1 --heat 2=0.5
--heat 9=0.5 --json`` prints ``{"network", "stepper", "dt_s", "t_s", "deformation_um",
"nodes", "temperature_c"}`` with one row per output time from 0 s, every node starting at
ambient. ``thermocomp model info NAME|PATH`` prints the bound and limit of the explicit step,
the time constants and the steady deformation per watt of each heat input.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from config.cli import EXIT_OK, EXIT_USAGE
from daemon.model.model import ModelError, Stepper, ThermalModel
from daemon.model.network import NetworkError, NetworkFacts, ThermalNetwork, network_facts
from daemon.model.presets import load_network, network_file

# the options live in daemon/commands/model_options.py (light: `thermocomp model --help` loads no
# NumPy or SciPy), which calls run_simulate and run_info when the command runs


def _fail(message: str) -> int:
    print(f"thermocomp model: error: {message}", file=sys.stderr)
    return EXIT_USAGE


def output_times(duration_s: float, every_s: float) -> list[float]:
    """0, every, 2 every, ... up to the duration, which is always the last row."""
    count = math.floor(duration_s / every_s + 1e-9)
    times = [k * every_s for k in range(count + 1)]
    if duration_s - times[-1] > 1e-9 * every_s:
        times.append(duration_s)
    return times


def simulate(
    network: ThermalNetwork,
    *,
    duration_s: float,
    dt_s: float,
    stepper: Stepper,
    heat_w: dict[str, float],
    ambient_c: float,
    every_s: float | None = None,
    allow_substeps: bool = False,
) -> dict[str, Any]:
    """The ``simulate`` document: rows of deformation and temperatures at the output times."""
    model = ThermalModel(
        network,
        stepper=stepper,
        dt_s=dt_s,
        ambient_c=ambient_c,
        allow_substeps=allow_substeps,
    )
    if heat_w:  # else the network's own heat inputs (none in the presets)
        model.set_heat(heat_w)
    times = output_times(duration_s, every_s or dt_s)
    deformation: list[float] = []
    temperatures: list[list[float]] = []
    for t_s in times:
        model.advance_to(t_s)
        deformation.append(model.deformation_um_scalar())
        temperatures.append(model.temperatures_c.tolist())
    return {
        "network": network.name,
        "stepper": stepper,
        "dt_s": dt_s,
        "t_s": times,
        "deformation_um": deformation,
        "nodes": list(network.node_names),
        "temperature_c": temperatures,
    }


def run_simulate(args: argparse.Namespace) -> int:
    heat: dict[str, float] = {}
    for node, watts in args.heat:
        heat[node] = heat.get(node, 0.0) + watts
    try:
        network = load_network(args.network, args.data_dir)
        if not heat and not network.heat_w.any():
            heaters = ", ".join(network.heater_nodes)
            return _fail(
                f"no heat input: network {network.name!r} defines none and no --heat was "
                "given, so every node would stay at ambient; give --heat NODE=WATTS"
                + (f" (its heater nodes: {heaters})" if heaters else "")
            )
        document = simulate(
            network,
            duration_s=args.duration,
            dt_s=args.dt,
            stepper=args.stepper,
            heat_w=heat,
            ambient_c=args.ambient,
            every_s=args.every,
            allow_substeps=args.substeps,
        )
    except (NetworkError, ModelError) as err:
        return _fail(str(err))
    if args.json:
        json.dump(document, sys.stdout)
        sys.stdout.write("\n")
        return EXIT_OK
    _print_simulation(network, document, heat)
    return EXIT_OK


def _print_simulation(
    network: ThermalNetwork, document: dict[str, Any], heat: dict[str, float]
) -> None:
    shown = list(dict.fromkeys([*heat, *network.reference_nodes]))
    columns = [network.node_index(node) for node in shown]
    first, second = network.reference_nodes
    print(
        f"network {network.name}: {document['stepper']} stepper, dt = {document['dt_s']:g} s; "
        f"deformation from node {first} to node {second}"
    )
    header = ["t (s)", "deformation (um)", *(f"T{network.node_names[i]} (C)" for i in columns)]
    header.append("T max (C)")
    widths = [max(len(h), 10) for h in header]
    print("  ".join(h.rjust(w) for h, w in zip(header, widths, strict=True)))
    for t_s, deformation, row in zip(
        document["t_s"], document["deformation_um"], document["temperature_c"], strict=True
    ):
        cells = [f"{t_s:g}", f"{deformation:.3f}", *(f"{row[i]:.3f}" for i in columns)]
        cells.append(f"{max(row):.3f}")
        print("  ".join(c.rjust(w) for c, w in zip(cells, widths, strict=True)))


def describe(network: ThermalNetwork, facts: NetworkFacts | None = None) -> dict[str, Any]:
    """The ``info`` document (``facts``: the network's, when already known)."""
    facts = facts or network_facts(network)
    inputs: Sequence[str] = network.heater_nodes or network.node_names
    return {
        "network": network.name,
        "description": network.description,
        "node_count": facts.node_count,
        "reference_nodes": list(network.reference_nodes),
        "positivity_bound_s": facts.positivity_bound_s,
        "stability_limit_s": facts.stability_limit_s,
        "slowest_time_constant_s": facts.slowest_time_constant_s,
        "fastest_time_constant_s": facts.fastest_time_constant_s,
        "steady_deformation_um_per_w": {
            node: facts.steady_deformation_um_per_w[network.node_names[network.node_index(node)]]
            for node in inputs
        },
    }


def run_info(
    args: argparse.Namespace,
    facts_of: Callable[[Path, ThermalNetwork], NetworkFacts] | None = None,
) -> int:
    """``model info``; ``facts_of(file, network)`` gives the facts when the caller keeps
    them (daemon/commands/model_options.py: the data directory's cache), else they are computed."""
    try:
        network = load_network(args.network, args.data_dir)
        facts = facts_of(network_file(args.network, args.data_dir), network) if facts_of else None
        document = describe(network, facts)
    except NetworkError as err:
        return _fail(str(err))
    if args.json:
        json.dump(document, sys.stdout, indent=2)
        sys.stdout.write("\n")
        return EXIT_OK
    first, second = document["reference_nodes"]
    print(f"network            {document['network']}  ({document['description']})")
    print(f"nodes              {document['node_count']}")
    print(f"deformation        node {first} to node {second}")
    print(
        f"explicit dt        <= {document['positivity_bound_s']:.6g} s (Eq. 5.1 bound, no "
        f"overshoot); stable below {document['stability_limit_s']:.6g} s"
    )
    print(
        f"time constants     slowest {document['slowest_time_constant_s']:.6g} s, "
        f"fastest {document['fastest_time_constant_s']:.6g} s"
    )
    print("steady deformation per watt:")
    for node, value in document["steady_deformation_um_per_w"].items():
        print(f"  node {node:<12} {value:10.3f} um/W")
    return EXIT_OK
