"""``thermocomp identify``: fit a network to a recorded run (issue 9), the glue around the pure
:mod:`daemon.model.identify`.

A run is read from the run database READ-ONLY (daemon.reports.read_run, so a live daemon's
recording is never disturbed), with the heat it commanded and its IR regions from the run's own
recorded parameters and settings; or from an exported CSV, with the heat and regions of
``--config``.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sqlite3
import sys
from collections.abc import Mapping, Sequence
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from config import Settings, load_settings
from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, add_config_argument, non_negative_float
from daemon.analysis import cli as analysis_cli
from daemon.analysis.steps import steps_from_rows
from daemon.model import NetworkError, load_network
from daemon.model.identify import (
    IdentificationError,
    IdentificationResult,
    RunData,
    heat_schedule,
    identify,
    network_toml,
    run_data_from_steps,
    validate,
)
from daemon.model.observer import regions_to_nodes
from daemon.recorder import DATABASE_NAME
from daemon.reports import ReportError, read_run

logger = logging.getLogger(__name__)

#: The simulated IR reader names its default regions ``node-<node>`` (drivers.sim.devices).
NODE_REGION_PREFIX = "node-"


class RunInputError(Exception):
    """The run cannot be read (exit status 1)."""


@dataclass(frozen=True)
class LoadedRun:
    data: RunData
    regions: dict[str, tuple[str, ...]]
    network: str | None = None  # the network the run's controller used, if recorded


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "identify",
        help="fit a thermal network's parameters to a recorded run",
        description="Grey-box identification (issue 9): scale a network's convection, heat "
        "inputs, shaft contact resistances and expansion coefficient, and fit IR offsets, so "
        "that it reproduces a run's IR region temperatures and measured deformation "
        "(least squares on log-parameters, robust loss). Reports each parameter with its "
        "standard error, flags the ones the data cannot identify, and writes the identified "
        "network as a TOML file load_network reads. RUN is a run number in the run database "
        "of --config's storage.data_dir, or an exported CSV.",
    )
    parser.add_argument("target", metavar="RUN_ID|FILE", help="run number or exported CSV")
    parser.add_argument(
        "--network",
        help="the network to start from: preset name or TOML path (default: the run's, else "
        "model.network of --config)",
    )
    parser.add_argument(
        "--params",
        nargs="+",
        metavar="PARAM",
        help="parameters to fit: convection, convection:A..B, heat, heat:NODE, contact:NODE, "
        "alpha, offset, offset:REGION (default: convection, heat per heater, alpha, offset)",
    )
    parser.add_argument("--out", type=Path, help="write the identified network here (TOML)")
    parser.add_argument(
        "--validate", metavar="RUN_ID|FILE", help="a second run to check the fit on"
    )
    parser.add_argument(
        "--heater-off",
        type=non_negative_float,
        metavar="S",
        help="for an exported CSV: run time the heaters switched off (default: "
        "bench.heater_off_s of --config)",
    )
    add_config_argument(parser)
    parser.add_argument(
        "--data-dir",
        type=Path,
        help="folder of the run database (default: storage.data_dir of --config), as for "
        "`thermocomp run --data-dir`",
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(handler=run_identify)


def _recorded_parameters(data_dir: Path, run_id: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """The run's recorded parameters and settings (runs table), read-only."""
    path = Path(data_dir) / DATABASE_NAME
    try:
        with closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as db:
            row = db.execute(
                "SELECT parameters_json, config_json FROM runs WHERE id = ?", (run_id,)
            ).fetchone()
    except sqlite3.Error as err:
        raise RunInputError(f"cannot read {path}: {err}") from err
    if row is None:
        raise RunInputError(f"no run {run_id} in {path}")
    return json.loads(row[0] or "{}"), json.loads(row[1] or "{}")


def _regions(
    configured: Mapping[str, tuple[str, ...]], recorded: Sequence[str]
) -> dict[str, tuple[str, ...]]:
    """IR regions tied to nodes: the configured ones, else the sim's ``node-<name>`` ones."""
    if configured:
        return dict(configured)
    return {
        name: (name.removeprefix(NODE_REGION_PREFIX),)
        for name in recorded
        if name.startswith(NODE_REGION_PREFIX)
    }


