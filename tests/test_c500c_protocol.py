"""The C500C console protocol: pure functions, and the driver replaying exact byte exchanges.

The driver tests work like pymeasure's ``expected_protocol``: a scripted console checks every
byte the driver sends against the recorded exchange, answers with the recorded bytes, and the
test fails unless every exchange was used.
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence
from typing import Any

import pytest

from config.settings import RobotSettings
from drivers import c500c_protocol as proto
from drivers.base import LinkState, Pose
from drivers.c500c import C500CRobot, _Connection
from drivers.errors import (
    DeviceReportedError,
    MotionHeldError,
    PointOfControlError,
    ProtocolError,
)

PROMPT = b"ash> "

# --- pure functions -----------------------------------------------------------------------------


def test_encode_command_appends_the_host_line_end() -> None:
    assert proto.encode_command("w2") == b"w2\r"
    for bad in ("", "w2\r", "move\x05", "wx 1\n", "caf\u00e9"):
        with pytest.raises(ValueError):
            proto.encode_command(bad)


@pytest.mark.parametrize(
    ("buffer", "complete"),
    [
        (b"ash> ", True),
        (b"w2\r\nash> ", True),
        (b"w2\r\nash>", False),  # prompt not finished
        (b"w2\r\nxash> ", False),  # not at the start of a line
        (b"w2\r\n", False),
        (b"", False),
    ],
)
def test_find_prompt(buffer: bytes, complete: bool) -> None:
    assert (proto.find_prompt(buffer, PROMPT) is not None) is complete


def test_split_reply_strips_echo_and_prompt() -> None:
    raw = b"speed\r\nspeed = 10%\r\nash> "
    assert proto.split_reply(raw, "speed", PROMPT) == ["speed = 10%"]
    assert proto.split_reply(b"here opgoal\r\nash> ", "here opgoal", PROMPT) == []


@pytest.mark.parametrize(
    "raw",
    [
        b"w3\r\nash> ",  # echo of another command
        b"w2\r\n\x8fash> ",  # a byte the console never sends
        b"w2\r\nWORLD: +1.000ash> ",  # unterminated line (prompt glued to it)
        b"w2\r\nabc\rdef\r\nash> ",  # stray CR inside a line
        b"w2\r\nWORLD\r\n",  # no prompt at all
    ],
)
def test_split_reply_rejects_garbled_replies(raw: bytes) -> None:
    with pytest.raises(ProtocolError):
        proto.split_reply(raw, "w2", PROMPT)


def test_error_lines_map_to_catalogue_numbers() -> None:
    assert proto.parse_error_line("WORLD:  +1.000") is None
    assert proto.parse_error_line("Unrecognized command.") == proto.ConsoleError(
        None, "Unrecognized command."
    )
    online = proto.parse_error_line("error: Straight-line moves are possible only in online mode")
    assert online == proto.ConsoleError(43, "Straight-line moves are possible only in online mode")
    joint = proto.parse_error_line("error: Joint 3 limit exceeded")
    assert joint is not None and joint.code == 1
    unknown = proto.parse_error_line("error: Something new")
    assert unknown == proto.ConsoleError(None, "Something new")
    for code, text in proto.MOTION_ERRORS.items():
        line = proto.format_error(code, text.replace("$1", "2"))
        parsed = proto.parse_error_line(line)
        assert parsed is not None and parsed.code == code


W2_LINES = [
    "                 1         2         3         4         5         6",
    "PULSES:   +100.000    -2.500    +0.000    +0.000    +0.000    +0.000",
    "JOINTS:     +1.000    +2.000    +3.000    +4.000    +5.000    +6.000",
    "WORLD:    +457.213   -12.001  +254.000    +0.000   +90.000  -180.000",
]


def test_w_table_is_parsed_row_by_row() -> None:
    rows = proto.parse_w_table(W2_LINES)
    assert rows["JOINTS"] == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    assert proto.parse_world_pose(W2_LINES) == Pose(457.213, -12.001, 254.0, 0.0, 90.0, -180.0)


def test_w_table_round_trips_through_the_emulator_format() -> None:
    world = (457.2134, -0.0004, 1234.5, -0.5, 90.0, 180.0)
    lines = proto.format_w_table(world, (0.0,) * 6, (0.0,) * 6)
    pose = proto.parse_world_pose(lines)
    assert pose.position == pytest.approx((457.213, -0.0, 1234.5), abs=1e-12)
    assert all(len(line) == len(lines[1]) for line in lines[1:])


@pytest.mark.parametrize(
    "mutate",
    [
        lambda lines: lines[:-1],  # WORLD row missing
        lambda lines: [*lines, lines[-1]],  # row twice
        lambda lines: [*lines[:-1], lines[-1].replace("+457.213", "+457.21 ")],  # 2 decimals
        lambda lines: [*lines[:-1], lines[-1].replace("-180.000", "")],  # five values
        lambda lines: [*lines[:-1], lines[-1].replace("+254", "+2x4")],  # not a number
    ],
)
def test_w_table_rejects_damaged_tables(mutate: Any) -> None:
    with pytest.raises(ProtocolError):
        proto.parse_w_table(mutate(list(W2_LINES)))


def test_absolute_sequence_rounds_to_the_console_resolution() -> None:
    commands, commanded = proto.absolute_move_commands((0.0123, -0.00049, 1.0006), online=True)
    assert commanded == (0.012, 0.0, 1.001)
    assert commands == [
        "set cur = opgoal",
        "wshift cur,0.012,0.000,1.001,0,0,0",
        "moves cur",
        "finish",
        "w2",
    ]
    assert proto.absolute_move_commands((0, 0, 0), online=False)[0][2] == "move cur"


def test_incremental_sequence_moves_only_non_zero_axes() -> None:
    commands, commanded = proto.incremental_move_commands((0.002, 0.0001, -0.0104))
    assert commanded == (0.002, 0.0, -0.01)
    assert commands == ["wx 0.002", "wz -0.010", "finish", "w2"]


# --- the driver against recorded exchanges -----------------------------------------------------


class _ScriptedTransport(asyncio.Transport):
    """Checks what the driver writes against the script and feeds the recorded answers."""

    def __init__(self, reader: asyncio.StreamReader, script: Sequence[tuple[bytes, bytes]]):
        super().__init__()
        self.reader = reader
        self.script = list(script)
        self.used = 0
        self.mismatch: str | None = None
        self.closed = False

    def write(self, data: bytes | bytearray | memoryview) -> None:
        sent = bytes(data)
        if self.used >= len(self.script):
            self.mismatch = f"unexpected write {sent!r} after the script ended"
            return
        expected, answer = self.script[self.used]
        if sent != expected:
            self.mismatch = f"exchange {self.used}: sent {sent!r}, expected {expected!r}"
            return
        self.used += 1
        if answer:
            self.reader.feed_data(answer)

    def is_closing(self) -> bool:
        return self.closed

    def abort(self) -> None:
        self.closed = True

    def close(self) -> None:
        self.closed = True


class ScriptedRobot(C500CRobot):
    def __init__(self, script: Sequence[tuple[bytes, bytes]], **settings: Any) -> None:
        super().__init__(RobotSettings(command_timeout_s=0.5, **settings), port="scripted")
        self.script = script
        self.transport: _ScriptedTransport | None = None

    async def _open_port(self) -> _Connection:
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader()
        protocol = asyncio.StreamReaderProtocol(reader)
        self.transport = _ScriptedTransport(reader, self.script)
        writer = asyncio.StreamWriter(self.transport, protocol, reader, loop)
        return _Connection(reader, writer)

    def assert_all_used(self) -> None:
        assert self.transport is not None
        assert self.transport.mismatch is None, self.transport.mismatch
        assert self.transport.used == len(self.script), (
            f"only {self.transport.used} of {len(self.script)} exchanges used"
        )


def _world(x: str, y: str, z: str) -> bytes:
    header = "        " + "".join(f"{n:>10}" for n in "123456")
    zeros = "    +0.000" * 6
    return (
        f"{header}\r\nPULSES: {zeros}\r\nJOINTS: {zeros}\r\n"
        f"WORLD:  {x:>10}{y:>10}{z:>10}    +0.000   +90.000    +0.000\r\n"
    ).encode()


CONNECT = [
    (b"\x05", b"\r\nash> "),  # Ctrl-E: a clean line
    (b"\r", b"\r\nash> "),
    (b"online on\r", b"online on\r\nash> "),
]
TEACH = [
    (b"here opgoal\r", b"here opgoal\r\nash> "),
    (b"w2\r", b"w2\r\n" + _world("+457.200", "+0.000", "+254.000") + b"ash> "),
]


async def test_connect_teach_and_absolute_move_exchange() -> None:
    script = [
        *CONNECT,
        *TEACH,
        (b"set cur = opgoal\r", b"set cur = opgoal\r\nash> "),
        (b"wshift cur,0.012,-0.003,0.000,0,0,0\r", b"wshift cur,0.012,-0.003,0.000,0,0,0\r\nash> "),
        (b"moves cur\r", b"moves cur\r\nash> "),
        (b"finish\r", b"finish\r\nash> "),
        (b"w2\r", b"w2\r\n" + _world("+457.213", "-0.003", "+253.999") + b"ash> "),
    ]
    robot = ScriptedRobot(script)
    async with robot:
        assert robot.status().link is LinkState.CONNECTED
        assert await robot.teach_goal() == Pose(457.2, 0.0, 254.0, 0.0, 90.0, 0.0)
        result = await robot.move_absolute((0.01249, -0.0031, 0.0))
    robot.assert_all_used()
    assert result.commanded_mm == (0.012, -0.003, 0.0)
    assert result.rounding_mm == pytest.approx((-0.00049, 0.0001, 0.0))
    assert result.actual.position == (457.213, -0.003, 253.999)
    assert result.bytes_sent == sum(len(sent) for sent, _ in script[-5:])
    assert result.bytes_received == sum(len(answer) for _, answer in script[-5:])


async def test_shell_prompt_at_connect_starts_ash() -> None:
    script = [
        (b"\x05", b"\r\n$ "),
        (b"\r", b"\r\n$ "),
        (b"ash\r", b"ash\r\nash> "),
        (b"online on\r", b"online on\r\nash> "),
    ]
    robot = ScriptedRobot(script)
    async with robot:
        assert robot.status().online is True
    robot.assert_all_used()


async def test_device_error_is_reported_with_its_number_and_holds_motion() -> None:
    script = [
        *CONNECT[:2],
        *TEACH,
        (b"set cur = opgoal\r", b"set cur = opgoal\r\nash> "),
        (b"wshift cur,0.000,0.000,0.000,0,0,0\r", b"wshift cur,0.000,0.000,0.000,0,0,0\r\nash> "),
        (
            b"moves cur\r",
            b"moves cur\r\nerror: Straight-line moves are possible only in online mode\r\nash> ",
        ),
        (b"w2\r", b"w2\r\n" + _world("+457.200", "+0.000", "+254.000") + b"ash> "),
    ]
    robot = ScriptedRobot(script, online=False)
    async with robot:
        await robot.teach_goal()
        # Configured for straight-line moves on a controller that is not online.
        robot.settings = robot.settings.model_copy(update={"online": True})
        with pytest.raises(DeviceReportedError) as caught:
            await robot.move_absolute((0.0, 0.0, 0.0))
        assert caught.value.code == 43
        status = robot.status()
        assert status.motion_held and status.online is False
        assert status.link is LinkState.CONNECTED  # the link itself is fine
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.0, 0.0, 0.0))  # nothing is sent: script would fail
        await robot.resume()  # checks the console with one `w2`
        assert not robot.status().motion_held
    robot.assert_all_used()


async def test_pause_continue_is_reported_as_a_status() -> None:
    message = proto.POINT_OF_CONTROL_MESSAGE.encode()
    script = [
        *CONNECT[:2],
        *TEACH,
        (b"set cur = opgoal\r", b"set cur = opgoal\r\nash> "),
        (b"wshift cur,0.000,0.000,0.000,0,0,0\r", b"wshift cur,0.000,0.000,0.000,0,0,0\r\nash> "),
        (b"move cur\r", b"move cur\r\n" + message + b"\r\nash> "),
    ]
    robot = ScriptedRobot(script, online=False)
    async with robot:
        await robot.teach_goal()
        with pytest.raises(PointOfControlError):
            await robot.move_absolute((0.0, 0.0, 0.0))
        status = robot.status()
        assert status.link is LinkState.AWAITING_POINT_OF_CONTROL
        assert status.point_of_control is False and status.motion_held
    robot.assert_all_used()
