"""The ``thermocomp`` command line and the real server started from it."""

import argparse
import logging
import subprocess
import sys

import httpx
import pytest

from api.cli import COMMANDS, build_parser
from api.startup import RepeatFilter
from daemon import __version__
from tests.helpers import REPO_ROOT, run_cli, running_server


def test_version() -> None:
    result = run_cli(["--version"])
    assert result.returncode == 0
    assert result.stdout.strip() == f"thermocomp {__version__}"


def test_help_lists_serve() -> None:
    result = run_cli(["--help"])
    assert result.returncode == 0
    assert "serve" in result.stdout
    serve_help = run_cli(["serve", "--help"])
    assert "--config" in serve_help.stdout and "--port" in serve_help.stdout


def test_unknown_command_is_a_usage_error() -> None:
    result = run_cli(["frobnicate"])
    assert result.returncode == 2
    assert "invalid choice" in result.stderr


@pytest.mark.slow
def test_real_server_answers_health() -> None:
    with running_server(["--config", "config/sim.toml"]) as base_url:
        response = httpx.get(f"{base_url}/api/v1/health", timeout=5.0)
    assert response.status_code == 200
    body = response.json()
    assert (body["status"], body["version"]) == ("ok", __version__)


# --- issue 16: help texts and start-up cost ----------------------------------------------

HEAVY_MODULES = frozenset({"matplotlib", "scipy", "cv2", "pandas"})
#: ... and what the top-level help needs none of either
SERVER_MODULES = frozenset({"fastapi", "uvicorn", "starlette", "pydantic", "numpy"})


def imported_modules(*args: str) -> set[str]:
    """Top-level packages ``thermocomp ARGS`` imports (python -X importtime)."""
    result = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "api", *args],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    return {
        line.split("|")[-1].strip().split(".")[0]
        for line in result.stderr.splitlines()
        if line.startswith("import time:") and "|" in line
    }


#: issue 30: no command's --help loads the numeric stack or the web framework
NUMERIC_STACK = frozenset({"numpy", "scipy", "cv2", "fastapi", "uvicorn"}) | HEAVY_MODULES
#: every command, and the actions of those that have some
HELP_COMMAND_LINES = [
    *([command.name] for command in COMMANDS),
    ["model", "simulate"],
    ["model", "info"],
    ["calibrate", "camera"],
    ["calibrate", "cameras"],
    ["calibrate", "model"],
]


@pytest.mark.parametrize(
    ("args", "forbidden"),
    [
        (["--help"], HEAVY_MODULES | SERVER_MODULES),
        (["serve", "--help"], HEAVY_MODULES | SERVER_MODULES),
        *(([*words, "--help"], NUMERIC_STACK) for words in HELP_COMMAND_LINES),
    ],
    ids=lambda value: " ".join(value) if isinstance(value, list) else "",
)
def test_help_imports_nothing_heavy(args: list[str], forbidden: frozenset[str]) -> None:
    """`thermocomp --help` used to take ~2 s of CPU importing matplotlib and scipy, and most
    `thermocomp COMMAND --help` 0.3-0.6 s importing NumPy, SciPy or OpenCV (issue 30): only
    the command being run is imported, its options apart from its work."""
    heavy = imported_modules(*args) & forbidden
    assert not heavy, heavy


def test_the_light_options_agree_with_the_analysis() -> None:
    from daemon.analysis import RESIDUAL_COLUMN
    from daemon.analysis.cli import FIT_KINDS
    from daemon.commands.report_options import FIT_KINDS as OPTION_KINDS
    from daemon.commands.report_options import RESIDUAL_COLUMN as OPTION_COLUMN

    assert (OPTION_COLUMN, OPTION_KINDS) == (RESIDUAL_COLUMN, FIT_KINDS)


def test_the_top_level_help_lines_are_the_commands_own() -> None:
    """api/cli.py lists the commands without importing them: its one-liners must not drift
    from the ones each command registers."""
    parser = build_parser()  # every module imported
    (subparsers,) = [
        action for action in parser._actions if isinstance(action, argparse._SubParsersAction)
    ]
    registered = {action.dest: action.help for action in subparsers._choices_actions}
    assert registered == {command.name: command.help for command in COMMANDS}


def test_no_help_text_shows_a_doubled_percent_sign() -> None:
    parser = build_parser()
    (subparsers,) = [
        action for action in parser._actions if isinstance(action, argparse._SubParsersAction)
    ]
    texts = [parser.format_help()]
    for command in subparsers.choices.values():
        texts.append(command.format_help())
        for action in command._actions:
            if isinstance(action, argparse._SubParsersAction):
                texts.extend(sub.format_help() for sub in action.choices.values())
    assert all("%%" not in text for text in texts)
    emulate = " ".join(subparsers.choices["emulate"].format_help().split())
    assert "--faults 'drop@5,delay=2@9,corrupt%0.01'" in emulate


def test_fit_kinds_of_the_command_line_are_the_fits_own() -> None:
    from daemon.analysis.cli import FIT_KINDS
    from daemon.analysis.fits import KINDS

    assert FIT_KINDS == KINDS


def test_repeated_log_lines_are_folded() -> None:
    """Accept errors and 503 warnings in a storm: one line per interval, then a count."""
    now = [0.0]
    fold = RepeatFilter(interval_s=10.0, clock=lambda: now[0])

    def record(message: str) -> logging.LogRecord:
        return logging.LogRecord("asyncio", logging.ERROR, __file__, 1, message, None, None)

    passed = [fold.filter(record("socket.accept() out of system resource")) for _ in range(1000)]
    assert passed.count(True) == 1
    assert fold.filter(record("another message"))
    now[0] = 10.0
    later = record("socket.accept() out of system resource")
    assert fold.filter(later) and "(and 999 more like it in 10 s)" in later.getMessage()
