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
from argparse import SUPPRESS
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NamedTuple

from config.cli import EXIT_FAILURE, EXIT_USAGE
from daemon import __version__

#: ``-v``: INFO, ``-vv``: DEBUG (issue 28: quiet unless asked).
VERBOSE_FLAGS = ("-v", "--verbose")
VERBOSE_OPTIONS: dict[str, Any] = {
    "action": "count",
    "default": 0,
    "help": "say more on stderr: -v progress (INFO), -vv debugging (DEBUG)",
}

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
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="logging threshold (default: WARNING, INFO for serve; -v is INFO, -vv DEBUG)",
    )
    parser.add_argument(*VERBOSE_FLAGS, **VERBOSE_OPTIONS)
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
    for subparser in _leaf_parsers(subparsers):  # -v after the command too: `run ... -v`
        subparser.add_argument(*VERBOSE_FLAGS, **{**VERBOSE_OPTIONS, "default": SUPPRESS})
    order = [command.name for command in COMMANDS]
    subparsers._choices_actions.sort(key=lambda action: order.index(action.dest))
    return parser


def _leaf_parsers(
    subparsers: argparse._SubParsersAction[argparse.ArgumentParser],
) -> Iterator[argparse.ArgumentParser]:
    """Every parser that runs a command (``devices check``, not ``devices``), once each."""
    seen: set[int] = set()
    for parser in subparsers.choices.values():
        if id(parser) in seen:
            continue
        seen.add(id(parser))
        nested = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if nested:
            for inner in nested:
                yield from _leaf_parsers(inner)
        else:
            yield parser


def log_level(args: argparse.Namespace) -> str:
    """The logging threshold: --log-level when given; else -v INFO, -vv DEBUG; else WARNING,
    so that a command's summary on stdout is not interleaved with progress lines on stderr
    (issue 28). ``serve`` is a service: its journal keeps INFO unless told otherwise."""
    if args.log_level is not None:
        return str(args.log_level)
    verbose = int(getattr(args, "verbose", 0) or 0)
    if verbose >= 2:
        return "DEBUG"
    if verbose == 1 or args.command == "serve":
        return "INFO"
    return "WARNING"


def main(argv: Sequence[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(words)
    args = parser.parse_args(words)
    logging.basicConfig(
        level=log_level(args),
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    # lazy: pydantic (the settings) loads for a command that runs, not for --help (issue 16)
    from config import ConfigError
    from config.inputs import InputError, one_line

    try:
        status: int = args.handler(args)
    except ConfigError as err:  # the settings file or environment: one line, exit 2
        print(f"thermocomp {args.command}: invalid configuration: {one_line(err)}", file=sys.stderr)
        return EXIT_USAGE
    except InputError as err:  # any file or name given (network, arm, duty cycle, ...)
        print(f"thermocomp {args.command}: {one_line(err)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return EXIT_FAILURE
    return status


if __name__ == "__main__":
    sys.exit(main())
