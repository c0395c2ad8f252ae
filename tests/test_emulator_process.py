"""The emulated C500C in its own process (bench.emulator = "process", issue 30): a real child
process (``thermocomp emulate c500c``) on a real pty, the real drivers, the real clock."""

from __future__ import annotations

import asyncio
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from config import ConfigError, load_settings
from config.settings import RobotSettings, Settings
from daemon.run.session import ResumeRefusedError
from daemon.run.states import RunParameters, RunState
from daemon.service import Daemon
from daemon.storage.recorder import Recorder
from drivers.base import LinkState
from drivers.c500c import server_protocol as proto
from drivers.c500c.server import C500CServerRobot
from drivers.clock import make_clock
from drivers.factory import Devices, open_devices
from drivers.sim import emulator_process
from drivers.sim.emulator_process import SHARED_POSE_PREFIX, EmulatorProcess, EmulatorProcessError
from drivers.sim.server_emulator import C500CServerEmulator, server_emulator_config
from tests.helpers import REPO_ROOT

SIM = Path("config/sim.toml")
PROCESS = {
    "THERMOCOMP_BENCH__CLOCK": "real",
    "THERMOCOMP_BENCH__EMULATOR": "process",
    "THERMOCOMP_ROBOT__DRIVER": "c500c-server",
}


def shm_names() -> set[str]:
    """The shared pose blocks of this process's emulators (named with its pid: other tests on
    other xdist workers make shared memory of their own at the same time)."""
    mine = f"{SHARED_POSE_PREFIX}{os.getpid()}-"
    return {name for name in os.listdir("/dev/shm") if name.startswith(mine)}


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is gone for our purpose only once reaped; asyncio reaps its own children
    with open(f"/proc/{pid}/stat") as stat:
        return stat.read().split(")")[-1].split()[0] != "Z"


def is_pty(path: str) -> bool:
    return Path(path).resolve().is_char_device()


def exists(path: Path) -> bool:
    return path.exists()


def robot_settings() -> RobotSettings:
    return RobotSettings(driver="c500c-server", command_timeout_s=2.0)


async def test_the_child_serves_the_same_arm_as_the_inline_emulator() -> None:
    # Same seed, same moves: the child's shared pose is the inline emulator's pose, to the bit
    # (the positioning noise is drawn from the same seeded generator).
    before = shm_names()
    moves = [(0.0123, 0.0, 0.0), (0.05, -0.02, 0.01), (-0.1, 0.0, 0.003)]
    arguments = ["--server", "--seed", "7", "--noise-um", "0.9", "--no-pacing"]
    inline = C500CServerEmulator(server_emulator_config(seed=7, noise_um=0.9, paced=False))
    async with EmulatorProcess(arguments) as child, inline:
        assert is_pty(child.device_path)
        assert child.actual_pose() == inline.actual_pose()
        names = []
        for emulator_path in (child.device_path, inline.device_path):
            async with C500CServerRobot(robot_settings(), port=emulator_path) as robot:
                await robot.teach_goal()
                for delta in moves:
                    result = await robot.move_absolute(delta)
                    names.append(result.actual)
        assert names[: len(moves)] == names[len(moves) :]
        assert child.actual_pose() == inline.actual_pose()
        assert child.actual_pose()[0] == pytest.approx(names[len(moves) - 1].x, abs=5e-5)
        pid = child.pid
        assert pid is not None and shm_names() == before  # unlinked once the child attached
    assert not alive(pid)
    assert not exists(Path(child.device_path).parent)  # the directory of its link is gone


async def test_a_child_that_cannot_start_is_one_error_with_its_words() -> None:
    before = shm_names()
    with pytest.raises(EmulatorProcessError) as caught:
        async with EmulatorProcess(["--server", "--shell"]):
            pass
    message = str(caught.value)
    assert "did not start" in message and "--shell are the console's" in message
    assert "\n" not in message
    assert shm_names() == before


def test_the_child_ends_when_the_daemon_is_killed() -> None:
    # The parent dies at once (SIGKILL: no cleanup of its own); the child sees its stdin close.
    parent = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import asyncio, sys\n"
            "from pathlib import Path\n"
            "from drivers.sim.emulator_process import EmulatorProcess\n"
            "async def main():\n"
            "    async with EmulatorProcess(['--no-pacing']) as child:\n"
            "        print(child.pid, flush=True)\n"
            "        print(Path(child.device_path).parent, flush=True)\n"
            "        await asyncio.sleep(60)\n"
            "asyncio.run(main())\n",
        ],
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert parent.stdout is not None
    child_pid = int(parent.stdout.readline())
    link_directory = Path(parent.stdout.readline().strip())
    assert link_directory.is_dir()
    parent.kill()
    parent.wait(timeout=10)
    parent.stdout.close()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and os.path.exists(f"/proc/{child_pid}"):
        time.sleep(0.05)
    outlived = os.path.exists(f"/proc/{child_pid}")
    if outlived:
        os.kill(child_pid, signal.SIGKILL)  # no orphan left by a failing test
    assert not outlived, "the emulator outlived its daemon"
    assert not link_directory.exists(), "the emulator left its link's directory behind"


@pytest.mark.parametrize(
    ("env", "words"),
    [
        ({"THERMOCOMP_BENCH__CLOCK": "virtual"}, "bench.clock virtual"),
        ({"THERMOCOMP_BENCH__CLOCK": "accelerated"}, "bench.clock accelerated"),
        ({"THERMOCOMP_ROBOT__DRIVER": "ur-rtde"}, "robot.driver ur-rtde"),
        ({"THERMOCOMP_ARM__ENABLED": "true", "THERMOCOMP_ROBOT__DRIVER": "sim"}, "arm.enabled"),
    ],
)
def test_process_is_refused_where_no_clock_or_emulator_can_be_shared(
    env: dict[str, str], words: str
) -> None:
    with pytest.raises(ConfigError) as caught:
        load_settings(SIM, {**PROCESS, **env})
    message = str(caught.value)
    assert "\n" not in message
    assert "bench.emulator 'process' needs bench.clock real" in message and words in message


