"""``thermocomp budget``: its options (light: ``--help`` imports no numeric stack, issue 16);
the work is daemon/commands/budget_run.py, imported when it runs."""

from __future__ import annotations

import argparse
from pathlib import Path

from config.cli import add_config_argument, positive_float, positive_int

HELP = "the measurement's error budget: each source's error against the deformation (thesis ch. 4)"


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "budget",
        help=HELP,
        description="Thesis chapter 4 (Table 4.5) for the configured set-up: every "
        "source of measurement error that applies, its error dL along the measured "
        "deformation against the deformation dL the model expects, ranked, with what would "
        "reduce it, and whether the set-up can resolve the compensation target. Analytic "
        "where the thesis was (cantilever bending 4.3, misalignment 4.4, the diode hole 4.5), "
        "measured where it experimented: a recording on a fixed target with the heaters off "
        "(the camera's own drift, 4.8), then a short stationary recording with the robot "
        "powered and held (vibration 4.6, the centroid against its Cramer-Rao bound 4.7), "
        "through the configured devices (the daemon must not hold them). For an arm: the 3-D "
        "measurement's uncertainty at each measured pose from the cameras' geometry and the "
        "markers, and an identified arm model's parameter uncertainties carried to the tool. "
        "Random errors count twice their 1-sigma (95 %), analytic ones at their worst case; "
        "the resolution is their root sum of squares. Exit status 0 when the set-up resolves "
        "the target, 1 when it cannot.",
    )
    add_config_argument(parser)
    parser.add_argument(
        "--target",
        type=positive_float,
        metavar="UM",
        help="the compensation target (um) the measurement must resolve (default: "
        "compensation.target_um of --config)",
    )
    parser.add_argument(
        "--setup",
        type=Path,
        metavar="FILE",
        help="a laser-spot set-up's mechanical facts (TOML; default: "
        "config/budget/thesis-two-link.toml, the thesis's apparatus)",
    )
    parser.add_argument(
        "--arm-model",
        metavar="NAME",
        help="an arm: the identified arm model (saved by `identify --save NAME`, or a file) "
        "whose parameter uncertainties are carried to the tool",
    )
    parser.add_argument(
        "--no-record",
        action="store_true",
        help="record nothing: the analytic and model rows only (the measured ones say why)",
    )
    parser.add_argument(
        "--drift-s",
        type=positive_float,
        default=1800.0,
        metavar="S",
        help="length of the camera-only recording on a fixed target (default 1800 s: the "
        "thesis's camera warmed up within 30 min)",
    )
    parser.add_argument(
        "--drift-frames",
        type=positive_int,
        default=60,
        metavar="N",
        help="frames of the camera-only recording, evenly spread (default 60)",
    )
    parser.add_argument(
        "--stationary-s",
        type=positive_float,
        default=60.0,
        metavar="S",
        help="length of the stationary recording with the robot held (default 60 s)",
    )
    parser.add_argument(
        "--stationary-frames",
        type=positive_int,
        default=60,
        metavar="N",
        help="frames of the stationary recording (default 60)",
    )
    parser.add_argument(
        "--data-dir",
        type=Path,
        help="folder of the saved arm models and of --save (default: storage.data_dir of --config)",
    )
    parser.add_argument(
        "--save",
        action="store_true",
        help="also keep it as the data directory's latest budget, which GET /api/v1/budget "
        "serves (the daemon cannot record: its devices belong to its runs)",
    )
    parser.add_argument("--json", action="store_true", help="print the budget as JSON")
    parser.set_defaults(handler=run_budget)


def run_budget(args: argparse.Namespace) -> int:
    # lazy: NumPy/SciPy and the analysis load when the command runs, not for --help
    from daemon.commands.budget_run import run_budget as run

    return run(args)
