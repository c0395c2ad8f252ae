"""What every ``thermocomp`` subcommand shares: exit statuses, ``--config``, argument types.

It sits in the bottom layer so that commands defined in any layer (``drivers.sim``, the pure
core's ``daemon.model``/``vision``/``analysis``, ``daemon``, ``api``) use this one copy.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

EXIT_OK = 0
EXIT_FAILURE = 1  # the command ran and failed (a device, a frame, a run)
EXIT_USAGE = 2  # bad usage or an invalid configuration
EXIT_DEVICE = 3  # a device is absent or cannot be opened (systemd retries with a back-off)
EXIT_STORAGE = 4  # the data directory or run database cannot be used (unwritable, in use)
EXIT_ADDRESS = 5  # the API's address and port cannot be bound (in use, not this machine's)


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--config`` option of every command that reads settings."""
    parser.add_argument(
        "--config",
        type=Path,
        help="TOML settings file (default: built-in defaults = the simulated bench); "
        "THERMOCOMP_<SECTION>__<FIELD> environment variables override it",
    )


def finite_float(text: str) -> float:
    """An argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be finite, got {text}")
    return value


def positive_float(text: str) -> float:
    """An argparse type: a finite number above zero."""
    value = finite_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def non_negative_float(text: str) -> float:
    """An argparse type: a finite number, zero or more."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative, got {text}")
    return value


def positive_int(text: str) -> int:
    """An argparse type: a whole number above zero."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return value


def non_negative_int(text: str) -> int:
    """An argparse type: a whole number, zero or more."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must not be negative, got {text}")
    return value


def port_number(text: str) -> int:
    """An argparse type: a TCP port, 0 (any free one) to 65535."""
    value = non_negative_int(text)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"must be a TCP port, 0 to 65535, got {text}")
    return value


def fraction(text: str) -> float:
    """An argparse type: a finite number above 0 and at most 1."""
    value = positive_float(text)
    if value > 1:
        raise argparse.ArgumentTypeError(f"must be at most 1, got {text}")
    return value
