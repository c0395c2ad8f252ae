"""``thermocomp identify``'s work (its options: daemon/commands/identify.py): fit a network to a
recorded run (issue 9), the glue around the pure :mod:`daemon.model.identify`.

A run is read from the run database READ-ONLY (daemon.storage.reports.read_run, so a live daemon's
recording is never disturbed), with the heat it commanded and its IR regions from the run's own
recorded parameters and settings; or from an exported CSV, with the heat and regions of
``--config``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import math
import sqlite3
import sys
from collections.abc import Mapping, Sequence
from contextlib import closing
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from config import Settings, load_settings
from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from daemon.analysis import cli as analysis_cli
from daemon.analysis.steps import RunSteps, steps_from_rows
from daemon.model import NetworkError, ThermalNetwork, available_presets, load_network
from daemon.model.identified_network import calibration_of, network_toml
from daemon.model.identify import (
    IdentificationError,
    IdentificationResult,
    RunData,
    heat_schedule,
    identify,
    run_data_from_steps,
    validate,
)
from daemon.model.observer import regions_to_nodes
from daemon.model.presets import check_network_name, new_saved_path, saved_networks_dir
from daemon.run.setup import RunParameterError, resolve_heat
from daemon.storage.recorder import DATABASE_NAME
from daemon.storage.reports import ReportError, read_run

logger = logging.getLogger(__name__)

#: The simulated IR reader names its default regions ``node-<node>`` (drivers.sim.devices).
NODE_REGION_PREFIX = "node-"


class RunInputError(Exception):
    """The run cannot be read (exit status 1)."""


@dataclass(frozen=True)
class LoadedRun:
    steps: RunSteps
    heat_w: dict[str, float] | None  # the heat the run used (recorded), None: not known
    heater_off_s: float | None
    ambient_c: float
    regions: dict[str, tuple[str, ...]]
    name: str
    settings: Settings  # the run's own (recorded) settings, else --config's
    network: str | None = None  # the network the run's controller used, if recorded

    @property
    def data(self) -> RunData:
        """The run as identification sees it, for a run that recorded its heat (from the
        database); else see :meth:`data_for`."""
        return self.data_for(None)

    def data_for(self, network: ThermalNetwork | None) -> RunData:
        """The run as identification sees it, against ``network``: a run that recorded no
        heat (an exported CSV) gets the heat a run on ``network`` would (resolve_heat)."""
        heat = self.heat_w
        if heat is None:
            if network is None:
                raise RunInputError(f"{self.name} recorded no heat input: give its network")
            try:
                heat, _ = resolve_heat(self.settings, None, network)
            except RunParameterError as err:
                raise RunInputError(str(err)) from err
        schedule = heat_schedule(heat, self.heater_off_s)
        return run_data_from_steps(self.steps, schedule, ambient_c=self.ambient_c, name=self.name)


def recorded_parameters(
    data_dir: Path, run_id: int, error: type[Exception] = RunInputError
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The run's recorded parameters and settings (runs table), read-only (a live daemon's
    recording is never disturbed); ``error`` when the database cannot be read or has no such
    run (daemon/commands/arm_identify.py reads an arm run's with it too)."""
    path = Path(data_dir) / DATABASE_NAME
    try:
        with closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as db:
            row = db.execute(
                "SELECT parameters_json, config_json FROM runs WHERE id = ?", (run_id,)
            ).fetchone()
    except sqlite3.Error as err:
        raise error(f"cannot read {path}: {err}") from err
    if row is None:
        raise error(f"no run {run_id} in {path}")
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
    heat: dict[str, float] | None
    if path.is_file():
        try:
            steps = steps_from_rows(analysis_cli.read_table(path))
        except analysis_cli.InputError as err:
            raise RunInputError(str(err)) from err
        heat, recorded = None, settings
        off = heater_off_s if heater_off_s is not None else settings.bench.heater_off_s
        name, network = path.name, None
    elif target.isdigit():
        data_dir = settings.storage.data_dir
        try:
            steps, _ = read_run(data_dir, int(target))
        except ReportError as err:
            raise RunInputError(str(err)) from err
        parameters, config = recorded_parameters(data_dir, int(target))
        recorded = Settings.model_validate(config) if config else settings
        recorded_heat = parameters.get("heat_w")
        heat = None if recorded_heat is None else dict(recorded_heat)
        off = parameters.get("heater_off_s") if heater_off_s is None else heater_off_s
        name, network = f"run {target}", parameters.get("network")
    else:
        raise RunInputError(f"{target!r} is neither a file nor a run number")
    if steps.n_steps == 0:
        raise RunInputError(f"{name} has no steps")
    regions = _regions(regions_to_nodes(recorded.ir.regions), list(steps.ir_mean_c))
    return LoadedRun(steps, heat, off, recorded.model.ambient_c, regions, name, recorded, network)


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
        "identified heat input (carried by the network file; a run's --heat overrides it): "
        + ", ".join(f"{node} = {watts:.4g} W" for node, watts in result.heat_w.items())
    )
    if result.offsets_c:
        lines.append(
            "identified IR offsets (the observer starts from them): "
            + ", ".join(
                f"{region} = {value:+.3f} degC" for region, value in result.offsets_c.items()
            )
        )
    lines += warning_lines(result.warnings, result.success, result.message)
    if out is not None:
        lines.append(f"network written to {out}")
    return "\n".join(lines)


