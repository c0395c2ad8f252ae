"""Start-up failures as a user meets them (issue 16): the real ``thermocomp`` command in a
subprocess; each failure is ONE line on stderr naming the device, path or port and what to
do, with its documented exit status (docs/reference/cli.md), and nothing was served.

Each exit status is met by a real process here; the variants of a refused argument, setting
or file call the same entry point in-process (tests.helpers.run_main: the same status and
stderr without a fresh interpreter's imports, issue 27)."""

from __future__ import annotations

import os
import socket
import tty
from contextlib import AsyncExitStack
from pathlib import Path

import pytest

from config.cli import EXIT_ADDRESS, EXIT_DEVICE, EXIT_STORAGE, EXIT_USAGE
from daemon.arm.duty import DutyCycleError
from drivers.errors import DeviceTimeoutError
from tests.helpers import free_port, run_cli, run_main, running_server

TOKEN = "control-token-0123456789"


def serve_fails(env: dict[str, str], *args: str) -> tuple[int, str]:
    """``thermocomp serve`` that must fail: (exit status, its one stderr line)."""
    result = run_cli(["serve", *args], env=env, timeout=60)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, result.stderr  # one line, no traceback, no "serving on"
    assert "Traceback" not in result.stderr and "serving on" not in result.stderr
    return result.returncode, lines[0]


@pytest.mark.slow
def test_lab_config_without_a_control_token_refuses_to_bind_beyond_loopback() -> None:
    status, line = serve_fails({}, "--config", "config/lab.toml", "--port", str(free_port()))
    assert status == EXIT_USAGE == 2
    assert line.startswith("thermocomp serve: api.host 0.0.0.0 is reachable")
    assert "THERMOCOMP_API__CONTROL_TOKEN" in line and "api.anonymous_read = true" in line


@pytest.mark.slow
def test_lab_config_without_the_hardware_names_the_device(tmp_path: Path) -> None:
    env = {
        "THERMOCOMP_API__CONTROL_TOKEN": TOKEN,
        "THERMOCOMP_ROBOT__PORT": "/dev/thermocomp-test-no-such-tty",
        "THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path),
    }
    status, line = serve_fails(env, "--config", "config/lab.toml", "--port", str(free_port()))
    assert status == EXIT_DEVICE == 3
    assert "robot.port /dev/thermocomp-test-no-such-tty: no such device" in line
    assert "set robot.port" in line


