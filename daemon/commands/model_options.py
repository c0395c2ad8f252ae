"""``thermocomp model``: its options (light: ``thermocomp model --help`` loads neither NumPy
nor SciPy, issue 30); the work is daemon/model/cli.py, imported when it runs."""

from __future__ import annotations

import argparse
import math
from importlib import resources
from pathlib import Path

from config.cli import finite_float, non_negative_float, positive_float

DEFAULT_AMBIENT_C = 22.0
#: daemon.model.model.STEPPERS (tests/test_model_cli.py checks they agree)
STEPPER_CHOICES = ("exact", "explicit", "implicit")


def _presets() -> list[str]:
    """daemon.model.presets.available_presets, without loading the model (the same folder:
    tests/test_model_cli.py checks they agree)."""
    folder = Path(str(resources.files("config").joinpath("networks")))
    return sorted(path.stem for path in folder.glob("*.toml"))


def _run_simulate(args: argparse.Namespace) -> int:
    from daemon.model.cli import run_simulate  # lazy: the model (SciPy) loads to run, not --help

    return run_simulate(args)


def _run_info(args: argparse.Namespace) -> int:
    # lazy: the model (SciPy) loads to run, not for --help
    from daemon.model.cli import run_info
    from daemon.storage.network_cache import (
        cached_network_facts,  # the cache: outside the pure core
    )

    return run_info(args, lambda path, network: cached_network_facts(path, network, args.data_dir))


def _heat(text: str) -> tuple[str, float]:
    node, equals, watts = text.partition("=")
    if not equals or not node.strip():
        raise argparse.ArgumentTypeError(f"expected NODE=WATTS, got {text!r}")
    try:
        value = float(watts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: {watts!r} is not a number of watts") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r}: heat must be finite")
    return node.strip(), value


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    presets = ", ".join(_presets()) or "none installed"
    parser = subparsers.add_parser(
        "model",
        help="simulate a thermal network or report its facts",
        description="The finite-difference thermal model of the links (thesis 5.4). "
        f"NETWORK is a preset ({presets}) or a TOML file.",
    )
    actions = parser.add_subparsers(dest="model_command", metavar="ACTION", required=True)

    simulate = actions.add_parser(
        "simulate",
        help="temperatures and deformation over time",
        description="Advance the network from ambient with constant heat inputs and print the "
        "deformation between the reference nodes and every node's temperature.",
    )
    simulate.add_argument(
        "--network",
        default="thesis-two-link",
        help="preset name, identified network saved in --data-dir, or TOML file "
        "(default %(default)s)",
    )
    simulate.add_argument(
        "--data-dir", type=Path, help="data directory whose saved networks NAME may be"
    )
    simulate.add_argument(
        "--duration", type=non_negative_float, required=True, help="simulated time (s)"
    )
    simulate.add_argument(
        "--dt", type=positive_float, default=1.0, help="step length (s, default %(default)s)"
    )
    simulate.add_argument(
        "--stepper",
        choices=STEPPER_CHOICES,
        default="exact",
        help="exact: zero-order hold, any dt; explicit: Eq. 5.1 (dt within its bound); "
        "implicit: sparse backward Euler (default %(default)s)",
    )
    simulate.add_argument(
        "--substeps",
        action="store_true",
        help="explicit only: split a dt above Eq. 5.1's bound into sub-steps instead of refusing",
    )
    simulate.add_argument(
        "--heat",
        type=_heat,
        nargs="+",
        action="extend",
        default=[],
        metavar="NODE=WATTS",
        help="heat inputs; NODE is the node's name (several after one "
        "--heat, or --heat repeated; default: the network's own heat inputs; the presets have "
        "none, and a simulation without any heat input is refused)",
    )
    simulate.add_argument(
        "--ambient",
        type=finite_float,
        default=DEFAULT_AMBIENT_C,
        help="ambient and initial temperature (degC, default %(default)s)",
    )
    simulate.add_argument(
        "--every", type=positive_float, help="output interval (s, default: every step)"
    )
    simulate.add_argument("--json", action="store_true", help="JSON on stdout")
    simulate.set_defaults(handler=_run_simulate)

    info = actions.add_parser(
        "info",
        help="node count, explicit bound and limit, time constants, deformation per watt",
        description="Facts of a network: Eq. 5.1's positivity bound, the true explicit "
        "stability limit, the slowest and fastest time constants, and the steady deformation "
        "per watt of each heat input (the network's heaters, or every node if it names none).",
    )
    info.add_argument(
        "network",
        metavar="NAME|PATH",
        help="preset name, identified network saved in --data-dir, or TOML file",
    )
    info.add_argument(
        "--data-dir",
        type=Path,
        help="data directory whose saved networks NAME may be; its cache/ keeps the facts "
        "of each network file seen (a large network's eigenvalues are paid once)",
    )
    info.add_argument("--json", action="store_true", help="JSON on stdout")
    info.set_defaults(handler=_run_info)
