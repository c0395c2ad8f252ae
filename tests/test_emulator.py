"""The C500C emulator: console semantics, exact bytes on a real pty, noise, faults, the CLI."""

from __future__ import annotations

import asyncio
import math
import subprocess
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest
import serial_asyncio
from scipy import stats

from api.cli import main
from config.settings import RobotSettings
from drivers import c500c_protocol as proto
from drivers.c500c import C500CRobot
from drivers.sim.emulator import (
    COMMAND_LOG_LINES,
    START_POSE,
    C500CEmulator,
    Console,
    EmulatorConfig,
    Fault,
    parse_faults,
)
from tests.helpers import REPO_ROOT, cli_command

PROMPT = b"ash> "


def console(**overrides: object) -> Console:
    config = EmulatorConfig(paced=False, move_ms=0.0, **overrides)  # type: ignore[arg-type]
    return Console(config, np.random.default_rng(0))


async def test_location_commands_and_absolute_moves() -> None:
    c = console(noise_um=0.0, online=True)
    assert await c.execute("here opgoal") == []
    assert await c.execute("set cur = opgoal") == []
    assert await c.execute("wshift cur,0.5,-0.25,1,0,0,0") == []
    assert await c.execute("moves cur") == []
    assert await c.execute("finish") == []
    pose = proto.parse_world_pose(await c.execute("w2"))
    assert pose.position == pytest.approx((START_POSE[0] + 0.5, -0.25, START_POSE[2] + 1.0))
    assert await c.execute("set p = {100, 0, 300, 0, 90, 0}") == []
    await c.execute("move p")
    assert proto.parse_world_pose(await c.execute("w0")).position == (100.0, 0.0, 300.0)


async def test_the_command_log_is_bounded_but_counts_every_line() -> None:
    """A sim daemon sends ~250 lines a second for days: the log keeps only the latest."""
    c = console()
    for _ in range(COMMAND_LOG_LINES + 5):
        await c.execute("speed")
    assert len(c.state.commands) == COMMAND_LOG_LINES
    assert c.state.received == COMMAND_LOG_LINES + 5


@pytest.mark.parametrize(
    ("command", "answer"),
    [
        ("frobnicate", "Unrecognized command."),
        ("wshift cur,1,2,3,0,0,0", "variable not found."),
        ("wshift opgoal,1,2,3", "missing comma."),
        ("wshift opgoal,1,2,3,0,0,0,9", "too many arguments."),
        ("wshift opgoal,1,x,3,0,0,0", "missing number."),
        ("move nowhere", "variable not found."),
        ("moves opgoal", "error: Straight-line moves are possible only in online mode"),
        ("speed 150", "error: Illegal speed chosen"),
        ("set far = {2000, 0, 0, 0, 0, 0}", None),
        ("online maybe", "invalid argument."),
    ],
)
async def test_console_errors_use_the_firmware_texts(command: str, answer: str | None) -> None:
    c = console()
    await c.execute("here opgoal")
    lines = await c.execute(command)
    assert lines == ([] if answer is None else [answer])


async def test_motion_preconditions() -> None:
    c = console(online=True)
    await c.execute("set far = {2000, 0, 0, 0, 0, 0}")
    assert await c.execute("move far") == ["error: Location out of reach"]
    await c.execute("armpower off")
    assert await c.execute("wx 1") == ["error: Arm power is OFF"]
    await c.execute("armpower on")
    c.state.homed = False
    assert await c.execute("wx 1") == ["error: Not homed or not calibrated"]
    await c.execute("home")
    c.state.point_of_control = False
    assert await c.execute("wx 1") == [proto.POINT_OF_CONTROL_MESSAGE]
    assert c.state.commanded == START_POSE  # nothing moved


async def test_positioning_noise_reproduces_the_thesis_spread() -> None:
    """Absolute moves to one goal: the sample deviation is the configured 0.9 um (the
    thesis's absolute-command S_x, Table 6.1) within the chi-squared 99.9 % interval."""
    c = Console(EmulatorConfig(paced=False, move_ms=0.0), np.random.default_rng(7))
    await c.execute("here opgoal")
    n = 400
    errors = []
    for _ in range(n):
        await c.execute("move opgoal")
        errors.append((c.state.actual[0] - START_POSE[0]) * 1000.0)
    s2 = float(np.var(errors, ddof=1))
    low, high = stats.chi2.ppf([0.0005, 0.9995], n - 1) * 0.9**2 / (n - 1)
    assert low < s2 < high
    assert abs(np.mean(errors)) < 4 * 0.9 / math.sqrt(n)


