"""A followed run's hold pauses the robot's own program through the Dashboard Server, after the
correction froze (robot.pause_program_on_hold; daemon/run/followed/program_pause.py).

Over the UR emulator on real TCP with the real UR driver, through the daemon: a hold, a
pause, a stop, a fault (the RTDE link dropped) and a shutdown each freeze the correction first
(the hold flag is already at the controller when the Dashboard's ``pause`` arrives, no
correction written after it) and then pause the program; the resume plays again what the hold
paused; a run that reaches its end does not pause the program; the setting off pauses
nothing; a Dashboard that refuses or hangs is noted in the errors and never raised into the
hold. ur-rtde's own DashboardClient reads the paused program in tests/test_ur_rtde_clients.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest

from config import CONFIG_DIR, Settings
from config.settings import load_settings
from daemon.run.events import ErrorLog, EventBus
from daemon.run.followed.program_pause import ProgramPause
from daemon.run.states import RunState, RunStateError
from daemon.service import Daemon
from drivers.errors import DeviceReportedError
from drivers.sim.ur.controller import URController
from drivers.sim.ur.emulator import UREmulator
from drivers.ur.dashboard_client import DashboardClient
from drivers.ur.modes import RuntimeState
from tests.fakes import params
from tests.loopback import loopback_host

WAIT_S = 60.0
#: The driver's link timeout here (robot.ur_timeout_s, 1 s by default): the emulated controller
#: runs in this process, so on a loaded machine (make test beside two busy loops) a second
#: without a state package is the test process starved, not a link fault; it held the robot
#: twice in one loaded run and the run never wrote its corrections. The fault this module
#: tests is a dropped connection (``drop_connections``), which a longer timeout does not slow.
LINK_TIMEOUT_S = 10.0


def ur_settings(tmp_path: Path, host: str, **robot: Any) -> Settings:
    """config/ur5e-sim.toml on ``host`` (a loopback address of the test's own), 10 Hz steps,
    without its tool cameras."""
    base = load_settings(CONFIG_DIR / "ur5e-sim.toml")
    return base.model_validate(
        {
            **base.model_dump(),
            "robot": {
                **base.robot.model_dump(),
                "host": host,
                "ur_timeout_s": LINK_TIMEOUT_S,
                **robot,
            },
            "scheduler": {**base.scheduler.model_dump(), "step_s": 0.1, "duration_s": 600.0},
            "storage": {**base.storage.model_dump(), "data_dir": str(tmp_path / "data")},
            # the pause is the Dashboard's: no tool camera to render (their holds with the
            # cameras measuring: tests/test_ur_followed_api.py)
            "arm": {**base.arm.model_dump(), "bench_cameras": False},
        }
    )


def emulator_of(daemon: Daemon) -> UREmulator:
    emulator = getattr(daemon.devices, "ur_emulator", None)
    assert isinstance(emulator, UREmulator)
    return emulator


async def until(condition: Callable[[], bool], what: str) -> None:
    async with asyncio.timeout(WAIT_S):
        while not condition():  # noqa: ASYNC110 -- the emulator's state, read not awaited
            await asyncio.sleep(0.01)
    assert condition(), what


class DashboardLog:
    """What the emulated controller's registers were when each Dashboard command arrived."""

    def __init__(self, emulator: UREmulator) -> None:
        self.controller = emulator.controller
        regs = self.controller.registers
        self.hold, self.target = regs.hold, regs.target[0]
        self.seen: list[tuple[str, int, int]] = []  # command, hold flag, corrections written
        answer = emulator.dashboard.answer

        def logged(command: str) -> str:
            c = self.controller
            self.seen.append((command, int(c.inputs[self.hold]), c.writes[self.target]))
            return answer(command)

        emulator.dashboard.answer = logged  # type: ignore[method-assign]

    def commands(self, word: str) -> list[tuple[str, int, int]]:
        return [entry for entry in self.seen if entry[0] == word]


async def follow(daemon: Daemon, settings: Settings) -> tuple[UREmulator, DashboardLog]:
    """A followed run started and writing corrections."""
    emulator = emulator_of(daemon)
    log = DashboardLog(emulator)
    await daemon.start_run(params(settings))
    await daemon.wait_state(RunState.RUNNING)
    await until(lambda: log.controller.writes[log.target] >= 3, "corrections written")
    return emulator, log


def runtime(emulator: UREmulator) -> RuntimeState:
    return emulator.controller.runtime_state


def paused_after_the_freeze(log: DashboardLog, written_at_hold: int) -> None:
    """The one ``pause`` the daemon sent came with the hold flag already set, and no
    correction was written between the hold and it."""
    pauses = log.commands("pause")
    assert len(pauses) == 1, log.seen
    _, hold_flag, written = pauses[0]
    assert hold_flag == 1  # the correction froze before the pause was asked
    assert written == written_at_hold


async def test_a_hold_pauses_the_program_after_the_freeze_and_the_resume_plays_it(
    tmp_path: Path,
) -> None:
    settings = ur_settings(tmp_path, loopback_host())
    async with Daemon(settings) as daemon:
        emulator, log = await follow(daemon, settings)
        assert runtime(emulator) is RuntimeState.PLAYING
        await daemon.hold_robot()  # the dashboard's Hold robot, POST /robot/stop
        await until(lambda: log.controller.inputs[log.hold] == 1, "the hold flag")
        written = log.controller.writes[log.target]  # nothing after the hold (the driver)
        await until(lambda: runtime(emulator) is RuntimeState.PAUSED, "program paused")
        assert daemon.run is not None and daemon.run.state is RunState.PAUSED
        paused_after_the_freeze(log, written)
        assert log.commands("programState")  # it was asked whether the program played

        await daemon.resume()
        await until(lambda: runtime(emulator) is RuntimeState.PLAYING, "program played again")
        assert log.controller.inputs[log.hold] == 0
        assert [c for c, *_ in log.seen].count("play") == 1
        await until(lambda: log.controller.writes[log.target] > written, "corrections again")

        log.seen.clear()
        await daemon.pause()  # an operator's pause of the run
        await until(lambda: runtime(emulator) is RuntimeState.PAUSED, "paused by the pause")
        written = log.controller.writes[log.target]
        paused_after_the_freeze(log, written)
        final = await daemon.stop()  # a stop while paused: the program stays paused, once
        assert final["state"] == "stopped"
        assert len(log.commands("pause")) == 1
        assert runtime(emulator) is RuntimeState.PAUSED
        assert not [e for e in daemon.recent_errors() if "could not" in e["message"]]


async def test_a_stop_and_a_fault_pause_the_program_a_finished_run_does_not(
    tmp_path: Path,
) -> None:
    settings = ur_settings(tmp_path, loopback_host())
    async with Daemon(settings) as daemon:
        emulator, log = await follow(daemon, settings)
        final = await daemon.stop()
        assert final["state"] == "stopped"
        assert runtime(emulator) is RuntimeState.PAUSED
        paused_after_the_freeze(log, log.controller.writes[log.target])

        # the operator plays it again on the pendant; a new run follows it; the RTDE link
        # drops: the step faults, the hold freezes the correction, then the program pauses
        assert await daemon._control.run(lambda: emulator.controller.play(emulator.now()))
        log.seen.clear()
        await daemon.start_run(params(settings))
        await daemon.wait_state(RunState.RUNNING)
        await until(lambda: bool(daemon.run and daemon.run.step >= 2), "steps")
        emulator.rtde.drop_connections()
        assert await daemon.wait_state(RunState.FAULT) is RunState.FAULT
        await until(lambda: runtime(emulator) is RuntimeState.PAUSED, "paused by the fault")
        pauses = log.commands("pause")
        assert len(pauses) == 1
        # the link was down, so the flag may not have reached the controller; the driver's
        # permit was held by the link fault before the step faulted (no correction after it)
        await daemon.stop()

    short = settings.model_validate(
        {
            **settings.model_dump(),
            "scheduler": {**settings.scheduler.model_dump(), "duration_s": 0.5},
            "storage": {"data_dir": str(tmp_path / "short")},
        }
    )
    async with Daemon(short) as daemon:
        emulator, log = await follow_to_end(daemon, short)
        assert runtime(emulator) is RuntimeState.PLAYING  # its end is not a hold
        assert not log.commands("pause")


async def follow_to_end(daemon: Daemon, settings: Settings) -> tuple[UREmulator, DashboardLog]:
    emulator = emulator_of(daemon)
    log = DashboardLog(emulator)
    await daemon.start_run(params(settings))
    final = await daemon.wait_run()
    assert final["state"] == "finished", final
    return emulator, log


async def test_a_shutdown_pauses_the_program_and_the_setting_off_pauses_nothing(
    tmp_path: Path,
) -> None:
    host = loopback_host()
    settings = ur_settings(tmp_path, host)
    async with Daemon(settings) as daemon:
        emulator, log = await follow(daemon, settings)
        await daemon.shutdown()
        assert daemon.run is not None and daemon.run.state is RunState.STOPPED
        assert runtime(emulator) is RuntimeState.PAUSED
        paused_after_the_freeze(log, log.controller.writes[log.target])

    off = ur_settings(tmp_path / "off", host, pause_program_on_hold=False)
    async with Daemon(off) as daemon:
        emulator, log = await follow(daemon, off)
        await daemon.hold_robot()
        await until(lambda: log.controller.inputs[log.hold] == 1, "the hold flag")
        await daemon.stop()
        assert runtime(emulator) is RuntimeState.PLAYING
        assert not log.seen  # not a single Dashboard command


async def test_a_dashboard_that_refuses_is_noted_and_the_hold_stands(tmp_path: Path) -> None:
    settings = ur_settings(tmp_path, loopback_host())
    async with Daemon(settings) as daemon:
        emulator, log = await follow(daemon, settings)
        await daemon._control.call(emulator.dashboard.close)  # the Dashboard Server is gone
        started = time.monotonic()
        await daemon.hold_robot()
        assert time.monotonic() - started < settings.robot.command_timeout_s
        await until(lambda: log.controller.inputs[log.hold] == 1, "the hold flag")
        await until(
            lambda: any("could not pause" in e["message"] for e in daemon.recent_errors()),
            "the failure noted",
        )
        assert daemon.run is not None and daemon.run.state is RunState.PAUSED
        assert daemon.devices.robot.permit.held
        assert runtime(emulator) is RuntimeState.PLAYING  # nobody could pause it
        final = await daemon.stop()
        assert final["state"] == "stopped"


# -- ProgramPause over a real Dashboard client ------------------------------------------------


class Dashboard:
    """drivers.base.ProgramControl over the real Dashboard client."""

    def __init__(self, client: DashboardClient) -> None:
        self.client = client

    async def program_state(self) -> str:
        return await self.client.program_state()

    async def pause_program(self) -> None:
        await self.client.pause()

    async def play_program(self) -> None:
        await self.client.play()


@pytest.fixture
async def emulator() -> AsyncIterator[UREmulator]:
    async with UREmulator(host=loopback_host()) as ur:
        yield ur


def errors() -> ErrorLog:
    return ErrorLog(EventBus())


async def test_only_a_playing_program_is_paused_and_only_that_one_played_again(
    emulator: UREmulator,
) -> None:
    control = Dashboard(DashboardClient(emulator.host, emulator.dashboard_port, 5.0))
    log = errors()
    pause = ProgramPause(control, enabled=True, errors=log)
    controller: URController = emulator.controller
    assert controller.pause(emulator.now())  # the operator paused it on the pendant
    await pause.pause(5.0)
    assert not pause.paused and "pause" not in emulator.dashboard.commands
    await pause.play_again(5.0)
    assert controller.runtime_state is RuntimeState.PAUSED  # not ours to play
    assert controller.play(emulator.now())

    await pause.pause(5.0)
    assert pause.paused and controller.runtime_state is RuntimeState.PAUSED
    await pause.pause(5.0)  # paused already by it: nothing sent again
    assert emulator.dashboard.commands.count("pause") == 1
    await pause.play_again(5.0)
    assert controller.runtime_state is RuntimeState.PLAYING and not pause.paused
    assert len(log) == 0

    disabled = ProgramPause(control, enabled=False, errors=log)
    sent = len(emulator.dashboard.commands)
    await disabled.pause(5.0)
    assert len(emulator.dashboard.commands) == sent


async def test_a_refusal_and_a_silent_dashboard_are_noted_within_the_grace(
    emulator: UREmulator,
) -> None:
    class Refusing(Dashboard):
        async def pause_program(self) -> None:
            raise DeviceReportedError("robot", None, "Dashboard 'pause': Failed to execute")

    log = errors()
    refusing = ProgramPause(
        Refusing(DashboardClient(emulator.host, emulator.dashboard_port, 5.0)),
        enabled=True,
        errors=log,
    )
    await refusing.pause(5.0)  # does not raise
    assert not refusing.paused
    assert "could not pause" in log.recent()[-1]["message"]
    assert "Failed to execute" in log.recent()[-1]["message"]

    async def silent(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        with contextlib.suppress(OSError):
            await reader.read()  # accepts, never answers (not even the welcome line)
        writer.close()

    server = await asyncio.start_server(silent, "127.0.0.1", 0)  # a port of its own
    try:
        port = server.sockets[0].getsockname()[1]
        hanging = ProgramPause(
            Dashboard(DashboardClient("127.0.0.1", port, 30.0)), enabled=True, errors=log
        )
        started = time.monotonic()
        await hanging.pause(0.3)  # the grace bounds it, not the client's 30 s
        assert time.monotonic() - started < 5.0
        assert log.recent()[-1]["kind"] == "timeout"
        assert "no answer within 0.3 s" in log.recent()[-1]["message"]
    finally:
        server.close()
        await server.wait_closed()


async def test_a_hold_during_the_resume_pauses_the_program_it_played_again(
    tmp_path: Path,
) -> None:
    """A hold that lands while the resume plays the program again (here: as the Dashboard's
    ``play`` arrives) wins: the resume is refused and the program is paused again."""
    settings = ur_settings(tmp_path, loopback_host())
    async with Daemon(settings) as daemon:
        emulator, log = await follow(daemon, settings)
        await daemon.hold_robot()
        await until(lambda: runtime(emulator) is RuntimeState.PAUSED, "program paused")
        permit = daemon.devices.robot.permit
        answer = emulator.dashboard.answer

        def hold_on_play(command: str) -> str:
            if command == "play":
                permit.hold("held during the resume")  # as the API's thread holds it
            return answer(command)

        emulator.dashboard.answer = hold_on_play  # type: ignore[method-assign]
        with pytest.raises(RunStateError, match="during the resume"):
            await daemon.resume()
        assert "play" in [c for c, *_ in log.seen]
        await until(lambda: runtime(emulator) is RuntimeState.PAUSED, "paused again")
        assert daemon.run is not None and daemon.run.state is RunState.PAUSED
        assert len(log.commands("pause")) == 2
        await daemon.stop()
        assert runtime(emulator) is RuntimeState.PAUSED
