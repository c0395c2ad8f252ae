"""The ``thermocomp`` command line and the real server started from it."""

import httpx

from daemon import __version__
from tests.helpers import run_cli, running_server


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


def test_real_server_answers_health() -> None:
    with running_server(["--config", "config/sim.toml"]) as base_url:
        response = httpx.get(f"{base_url}/api/v1/health", timeout=5.0)
    assert response.status_code == 200
    body = response.json()
    assert (body["status"], body["version"]) == ("ok", __version__)