async def test_same_seed_same_positions() -> None:
    async def run(seed: int) -> list[tuple[float, ...]]:
        c = Console(
            EmulatorConfig(paced=False, move_ms=0.0, seed=seed), np.random.default_rng(seed)
        )
        await c.execute("here g")
        poses = []
        for _ in range(5):
            await c.execute("move g")
            poses.append(c.state.actual)
        return poses

    assert await run(3) == await run(3)
    assert await run(3) != await run(4)


def test_fault_specs() -> None:
    assert parse_faults("drop@5, delay=2.5@7,corrupt%0.25,close@9,stall=1@2") == (
        Fault("drop", None, 5),
        Fault("delay", 2.5, 7),
        Fault("corrupt", None, None, 0.25),
        Fault("close", None, 9),
        Fault("stall", 1.0, 2),
    )
    assert parse_faults("") == ()
    for bad in ("explode@1", "drop", "drop%2", "delay=x@1", "drop@-1"):
        with pytest.raises(ValueError, match="bad fault"):
            parse_faults(bad)


RawLink = tuple[C500CEmulator, asyncio.StreamReader, asyncio.StreamWriter]


@pytest.fixture
async def raw_link() -> AsyncIterator[
    tuple[C500CEmulator, asyncio.StreamReader, asyncio.StreamWriter]
]:
    config = EmulatorConfig(paced=False, faults=parse_faults("drop@2"), start_in_shell=True)
    async with C500CEmulator(config) as emulator:
        reader, writer = await serial_asyncio.open_serial_connection(url=emulator.device_path)
        try:
            yield emulator, reader, writer
        finally:
            writer.transport.abort()


async def read_until(reader: asyncio.StreamReader, end: bytes) -> bytes:
    return await asyncio.wait_for(reader.readuntil(end), 2.0)


async def test_exact_bytes_on_the_pty(
    raw_link: RawLink,
) -> None:
    emulator, reader, writer = raw_link
    assert await read_until(reader, b"$ ") == b"$ "  # the system shell greets first
    writer.write(b"ash\r\n")  # CRLF from the host counts as one line end
    assert await read_until(reader, PROMPT) == b"ash\r\nash> "
    writer.write(b"wx 1\x05")  # Ctrl-E discards the half-typed line
    assert await read_until(reader, PROMPT) == b"wx 1\r\nash> "
    writer.write(b"speed\r")  # the 2nd command line: its answer is dropped
    assert await read_until(reader, b"\r\n") == b"speed\r\n"
    writer.write(b"speed\r")
    assert await read_until(reader, PROMPT) == b"speed\r\nspeed = 10%\r\nash> "
    assert emulator.faults_applied == [(2, "drop")]
    assert list(emulator.state.commands) == ["ash", "speed", "speed"]


async def test_probabilistic_faults_are_seeded() -> None:
    async def struck(seed: int) -> list[int]:
        config = EmulatorConfig(paced=False, seed=seed, faults=parse_faults("corrupt%0.3"))
        async with C500CEmulator(config) as emulator:
            reader, writer = await serial_asyncio.open_serial_connection(url=emulator.device_path)
            try:
                garbled = []
                for number in range(1, 13):
                    writer.write(b"speed\r")
                    answer = await read_until(reader, PROMPT)
                    if any(byte > 0x7E for byte in answer):
                        garbled.append(number)
            finally:
                writer.transport.abort()
            assert garbled == [number for number, _ in emulator.faults_applied]
        return garbled

    first = await struck(5)
    assert first and first == await struck(5)
    assert first != await struck(6)


def test_cli_serves_a_pty_until_terminated() -> None:
    process = subprocess.Popen(
        cli_command("emulate", "c500c", "--pty", "--no-pacing", "--noise-um", "0"),
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
            async with C500CRobot(RobotSettings(command_timeout_s=2.0), port=path) as robot:
                goal = await robot.teach_goal()
                result = await robot.move_absolute((0.123, 0.0, 0.0))
            return (result.actual.x - goal.x, result.actual.y - goal.y, result.actual.z - goal.z)

        assert asyncio.run(converse()) == pytest.approx((0.123, 0.0, 0.0))
    finally:
        process.terminate()
        process.wait(timeout=10)
        for stream in (process.stdout, process.stderr):
            if stream:
                stream.close()
    assert process.returncode == 0


def test_cli_rejects_bad_faults(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["emulate", "c500c", "--faults", "drop"])
    assert exited.value.code == 2
    assert "say when with @N or %P" in capsys.readouterr().err