def load_run(target: str, settings: Settings, heater_off_s: float | None) -> LoadedRun:
    """A run from the database (by number) or an exported CSV file."""
    path = Path(target)
    if path.is_file():
        try:
            steps = steps_from_rows(analysis_cli.read_table(path))
        except analysis_cli.InputError as err:
            raise RunInputError(str(err)) from err
        heat = dict(settings.model.heat_w)
        off = heater_off_s if heater_off_s is not None else settings.bench.heater_off_s
        ambient, configured = settings.model.ambient_c, regions_to_nodes(settings.ir.regions)
        name, network = path.name, None
    elif target.isdigit():
        data_dir = settings.storage.data_dir
        try:
            steps, _ = read_run(data_dir, int(target))
        except ReportError as err:
            raise RunInputError(str(err)) from err
        parameters, config = _recorded_parameters(data_dir, int(target))
        recorded = Settings.model_validate(config) if config else settings
        heat = dict(parameters.get("heat_w") or recorded.model.heat_w)
        off = parameters.get("heater_off_s") if heater_off_s is None else heater_off_s
        ambient, configured = recorded.model.ambient_c, regions_to_nodes(recorded.ir.regions)
        name, network = f"run {target}", parameters.get("network")
    else:
        raise RunInputError(f"{target!r} is neither a file nor a run number")
    if steps.n_steps == 0:
        raise RunInputError(f"{name} has no steps")
    data = run_data_from_steps(steps, heat_schedule(heat, off), ambient_c=ambient, name=name)
    return LoadedRun(data, _regions(configured, list(steps.ir_mean_c)), network)


def format_result(result: IdentificationResult, out: Path | None) -> str:
    lines = [f"{'parameter':<18} {'value':>10} {'std error':>10} {'rel.':>8}  identifiable"]
    for p in result.parameters:
        relative = "" if p.relative_error is None else f"{100 * p.relative_error:7.2f}%"
        verdict = "yes" if p.identifiable else f"NO: {p.reason}"
        lines.append(
            f"{p.name:<18} {p.value:>10.4g} {p.standard_error:>10.3g} {relative:>8}  {verdict}"
        )
    fit = result.fit
    lines.append(
        f"fit: temperature RMS {_number(fit.temperature_rms_c)} degC "
        f"({fit.temperature_samples} values), deformation RMS "
        f"{_number(fit.deformation_rms_um)} um ({fit.deformation_samples} values)"
    )
    if result.validation is not None:
        check = result.validation
        lines.append(
            f"validation: temperature RMS {_number(check.temperature_rms_c)} degC, "
            f"deformation RMS {_number(check.deformation_rms_um)} um"
        )
    lines.append(
        "identified heat input (set model.heat_w to use it): "
        + ", ".join(f"{node} = {watts:.4g} W" for node, watts in result.heat_w.items())
    )
    lines += [f"warning: {warning}" for warning in result.warnings]
    if not result.success:
        lines.append(f"warning: the optimiser stopped early: {result.message}")
    if out is not None:
        lines.append(f"network written to {out}")
    return "\n".join(lines)


def _number(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.4g}"


def run_identify(args: argparse.Namespace) -> int:
    settings = load_settings(args.config)
    if args.data_dir is not None:
        settings = settings.model_copy(
            update={"storage": settings.storage.model_copy(update={"data_dir": args.data_dir})}
        )
    try:
        run = load_run(args.target, settings, args.heater_off)
    except (RunInputError, OSError, ValueError) as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_FAILURE
    try:
        network = load_network(args.network or run.network or settings.model.network)
    except NetworkError as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_USAGE
    try:
        result = identify(run.data, network, run.regions, args.params)
        if args.validate:
            other = load_run(args.validate, settings, args.heater_off)
            result = validate(result, other.data, network, other.regions)
        if args.out is not None:
            header = f"identified by thermocomp identify {args.target} from {network.name}"
            args.out.write_text(network_toml(result.network, header=header), encoding="utf-8")
    except (IdentificationError, NetworkError) as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_USAGE
    except (RunInputError, OSError, ValueError) as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_FAILURE
    if args.json:
        document = result.to_dict()
        document["network_file"] = None if args.out is None else str(args.out)
        print(json.dumps(_finite(document), indent=2, allow_nan=False))
    else:
        print(format_result(result, args.out))
    return EXIT_OK


def _finite(value: object) -> object:
    """JSON has no inf/NaN: an unbounded standard error is null."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    return value
