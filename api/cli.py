"""The ``thermocomp`` command: the process entry point.

It lives at the top of the stack because ``serve`` wires every layer together
(config -> drivers -> daemon -> api). Each subcommand is defined beside the feature it exposes
by a ``register(subparsers)`` function that adds its parser and sets ``handler``; this module
only collects them, configures logging and maps errors to exit statuses.
Exit statuses: 0 success, 1 failure at run time, 2 bad usage or invalid configuration.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Callable, Sequence
from typing import NamedTuple

from config.cli import EXIT_FAILURE, EXIT_USAGE

Register = Callable[["argparse._SubParsersAction[argparse.ArgumentParser]"], None]


class Command(NamedTuple):
    name: str
    module: str  # defines ``register(subparsers)``, which adds this command (and maybe others)
    help: str  # the one line ``thermocomp --help`` shows (tests check it is the module's)


#: Every subcommand, in the order ``--help`` lists them. Only the module of the command being
#: run is imported: the others pull in FastAPI, SciPy, Matplotlib, OpenCV, and ``--help`` or
#: a subcommand's first line must come in well under 0.5 s (issue 16).
COMMANDS: tuple[Command, ...] = (
    Command("serve", "api.serve_cli", "run the daemon with its REST/WebSocket API"),
    Command(
        "run", "daemon.commands.run", "run one compensation run to its end and print its summary"
    ),
    Command(
        "stats",
        "daemon.commands.report_options",
        "error statistics of a column (thesis 6.6: N, mean, S_x, chi-squared)",
    ),
    Command(
        "fit",
        "daemon.commands.report_options",
        "first-order exponential fit of a column: time constant and steady state",
    ),
    Command(
        "report",
        "daemon.commands.report_options",
        "write a run's report: figures, summary.json and an HTML page",
    ),
    Command(
        "identify",
        "daemon.commands.identify",
        "fit a thermal network's parameters to a recorded run",
    ),
    Command(
        "devices", "daemon.commands.devices", "bring-up: check that the configured devices answer"
    ),
    Command(
        "calibrate",
        "daemon.commands.calibrate",
        "calibrate with the robot: the camera, several cameras in 3-D, or the model",
    ),
    Command(
        "budget",
        "daemon.commands.budget",
        "the measurement's error budget: each source's error against the deformation "
        "(thesis ch. 4)",
    ),
    Command(
        "cte",
        "daemon.commands.cte",
        "apparent expansion coefficients from runs and their predictions (thesis 2.2.4)",
    ),
    Command(
        "model", "daemon.commands.model_options", "simulate a thermal network or report its facts"
    ),
    Command(
        "centroid",
        "daemon.commands.centroid_options",
        "measure the laser spot's sub-pixel centroid in image files",
    ),
    Command(
        "robot", "drivers.c500c.robot_check", "check the robot controller's console (moves nothing)"
    ),
    Command("emulate", "drivers.sim.cli", "serve an emulated device (the C500C console, a UR)"),
)


def _version() -> str:
    from daemon import __version__

    return __version__


def _chosen(argv: Sequence[str]) -> str | None:
    """The subcommand named on the command line, if any (the first word that is one)."""
    names = {command.name for command in COMMANDS}
    return next((word for word in argv if word in names), None)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The full parser of the command ``argv`` names (every command's when None); the other
    commands get a stub with their one-line help, enough for ``--help`` and for argparse to
    say "invalid choice" correctly."""
    parser = argparse.ArgumentParser(
        prog="thermocomp",
        description="Predict and cancel the warm-up deformation of a robot's links.",
    )
    parser.add_argument("--version", action="version", version=f"thermocomp {_version()}")
    parser.add_argument(
        "--log-level",
        default="INFO",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="logging threshold (default INFO)",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    chosen = None if argv is None else _chosen(argv)
    modules = (
        [command.module for command in COMMANDS]
        if argv is None
        else [c.module for c in COMMANDS if c.name == chosen]
    )
    for module in dict.fromkeys(modules):  # each module once, in order
        register: Register = importlib.import_module(module).register
        register(subparsers)
    for command in COMMANDS:
        if command.name not in subparsers.choices:
            subparsers.add_parser(command.name, help=command.help)
    order = [command.name for command in COMMANDS]
    subparsers._choices_actions.sort(key=lambda action: order.index(action.dest))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(words)
    args = parser.parse_args(words)
    logging.basicConfig(
        level=args.log_level,
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    from config import ConfigError

    try:
        status: int = args.handler(args)
    except ConfigError as err:
        print(f"thermocomp: invalid configuration:\n{err}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return EXIT_FAILURE
    return status


if __name__ == "__main__":
    sys.exit(main())
