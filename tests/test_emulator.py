"""The C500C emulator: console semantics, exact bytes on a real pty, noise, faults, the CLI."""

from __future__ import annotations

import asyncio
import math
import signal
import subprocess
import time
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest
import serial_asyncio
from scipy import stats

from api.cli import main
from config.settings import RobotSettings
from drivers.base import LinkState
from drivers.c500c import protocol as proto
from drivers.c500c.robot import C500CRobot
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
    for name in ("opgoal", "cur", "p"):
        assert await c.execute(f"new {name}") == []
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
        ("frobnicate", "error: Unrecognized command."),
        ("wshift cur,1,2,3,0,0,0", "error: variable not found."),
        ("wshift opgoal,1,2,3", "error: missing comma."),
        ("wshift opgoal,1,2,3,0,0,0,9", "error: too many arguments."),
        ("wshift opgoal,1,x,3,0,0,0", "error: missing number."),
        ("move nowhere", "error: variable not found."),
        ("moves opgoal", "error: Straight-line moves are possible only in online mode"),
        ("speed 150", "error: Illegal speed chosen"),
        ("set opgoal = {2000, 0, 0, 0, 0, 0}", None),
        ("online maybe", "error: invalid argument."),
        ("new opgoal", "error: variable already exists."),
    ],
)
async def test_console_errors_use_the_firmware_texts(command: str, answer: str | None) -> None:
    c = console()
    await c.execute("new opgoal")
    lines = await c.execute(command)
    assert lines == ([] if answer is None else [answer])
    parsed = proto.first_error(lines)
    assert (parsed is None) is (answer is None)


async def test_a_new_name_asks_create_it() -> None:
    """docs/reference/c500c-console.md "Questions": `here`/`set` to a name that does not exist stops
    and asks."""
    c = console(noise_um=0.0)
    assert await c.execute("here spot") == ["Variable 'spot' not found."]
    assert c.prompt == b"  -- create it? "
    assert await c.execute("maybe") == []
    assert c.prompt == b"Please answer 'yes' or 'no': "
    assert await c.execute("no") == [] and "spot" not in c.state.locations
    assert c.prompt == PROMPT
    assert await c.execute("set spot = spot2") == ["error: variable not found."]
    await c.execute("here spot")
    assert await c.execute("yes") == [] and c.state.locations["spot"] == START_POSE


async def test_ash_without_an_application_asks_for_it() -> None:
    c = console(start_in_shell=True)
    assert c.prompt == b"$ "
    assert await c.execute("ash") == [] and c.prompt == b"Application name > "
    assert await c.execute("cell") == ["cell: application not found"] and c.prompt == b"$ "
    assert await c.execute("ash ash") == [] and c.prompt == PROMPT


async def test_a_restart_forgets_every_variable() -> None:
    c = console(online=True)
    await c.execute("new opgoal")
    c.restart()
    assert c.state.locations == {} and not c.state.online and c.prompt == b"$ "
    assert c.state.restarts == 1


def test_w2_prints_the_firmware_layout_by_default() -> None:
    c = console(noise_um=0.0)

    async def read() -> list[str]:
        return await c.execute("w2")

    lines = asyncio.run(read())
    assert lines[0] == proto.ACTUAL_TITLE and lines[7].startswith("WORLD")
    assert lines[8] == " " * 8 + " ".join(f"{v:+10.3f}" for v in START_POSE)
    assert proto.parse_position_table(lines).pulses == (0,) * 6
    old = console(layout="single-line")
    assert [line[:6] for line in asyncio.run(old.execute("w0"))[1:]] == [
        "PULSES",
        "JOINTS",
        "WORLD:",
    ]


async def test_motion_preconditions() -> None:
    c = console(online=True)
    await c.execute("new far")
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
    assert c.state.awaiting_button and c.state.commanded == START_POSE  # waits, nothing moved
    c.press_pause_continue()
    assert await c.wait_for_button() == []
    assert not c.state.awaiting_button and c.state.commanded[0] == START_POSE[0] + 1


async def test_positioning_noise_reproduces_the_thesis_spread() -> None:
    """Absolute moves to one goal: the sample deviation is the configured 0.9 um (the
    thesis's absolute-command S_x, Table 6.1) within the chi-squared 99.9 % interval."""
    c = Console(EmulatorConfig(paced=False, move_ms=0.0), np.random.default_rng(7))
    await c.execute("new opgoal")
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
        await c.execute("new g")
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
    config = EmulatorConfig(paced=False, faults=parse_faults("drop@3"), start_in_shell=True)
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
    assert await read_until(reader, b"name > ") == b"ash\r\nApplication name > "
    writer.write(b"ash\r")
    assert await read_until(reader, PROMPT) == b"ash\r\nash> "
    writer.write(b"wx 1\x05")  # Ctrl-E discards the half-typed line
    assert await read_until(reader, PROMPT) == b"wx 1\r\nash> "
    writer.write(b"speed\r")  # the 3rd command line: its answer is dropped
    assert await read_until(reader, b"\r\n") == b"speed\r\n"
    writer.write(b"speed\r")
    assert await read_until(reader, PROMPT) == b"speed\r\nspeed = 10%\r\nash> "
    writer.write(b"nope\r")
    assert await read_until(reader, PROMPT) == b"nope\r\nerror: Unrecognized command.\r\nash> "
    assert emulator.faults_applied == [(3, "drop")]
    assert list(emulator.state.commands) == ["ash", "ash", "speed", "speed", "nope"]


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
    """The emulator as a process: a move waits for the point of control until SIGUSR1 (the
    button); SIGTERM stops it at once, and it says so (issue 21)."""
    process = subprocess.Popen(
        cli_command(
            "emulate", "c500c", "--pty", "--no-pacing", "--noise-um", "0", "--no-point-of-control"
        ),
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
                move = asyncio.create_task(robot.move_absolute((0.123, 0.0, 0.0)))
                await robot.wait_link(LinkState.AWAITING_POINT_OF_CONTROL, 10.0)
                process.send_signal(signal.SIGUSR1)  # the operator presses PAUSE/CONTINUE
                result = await move
            return (result.actual.x - goal.x, result.actual.y - goal.y, result.actual.z - goal.z)

        assert asyncio.run(converse()) == pytest.approx((0.123, 0.0, 0.0))
        signalled = time.monotonic()
        process.terminate()
        assert process.stdout.readline().strip() == "thermocomp emulate: stopped"
        process.wait(timeout=10)
        exited_s = time.monotonic() - signalled
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=10)
        for stream in (process.stdout, process.stderr):
            if stream:
                stream.close()
    assert process.returncode == 0
    assert exited_s < 0.5  # ~0.05 s on the development machine


def test_cli_rejects_bad_faults(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["emulate", "c500c", "--faults", "drop"])
    assert exited.value.code == 2
    assert "say when with @N or %P" in capsys.readouterr().err