@pytest.mark.slow
def test_an_unwritable_data_directory_is_named(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    env = {"THERMOCOMP_STORAGE__DATA_DIR": str(blocker / "data")}
    status, line = serve_fails(env, "--config", "config/sim.toml", "--port", str(free_port()))
    assert status == EXIT_STORAGE == 4
    assert str(blocker / "data") in line and "choose another folder" in line


@pytest.mark.slow
def test_an_unusable_database_is_named(tmp_path: Path) -> None:
    (tmp_path / "thermocomp.sqlite3").mkdir()  # a database that cannot be opened
    env = {"THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path)}
    status, line = serve_fails(env, "--config", "config/sim.toml", "--port", str(free_port()))
    assert status == EXIT_STORAGE
    assert "thermocomp.sqlite3" in line and "writable" in line


@pytest.mark.slow
def test_a_port_in_use_is_named(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        env = {"THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path)}
        status, line = serve_fails(env, "--config", "config/sim.toml", "--port", str(port))
    assert status == EXIT_ADDRESS == 5
    assert f"port {port} on 127.0.0.1 is in use by another process" in line
    assert "--port" in line


@pytest.mark.slow
def test_a_data_directory_another_process_serves_names_its_pid(tmp_path: Path) -> None:
    env = {"THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path)}
    with running_server(["--config", "config/sim.toml"], env=env):
        owner = (tmp_path / "thermocomp.lock").read_text().strip()
        assert owner.isdigit() and int(owner) != os.getpid()
        run = run_cli(
            ["run", "--config", "config/sim.toml", "--data-dir", str(tmp_path), "--duration", "5"],
            timeout=60,
        )
        status, line = serve_fails(env, "--config", "config/sim.toml", "--port", str(free_port()))
    assert run.returncode == EXIT_STORAGE, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in run.stderr, run.stderr
    assert f"(pid {owner})" in lines[0]
    assert "POST /api/v1/runs" in lines[0] and "--data-dir" in lines[0]
    assert status == EXIT_STORAGE and f"(pid {owner})" in line


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["run", "--duration", "inf"], "argument --duration: must be finite, got inf"),
        (["run", "--step", "nan"], "argument --step: must be finite, got nan"),
        (["serve", "--port", "70000"], "argument --port: must be a TCP port"),
    ],
)
def test_non_finite_or_out_of_range_arguments_exit_2_naming_them(
    args: list[str], expected: str
) -> None:
    result = run_main(args)
    assert result.returncode == EXIT_USAGE
    assert expected in result.stderr and "Traceback" not in result.stderr


@pytest.mark.parametrize(
    ("toml", "field"),
    [
        ("[bench]\nheater_power_w = inf\n", "bench.heater_power_w: Input should be a finite"),
        ("[model]\nambient_c = 1e400\n", "model.ambient_c: Input should be a finite"),
        ("[scheduler]\nduration_s = nan\n", "scheduler.duration_s: Input should be a finite"),
        ("[model]\nambient_c = 5000\n", "model.ambient_c: Input should be less than"),
    ],
)
def test_non_finite_settings_exit_2_naming_the_field(tmp_path: Path, toml: str, field: str) -> None:
    config = tmp_path / "bad.toml"
    config.write_text(toml)
    result = run_main(["serve", "--config", str(config)])
    assert result.returncode == EXIT_USAGE, result.stderr
    assert f"{config}: {field}" in result.stderr and "Traceback" not in result.stderr


def test_environment_infinity_is_refused_naming_the_variable() -> None:
    result = run_main(
        ["serve", "--config", "config/sim.toml"],
        env={"THERMOCOMP_SCHEDULER__DURATION_S": "Infinity"},
    )
    assert result.returncode == EXIT_USAGE
    assert "THERMOCOMP_SCHEDULER__DURATION_S (environment): scheduler.duration_s" in (result.stderr)


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (bytes(range(256)) * 4, "a binary file, not TOML text"),
        ("[bench]\nseed = 1 # caf\u00e9\n".encode("latin-1"), "not UTF-8 text (byte 22)"),
    ],
)
def test_binary_or_non_utf8_files_are_refused_in_one_line(
    tmp_path: Path, content: bytes, reason: str
) -> None:
    path = tmp_path / "file.toml"
    path.write_bytes(content)
    settings = run_main(["serve", "--config", str(path)])
    assert settings.returncode == EXIT_USAGE
    assert f"{path}: {reason}" in settings.stderr and "Traceback" not in settings.stderr
    network = run_main(["model", "info", str(path)])
    assert network.returncode == EXIT_USAGE
    assert network.stderr.strip().startswith(f"thermocomp model: error: {path}: {reason}")
    assert len(network.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_robot_that_does_not_answer_is_one_line_and_exit_3(tmp_path: Path) -> None:
    """The port is there (the checks pass) but nothing answers on it: the daemon's start
    fails before the server listens, logged in one line, no traceback."""
    controller, port = os.openpty()
    tty.setraw(port)
    try:
        env = {
            "THERMOCOMP_ROBOT__DRIVER": "c500c",
            "THERMOCOMP_ROBOT__PORT": os.ttyname(port),
            "THERMOCOMP_ROBOT__COMMAND_TIMEOUT_S": "0.5",
            "THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path),
        }
        result = run_cli(
            ["serve", "--config", "config/sim.toml", "--port", str(free_port())],
            env=env,
            timeout=60,
        )
    finally:
        os.close(controller)
        os.close(port)
    assert result.returncode == EXIT_DEVICE, result.stderr
    errors = [line for line in result.stderr.splitlines() if " ERROR " in line]
    assert "Traceback" not in result.stderr and "serving on" not in result.stderr
    assert len(errors) == 1, result.stderr  # the daemon is not uvicorn's: no "startup failed"
    assert "cannot start the daemon: robot: " in errors[0]
    assert "0.5 s" in errors[0]  # what it waited for


class _FailingService:
    """A daemon whose start raises ``error`` (what the daemon met opening its inputs)."""

    def __init__(self, error: Exception) -> None:
        self.error = error

    def __call__(self, settings: object) -> _FailingService:
        return self

    async def __aenter__(self) -> None:
        raise self.error

    async def __aexit__(self, *exc: object) -> None:
        return None


@pytest.mark.parametrize(
    ("error", "status"),
    [
        (DutyCycleError("duty.toml: poses: at most 1000"), EXIT_USAGE),
        (DeviceTimeoutError("robot", "no answer within 0.5 s"), EXIT_DEVICE),
    ],
    ids=["bad-file", "device"],
)
async def test_a_bad_file_met_by_the_daemons_start_asks_for_exit_2(
    error: Exception, status: int
) -> None:
    """A file or name the start-up checks passed but the daemon's start cannot load (changed
    in between): a configuration error, exit 2 -- not 3, which systemd retries forever; a
    device that does not answer stays 3."""
    from api.app import DaemonStartFailed, open_service
    from config import Settings

    with pytest.raises(DaemonStartFailed) as failed:
        async with AsyncExitStack() as stack:
            await open_service(stack, Settings(), _FailingService(error))  # type: ignore[arg-type]
    assert failed.value.status == status
    assert str(failed.value) == str(error)