def test_process_is_accepted_for_both_emulated_links() -> None:
    assert load_settings(SIM, PROCESS).bench.emulator == "process"
    console = load_settings(SIM, {**PROCESS, "THERMOCOMP_ROBOT__DRIVER": "sim"})
    assert console.bench.emulator == "process"
    assert load_settings(SIM, {}).bench.emulator == "inline"


async def test_the_factory_runs_the_console_in_its_own_process() -> None:
    # robot.driver sim: the console's driver (C500CRobot) on the child's pty; the bench follows
    # the arm the driver moved, through the shared pose.
    settings = load_settings(
        SIM,
        {**PROCESS, "THERMOCOMP_ROBOT__DRIVER": "sim", "THERMOCOMP_BENCH__ROBOT_NOISE_UM": "0"},
    )
    async with open_devices(settings, make_clock("real", 1.0)) as devices:
        assert devices.emulator is None and devices.emulator_process is not None
        assert devices.bench is not None
        goal = await devices.robot.teach_goal()
        await devices.robot.move_absolute((0.012, -0.004, 0.0))  # the console's 1 um grain
        offset = devices.bench.robot_offset_um()
        assert offset[0] == pytest.approx(12.0, abs=1e-6)
        assert offset[1] == pytest.approx(-4.0, abs=1e-6)
        pose = await devices.robot.actual_pose()
        assert 1000 * (pose.x - goal.x) == pytest.approx(offset[0], abs=1e-6)
        pid = devices.emulator_process.pid
        assert pid is not None
    assert not alive(pid)


def _settings(tmp_path: Path, **extra: str) -> Settings:
    env = {
        **PROCESS,
        "THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path),
        "THERMOCOMP_STORAGE__REPORT_AT_END": "false",
        "THERMOCOMP_SCHEDULER__STEP_S": "0.1",
        "THERMOCOMP_SCHEDULER__DURATION_S": "600",
        **extra,
    }
    return load_settings(SIM, env)


@pytest.mark.slow
async def test_a_real_clock_run_steps_measures_and_its_hold_reaches_the_child(
    tmp_path: Path,
) -> None:
    settings = _settings(tmp_path)
    before = shm_names()
    daemon = Daemon(settings, clock=make_clock("real", 1.0))
    async with daemon:
        devices = daemon.devices
        assert isinstance(devices, Devices)
        process = devices.emulator_process
        assert process is not None and process.running
        info = await daemon.start_run(RunParameters.from_settings(settings))
        await daemon.wait_state(RunState.RUNNING)
        await asyncio.sleep(3.0)
        final = await daemon.stop()
        status = daemon.devices.robot.status()
        flags = int(status.extra["controller_flags"])
        # the HOLD frame reached the child: its own reply says it holds
        assert flags & proto.Flag.HELD, status
        pid = process.pid
    assert final["state"] == "stopped"
    with Recorder(tmp_path) as recorder:
        steps = recorder.steps(info["id"])
    assert len(steps) >= 10
    measured = [s for s in steps if s.drift_x_um is not None and s.pose_x_mm is not None]
    assert len(measured) >= len(steps) - 1
    assert pid is not None and not alive(pid)
    assert shm_names() == before


@pytest.mark.slow
async def test_a_child_killed_mid_run_faults_the_run_in_one_line_and_leaks_nothing(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The emulated controller dies (SIGKILL): the driver sees a cut cable, the run faults with
    # the robot held; a fresh controller starts behind the same path (restarted at once here:
    # a real one that died young is not, MIN_LIFETIME_S) and the driver's reconnection finds
    # it; resuming is refused in one line (the fresh controller forgot the goal).
    monkeypatch.setattr(emulator_process, "MIN_LIFETIME_S", 0.0)
    settings = _settings(tmp_path)
    before = shm_names()
    daemon = Daemon(settings, clock=make_clock("real", 1.0))
    with caplog.at_level(logging.WARNING):
        async with daemon:
            devices = daemon.devices
            assert isinstance(devices, Devices)
            process = devices.emulator_process
            assert process is not None
            await daemon.start_run(RunParameters.from_settings(settings))
            await daemon.wait_state(RunState.RUNNING)
            await asyncio.sleep(0.5)
            killed = process.pid
            assert killed is not None
            os.kill(killed, signal.SIGKILL)
            state = await asyncio.wait_for(daemon.wait_state(RunState.FAULT), timeout=30)
            assert state is RunState.FAULT
            robot = daemon.devices.robot
            assert robot.status().motion_held
            assert "link lost" in daemon.snapshot()["run"]["reason"]
            async with asyncio.timeout(30):
                while robot.status().link is not LinkState.CONNECTED:  # noqa: ASYNC110 -- a driver's state, polled
                    await asyncio.sleep(0.1)
            assert process.starts == 2 and process.pid != killed
            with pytest.raises(ResumeRefusedError, match="start a new run"):
                await daemon.resume()
            restarted = process.pid
    lines = [r.getMessage() for r in caplog.records if "emulated controller" in r.getMessage()]
    died = [line for line in lines if f"process {killed} was killed by SIGKILL" in line]
    assert len(died) == 1 and "starting a fresh controller" in died[0], lines
    assert not alive(killed) and restarted is not None and not alive(restarted)
    assert shm_names() == before