def warning_lines(warnings: Sequence[str], success: bool, message: str) -> list[str]:
    """The report's closing lines: the identifiability warnings, and the optimiser's message
    when it stopped early (the arm's report ends with them too)."""
    lines = [f"warning: {warning}" for warning in warnings]
    if not success:
        lines.append(f"warning: the optimiser stopped early: {message}")
    return lines


def write_outputs(paths: Sequence[Path], text: str) -> None:
    """``text`` written to each of ``paths`` (``--out`` and ``--save``), folders made."""
    for path in paths:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")


def _number(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.4g}"


def identify_settings(args: argparse.Namespace) -> Settings:
    """``--config``'s settings with ``--data-dir`` applied."""
    settings = load_settings(args.config)
    if args.data_dir is not None:
        settings = settings.model_copy(
            update={"storage": settings.storage.model_copy(update={"data_dir": args.data_dir})}
        )
    return settings


def recorded_target(args: argparse.Namespace, settings: Settings) -> dict[str, Any] | None:
    """The recorded parameters of the run ``args.target`` names by number (None: a CSV file);
    RunInputError when there is no such run. daemon/commands/identify.py picks the two-link or
    the arm identification (daemon/commands/arm_identify.py) with it."""
    if not (args.target.isdigit() and not Path(args.target).is_file()):
        return None
    parameters, _ = recorded_parameters(settings.storage.data_dir, int(args.target))
    return parameters


def run_network_identify(args: argparse.Namespace, settings: Settings) -> int:
    """A two-link run's identification (an arm run's: daemon/commands/arm_identify.py)."""
    saved = None
    try:
        if args.save is not None:
            saved = saved_network_path(args.save, settings.storage.data_dir)
        run = load_run(args.target, settings, args.heater_off)
    except (RunInputError, OSError, ValueError) as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_FAILURE if isinstance(err, RunInputError | OSError) else EXIT_USAGE
    try:
        base = args.network or run.network or settings.model.network
        network = load_network(base, settings.storage.data_dir)
    except NetworkError as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_USAGE
    try:
        result = identify(run.data_for(network), network, run.regions, args.params)
        validation_runs: list[str] = []
        if args.validate:
            other = load_run(args.validate, settings, args.heater_off)
            result = validate(result, other.data_for(network), network, other.regions)
            validation_runs.append(other.name)
        calibration = calibration_of(
            result,
            network.name,
            [run.name],
            datetime.now(UTC).isoformat(timespec="seconds"),
            validation_runs,
        )
        identified = dataclasses.replace(result.network, calibration=calibration)
        header = f"identified by thermocomp identify {args.target} from {network.name}"
        text = network_toml(identified, header=header)
        write_outputs([path for path in (args.out, saved) if path is not None], text)
    except (IdentificationError, NetworkError) as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_USAGE
    except (RunInputError, OSError, ValueError) as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_FAILURE
    if args.json:
        document = result.to_dict()
        document["network_file"] = None if args.out is None else str(args.out)
        document["saved_network"] = args.save
        print(json.dumps(finite_json(document), indent=2, allow_nan=False))
    else:
        print(format_result(result, args.out))
        if saved is not None:
            print(
                f"saved as network {args.save!r} ({saved}): `thermocomp run --network "
                f'{args.save}`, or "network": "{args.save}" in POST /runs'
            )
    return EXIT_OK


def saved_network_path(name: str, data_dir: Path) -> Path:
    """Where ``--save NAME`` writes: a valid name, no preset's, not yet taken (ValueError)."""
    check_network_name(name)
    return new_saved_path(name, saved_networks_dir(data_dir), available_presets(), "a preset")


def finite_json(value: object) -> object:
    """JSON has no inf/NaN: an unbounded standard error is null (in dicts, lists, tuples)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: finite_json(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [finite_json(item) for item in value]
    return value
