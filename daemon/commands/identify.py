"""``thermocomp identify``: its options (light: ``--help`` answers at once, issue 16); the work
is daemon/calibration/identify_run.py (SciPy, the network, the run database), imported when it
runs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from config.cli import EXIT_FAILURE, add_config_argument, non_negative_float


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "identify",
        help="fit a thermal network's parameters to a recorded run",
        description="Grey-box identification: scale a network's convection, heat "
        "inputs, shaft contact resistances and expansion coefficient, and fit IR offsets, so "
        "that it reproduces a run's IR region temperatures and measured deformation "
        "(least squares on log-parameters, robust loss). Reports each parameter with its "
        "standard error, flags the ones the data cannot identify, and writes the identified "
        "network as a TOML file load_network reads. RUN is a run number in the run database "
        "of --config's storage.data_dir, or an exported CSV. An arm run (one with a duty "
        "cycle) gives an arm model instead: each joint's heat, convection, alpha and the IR "
        "offsets, fitted to its measured tool positions and IR regions; --save NAME keeps it "
        "for `thermocomp run --arm-model NAME`.",
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
        "--save",
        metavar="NAME",
        help="save the identified network in the data directory's networks/ folder as NAME: "
        "`thermocomp run --network NAME` and POST /runs use it by name, GET /networks lists it",
    )
    parser.add_argument(
        "--validate",
        metavar="RUN_ID|FILE",
        help="a second run to check the fit on (of an arm run: another recorded arm run by "
        "number, predicted by the identified model and by the preset)",
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
    parser.add_argument(
        "--force",
        action="store_true",
        help="an arm run: save the arm model even with a value outside its physical range "
        "(flagged in the file as implausible)",
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(handler=run_identify)


def run_identify(args: argparse.Namespace) -> int:
    """A two-link run's network, or an arm run's arm model (issue 20), identified."""
    # lazy: SciPy, the network and the run database load when the command runs, not for
    # --help (issue 16)
    from daemon.calibration.identify_run import (
        RunInputError,
        identify_settings,
        recorded_target,
        run_network_identify,
    )
    from daemon.commands.arm_identify import is_arm_run
    from daemon.commands.arm_identify_cli import run_arm_identify

    settings = identify_settings(args)
    try:
        parameters = recorded_target(args, settings)
    except RunInputError as err:
        print(f"thermocomp identify: {err}", file=sys.stderr)
        return EXIT_FAILURE
    if parameters is not None and is_arm_run(parameters):
        return run_arm_identify(args, settings)
    return run_network_identify(args, settings)
