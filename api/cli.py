"""The ``thermocomp`` command: the process entry point.

It lives at the top of the stack because ``serve`` wires every layer together
(config -> drivers -> daemon -> api). Each subcommand is defined beside the feature it exposes
by a ``register(subparsers)`` function that adds its parser and sets ``handler``; this module
only collects them, configures logging and maps errors to exit statuses.
Exit statuses: 0 success, 1 failure at run time, 2 bad usage or invalid configuration.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable, Sequence

from api import serve
from config import ConfigError
from config.cli import EXIT_FAILURE, EXIT_USAGE
from daemon import __version__, identify_cli, reports, run_cli
from daemon.model import cli as model_cli
from daemon.vision import cli as vision_cli
from drivers import robot_check
from drivers.sim import cli as emulate_cli

Register = Callable[["argparse._SubParsersAction[argparse.ArgumentParser]"], None]

#: Every subcommand, in the order ``--help`` lists them.
COMMANDS: tuple[Register, ...] = (
    serve.register,
    run_cli.register,
    reports.register,
    identify_cli.register,
    model_cli.register,
    vision_cli.register,
    emulate_cli.register,
    robot_check.register,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="thermocomp",
        description="Predict and cancel the warm-up deformation of a robot's links.",
    )
    parser.add_argument("--version", action="version", version=f"thermocomp {__version__}")
    parser.add_argument(
        "--log-level",
        default="INFO",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="logging threshold (default INFO)",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for register in COMMANDS:
        register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=args.log_level,
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        stream=sys.stderr,
    )
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
