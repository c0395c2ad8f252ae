"""The whole daemon on the simulated bench through the fast path (robot.driver = "c500c-server"):
the factory opens the server driver on the emulated program's pty, and `thermocomp run` runs
to its end through it."""

from __future__ import annotations

import asyncio
import json
import subprocess
from pathlib import Path

import pytest

from config import ConfigError, load_settings
from config.settings import RobotSettings
from daemon.storage.recorder import Recorder
from drivers.c500c.server import C500CServerRobot
from drivers.clock import ScaledClock
from drivers.factory import open_devices
from drivers.sim.server_emulator import C500CServerEmulator
from tests.helpers import REPO_ROOT, cli_command, run_cli, run_main

SIM = "config/sim.toml"
FAST_PATH = {"THERMOCOMP_ROBOT__DRIVER": "c500c-server"}


@pytest.mark.slow
async def test_the_factory_opens_the_server_driver_on_the_emulated_program(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("THERMOCOMP_ROBOT__DRIVER", "c500c-server")
    settings = load_settings(Path(SIM))
    async with open_devices(settings, ScaledClock()) as devices:
        assert isinstance(devices.robot, C500CServerRobot)
        assert isinstance(devices.emulator, C500CServerEmulator)
        assert devices.bench is not None
        goal = await devices.robot.teach_goal()
        result = await devices.robot.move_absolute((0.0123, 0.0, 0.0))
        # The bench's truth follows the emulated arm the driver moved.
        assert devices.emulator.actual_pose()[0] == pytest.approx(result.actual.x, abs=5e-5)
        assert result.actual.x == pytest.approx(goal.x + 0.0123, abs=0.005)
    assert devices.emulator.server_config.silence_timeout_s == settings.robot.server_silence_s


async def test_without_the_bench_the_fast_path_is_a_real_driver(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # bench disabled: c500c-server is the real program on robot.server_port, not a sim device.
    monkeypatch.setenv("THERMOCOMP_ROBOT__DRIVER", "c500c-server")
    monkeypatch.setenv("THERMOCOMP_BENCH__ENABLED", "false")
    settings = load_settings(Path(SIM))
    with pytest.raises(ConfigError) as caught:
        async with open_devices(settings, ScaledClock()):
            pass
    assert "camera.driver, ir.driver is 'sim'" in str(caught.value)
    assert "robot" not in str(caught.value)


@pytest.mark.slow
def test_a_bench_run_through_the_fast_path(tmp_path: Path) -> None:
    options = ["--data-dir", str(tmp_path), "--duration", "20", "--json"]
    result = run_main(["run", "--config", SIM, *options], env=FAST_PATH)
    assert result.returncode == 0, result.stderr
    final = json.loads(result.stdout)
    assert final["state"] == "finished"
    assert final["summary"]["n"] == 20 and final["summary"]["overruns"] == 0
    with Recorder(tmp_path) as recorder:
        steps = recorder.steps(final["id"])
    assert len(steps) == 20
    poses = [s.pose_x_mm for s in steps]
    assert all(p is not None for p in poses)
    # The fast path reads poses at 0.1 um: finer than the console's 0.001 mm grain.
    assert any(round(p * 1000) != p * 1000 for p in poses if p is not None)


def test_emulate_server_cli_serves_the_program_on_a_pty_until_terminated() -> None:
    process = subprocess.Popen(
        cli_command("emulate", "c500c", "--server", "--no-pacing", "--noise-um", "0"),
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None
        path = process.stdout.readline().strip()
        assert Path(path).resolve().is_char_device(), f"not a pty: {path!r}"

        async def converse() -> tuple[float, float, float]:
            settings = RobotSettings(driver="c500c-server", command_timeout_s=2.0)
            async with C500CServerRobot(settings, port=path) as robot:
                goal = await robot.teach_goal()
                result = await robot.move_absolute((0.1234, 0.0, 0.0))
            return (result.actual.x - goal.x, result.actual.y - goal.y, result.actual.z - goal.z)

        assert asyncio.run(converse()) == pytest.approx((0.1234, 0.0, 0.0), abs=1e-9)
    finally:
        process.terminate()
        process.wait(timeout=10)
        for stream in (process.stdout, process.stderr):
            if stream:
                stream.close()
    assert process.returncode == 0


def test_emulate_server_refuses_the_console_only_options() -> None:
    result = run_cli(["emulate", "c500c", "--server", "--shell"])
    assert result.returncode == 2 and "console's" in result.stderr
