"""The C500C console protocol as the firmware speaks it (docs/reference/c500c-console.md): pure
functions, and the driver replaying exact byte exchanges.

The driver tests work like pymeasure's ``expected_protocol``: a scripted console checks every
byte the driver sends against the recorded exchange, answers with the recorded bytes, and the
test fails unless every exchange was used (tests/c500c_scripted.py).
"""

from __future__ import annotations

from typing import Any

import pytest

from drivers.base import LinkState, Pose
from drivers.c500c import protocol as proto
from drivers.errors import (
    ConsoleQuestionError,
    DeviceError,
    DeviceReportedError,
    DeviceTimeoutError,
    GoalLostError,
    MotionHeldError,
    PointOfControlError,
    ProtocolError,
)
from tests.c500c_scripted import ScriptedRobot

PROMPT = b"ash> "
ASH = proto.prompt_pattern("ash")

# --- pure functions -----------------------------------------------------------------------------


def test_encode_command_appends_the_host_line_end() -> None:
    assert proto.encode_command("w2") == b"w2\r"
    for bad in ("", "w2\r", "move\x05", "wx 1\n", "caf\u00e9"):
        with pytest.raises(ValueError):
            proto.encode_command(bad)


@pytest.mark.parametrize(
    ("buffer", "end"),
    [
        (b"ash> ", 5),
        (b"w2\r\nash> ", 9),
        (b"w2\r\nash[cell.v3]> ", 18),  # the second prompt form [firmware]
        (b"w2\r\nash[]> ", None),  # a file name is not empty
        (b"w2\r\nash>", None),  # prompt not finished
        (b"w2\r\nxash> ", None),  # not at the start of a line
        (b"w2\r\nash[a\r\nb]> ", None),
        (b"w2\r\n", None),
        (b"", None),
        (b"set a = b\r\nash> wshift a,1\r\nash> ", 16),  # the first of two replies
    ],
)
def test_find_prompt_knows_both_prompt_forms(buffer: bytes, end: int | None) -> None:
    assert proto.find_prompt(buffer, ASH) == end


def test_find_prompt_of_another_application_and_of_the_shell() -> None:
    cell = proto.prompt_pattern("cell")
    assert proto.find_prompt(b"w2\r\ncell[run.v3]> ", cell) == 18
    assert proto.find_prompt(b"w2\r\nash> ", cell) is None
    assert proto.find_shell_prompt(b"boot\r\n$ ") == 8
    assert proto.find_shell_prompt(b"cost $ 5") is None
    either = proto.prompt_or_shell_pattern("ash")
    assert proto.find_prompt(b"x\r\n$ ", either) == 5
    assert proto.find_prompt(b"x\r\nash[f]> ", either) == 11


def test_split_reply_strips_echo_and_either_prompt() -> None:
    assert proto.split_reply(b"speed\r\nspeed = 10%\r\nash> ", "speed", ASH) == ["speed = 10%"]
    assert proto.split_reply(b"here opgoal\r\nash> ", "here opgoal", PROMPT) == []
    assert proto.split_reply(b"w0\r\nx\r\nash[a.v3]> ", "w0", ASH) == ["x"]


@pytest.mark.parametrize(
    "raw",
    [
        b"w3\r\nash> ",  # echo of another command
        b"w2\r\n\x8fash> ",  # a byte the console never sends
        b"w2\r\nWORLD: +1.000ash> ",  # unterminated line (prompt glued to it)
        b"w2\r\nabc\rdef\r\nash> ",  # stray CR inside a line
        b"w2\r\nWORLD\r\n",  # no prompt at all
        b"w2\r\nash> w2\r\nash> ",  # more than one reply
    ],
)
def test_split_reply_rejects_garbled_replies(raw: bytes) -> None:
    with pytest.raises(ProtocolError):
        proto.split_reply(raw, "w2", ASH)


@pytest.mark.parametrize(
    ("line", "code", "text"),
    [
        ("error: Unrecognized command.", None, "Unrecognized command."),
        ("Unrecognized command.", None, "Unrecognized command."),  # without the prefix
        ("error: variable not found.", None, "variable not found."),
        ("error: Straight-line moves are possible only in online mode", 43, None),
        ("Straight-line moves are possible only in online mode", 43, None),
        ("043 Straight-line moves are possible only in online mode", 43, None),
        ("error: 043: Straight-line moves are possible only in online mode", 43, None),
        ("error: sys004-043 Straight-line moves are possible only in online mode", 43, None),
        ("Robot must be in online mode for this command.", 43, None),  # ash's own text
        ("error: Robot must be in online mode for this command.", 43, None),
        ("error: Joint 3 limit exceeded", 1, None),
        ("1 Joint 3 limit exceeded", 1, None),
        ("error: 044 Halt() command invoked", 44, None),
        ("error: 099 Something new", 99, "Something new"),
        ("error: Something new", None, "Something new"),
    ],
)
def test_error_lines_in_every_form(line: str, code: int | None, text: str | None) -> None:
    parsed = proto.parse_error_line(line)
    assert parsed is not None and parsed.code == code
    if text is not None:
        assert parsed.text == text


@pytest.mark.parametrize(
    "line",
    ["WORLD (mm)", "        +457.200     +0.000", "speed = 10%", "12 apples", "Something new"],
)
def test_ordinary_lines_are_not_errors(line: str) -> None:
    assert proto.parse_error_line(line) is None


def test_every_catalogue_error_round_trips() -> None:
    for code, text in proto.MOTION_ERRORS.items():
        parsed = proto.parse_error_line(proto.format_error(code, text.replace("$1", "2")))
        assert parsed is not None and parsed.code == code


# --- the `w2` read-out -------------------------------------------------------------------------

WORLD = (457.2134, -12.0006, 254.0, -0.5, 90.0, -180.0)
JOINTS = (1.0, -2.5, 3.25, 0.0, 45.0, -90.0)
PULSES = (100, -2500, 0, 7, -123456, 3)


def firmware_lines(world: tuple[float, ...] = WORLD) -> list[str]:
    return proto.format_w_table(world, JOINTS, PULSES)


def test_firmware_read_out_layout() -> None:
    """docs/reference/c500c-console.md: title, blank line, axis header, PULSES integers, JOINTS
    decimals, blank line, world header, the `WORLD (mm) ...` units line, and the values on the next
    line, indented 8 spaces, `%+10.3f` one space apart."""
    lines = firmware_lines()
    assert lines[0] == "Actual Position :" and lines[1] == "" and lines[5] == ""
    assert proto.AXIS_HEADER in lines[2] and proto.WORLD_HEADER in lines[6]
    assert lines[3].split() == ["PULSES", "+100", "-2500", "+0", "+7", "-123456", "+3"]
    assert lines[4].startswith("JOINTS") and "+45.000" in lines[4]
    assert lines[7].split() == ["WORLD", "(mm)", "(mm)", "(mm)", "(deg)", "(deg)", "(deg)"]
    assert lines[8] == " " * 8 + " ".join(f"{v:+10.3f}" for v in WORLD)
    size = sum(len(line) + 2 for line in lines)
    # docs/reference/c500c-console.md: roughly 500-600 bytes with echo and prompt
    assert 450 <= size <= 600, size


def test_world_values_are_the_line_after_the_units_line() -> None:
    table = proto.parse_position_table(firmware_lines())
    assert table.world == (457.213, -12.001, 254.0, -0.5, 90.0, -180.0)
    assert table.joints == JOINTS and table.pulses == PULSES and table.units == "mm"
    pose = proto.parse_world_pose(firmware_lines())
    assert pose == Pose(457.213, -12.001, 254.0, -0.5, 90.0, -180.0)


def test_blank_lines_between_units_and_values_are_skipped() -> None:
    lines = firmware_lines()
    lines.insert(8, "")
    assert proto.parse_world_pose(lines).x == 457.213


def test_the_older_single_line_form_is_still_read() -> None:
    lines = proto.format_w_table(WORLD, JOINTS, PULSES, layout="single-line")
    assert lines[3].startswith("WORLD:")
    assert proto.parse_world_pose(lines).position == (457.213, -12.001, 254.0)
    assert proto.parse_world_pose(["WORLD  +1.000 +2.000 +3.000 +0.000 +0.000 +0.000"]).z == 3.0


def test_inches_are_refused_not_converted_silently() -> None:
    lines = [line.replace("(mm)", "(in)") for line in firmware_lines()]
    with pytest.raises(ProtocolError, match="inches"):
        proto.parse_world_pose(lines)


@pytest.mark.parametrize(
    "mutate",
    [
        lambda lines: lines[:-1],  # values line missing after the units line
        lambda lines: lines[:-2],  # no WORLD at all
        lambda lines: [*lines, "WORLD:  +1.000 +2.000 +3.000 +0.000 +0.000 +0.000"],  # twice
        lambda lines: [*lines[:-1], lines[-1].replace("-180.000", "")],  # five values
        lambda lines: [*lines[:-1], lines[-1].replace("+254", "+2x4")],  # not a number
        lambda lines: [*lines[:-1], lines[-1].replace("+254.000", "254")],  # not a decimal
        lambda lines: [lines[0], lines[3] + " +5", *lines[4:]],  # seven pulses
        lambda lines: [lines[0], lines[3], lines[3], *lines[4:]],  # PULSES twice
    ],
)
def test_damaged_read_outs_are_refused(mutate: Any) -> None:
    with pytest.raises(ProtocolError):
        proto.parse_world_pose(mutate(firmware_lines()))


# --- questions ---------------------------------------------------------------------------------


@pytest.mark.parametrize("question", proto.KNOWN_QUESTIONS, ids=lambda q: q.kind)
def test_known_questions_are_recognised(question: proto.Question) -> None:
    buffer = b"here x\r\nVariable 'x' not found.\r\n" + question.text.encode()
    assert proto.find_question(buffer) == question
    assert proto.may_be_question(buffer)


def test_unknown_questions_and_lines_in_transit() -> None:
    assert proto.may_be_question(b"x\r\nReally delete everything? ")
    assert proto.may_be_question(b"x\r\nEnter a value: ")
    assert not proto.may_be_question(b"w2\r\nActual Position :")  # a title line in transit
    assert not proto.may_be_question(b"w2\r\n   +457.2")
    assert not proto.may_be_question(b"w2\r\n")
    assert proto.find_question(b"x\r\nReally? ") is None


def test_blocking_messages() -> None:
    assert proto.blocking_message(["There is already a copy of ash running."])
    assert proto.blocking_message(["Please shut down the pendant so ash can initialize..."])
    assert proto.blocking_message(["speed = 10%"]) is None


# --- command sequences -------------------------------------------------------------------------


def test_absolute_sequence_rounds_and_writes_set_and_wshift_together() -> None:
    writes, commanded = proto.absolute_move_commands((0.0123, -0.00049, 1.0006), online=True)
    assert commanded == (0.012, 0.0, 1.001)
    assert writes == [
        ("set cur = opgoal", "wshift cur,0.012,0.000,1.001,0,0,0"),
        ("moves cur",),
        ("finish",),
        ("w2",),
    ]
    assert proto.absolute_move_commands((0, 0, 0), online=False)[0][1] == ("move cur",)
    assert proto.absolute_move_commands((0, 0, 0), online=True, readback=False)[0][-1] == (
        "finish",
    )


def test_incremental_sequence_moves_only_non_zero_axes() -> None:
    writes, commanded = proto.incremental_move_commands((0.002, 0.0001, -0.0104))
    assert commanded == (0.002, 0.0, -0.01)
    assert writes == [("wx 0.002",), ("wz -0.010",), ("finish",), ("w2",)]


def test_motion_commands_are_classified() -> None:
    for command in ("move cur", "moves cur", "wx 1", "wzs -0.1", "ready", "home", "joint 1,5"):
        assert proto.is_motion_command(command), command
    for command in ("set cur = opgoal", "wshift cur,1,0,0,0,0,0", "finish", "w2", "here opgoal"):
        assert not proto.is_motion_command(command), command


# --- the driver against recorded exchanges -----------------------------------------------------


def _probe(n: int, prompt: bytes = PROMPT, before: bytes = b"\r\n" + PROMPT) -> tuple[bytes, bytes]:
    """Ctrl-E and probe line n, and the console's answer: Ctrl-E's prompt, the probe's echo,
    the firmware's error for an unknown word, the prompt."""
    line = f"tcsync{n}".encode()
    return (
        b"\x05" + line + b"\r",
        before + line + b"\r\nerror: Unrecognized command.\r\n" + prompt,
    )


def _ok(command: bytes, prompt: bytes = PROMPT) -> tuple[bytes, bytes]:
    return (command + b"\r", command + b"\r\n" + prompt)


def _w2(x: float, y: float, z: float, prompt: bytes = PROMPT) -> tuple[bytes, bytes]:
    table = proto.format_w_table((x, y, z, 0.0, 90.0, 0.0), (0.0,) * 6, (0,) * 6)
    return (b"w2\r", b"w2\r\n" + "".join(f"{line}\r\n" for line in table).encode() + prompt)


CONNECT = [_probe(1), _ok(b"new cur"), _ok(b"online on")]
CONNECT_OFFLINE = [_probe(1), _ok(b"new cur")]
TEACH = [_ok(b"new opgoal"), _ok(b"here opgoal"), _w2(457.2, 0.0, 254.0)]


def _set_and_shift(shift: bytes, answer: bytes = b"") -> tuple[bytes, bytes]:
    set_cur = b"set cur = opgoal"
    return (
        set_cur + b"\r" + shift + b"\r",
        set_cur + b"\r\n" + answer + PROMPT + shift + b"\r\n" + PROMPT,
    )


async def test_connect_teach_and_absolute_move_exchange() -> None:
    move = [
        _set_and_shift(b"wshift cur,0.012,-0.003,0.000,0,0,0"),
        _ok(b"moves cur"),
        _ok(b"finish"),
        _w2(457.213, -0.003, 253.999),
    ]
    robot = ScriptedRobot([*CONNECT, *TEACH, *move])
    async with robot:
        assert robot.status().link is LinkState.CONNECTED
        assert robot.status().extra["prompt"] == "ash> "
        assert await robot.teach_goal() == Pose(457.2, 0.0, 254.0, 0.0, 90.0, 0.0)
        result = await robot.move_absolute((0.01249, -0.0031, 0.0))
    robot.assert_all_used()
    assert result.commanded_mm == (0.012, -0.003, 0.0)
    assert result.rounding_mm == pytest.approx((-0.00049, 0.0001, 0.0))
    assert result.actual.position == (457.213, -0.003, 253.999)
    assert result.bytes_sent == sum(len(sent) for sent, _ in move)
    assert result.bytes_received == sum(len(answer) for _, answer in move)
    assert len(result.round_trips_s) == len(move)


async def test_the_second_prompt_form_is_a_prompt() -> None:
    prompt = b"ash[cell.v3]> "
    script = [
        _probe(1, prompt, b"\r\n" + prompt),
        _ok(b"new cur", prompt),
        _ok(b"new opgoal", prompt),
        _ok(b"here opgoal", prompt),
        _w2(1.0, 2.0, 3.0, prompt),
    ]
    robot = ScriptedRobot(script, online=False)
    async with robot:
        assert (await robot.teach_goal()).position == (1.0, 2.0, 3.0)
        assert robot.status().extra["prompt"] == "ash[cell.v3]> "
    robot.assert_all_used()


async def test_connect_discards_what_came_before_the_probe() -> None:
    """A late answer of a previous session and Ctrl-E's own prompt come before the probe's
    echo: all of it is discarded, never read as a reply."""
    late = b"w2\r\nActual Position :\r\n\r\n  garbage of a cut table\r\nash> ^E\r\nash> "
    robot = ScriptedRobot([_probe(1, before=late), _ok(b"new cur")], online=False)
    async with robot:
        assert robot.status().link is LinkState.CONNECTED
    robot.assert_all_used()


async def test_connect_retries_the_probe() -> None:
    """The first probe's answer never comes (a console still busy, or one that dropped what
    followed Ctrl-E): a second probe line, alone, bounded."""
    first = (b"\x05tcsync1\r", b"")
    second = _probe(2)
    second = (second[0].removeprefix(b"\x05"), second[1].removeprefix(b"\r\n" + PROMPT))
    robot = ScriptedRobot([first, second, _ok(b"new cur")], online=False, command_timeout_s=0.1)
    async with robot:
        assert robot.status().link is LinkState.CONNECTED
    robot.assert_all_used()


async def test_shell_prompt_at_connect_starts_ash_with_its_application() -> None:
    script = [
        _probe(1, b"$ ", b"\r\n$ "),
        (b"ash cell\r", b"ash cell\r\ncell> "),
        _ok(b"new cur", b"cell> "),
        _ok(b"online on", b"cell> "),
    ]
    robot = ScriptedRobot(script, application="cell")
    async with robot:
        assert robot.status().online is True
    robot.assert_all_used()


async def test_ash_already_running_is_a_clear_error() -> None:
    script = [
        _probe(1, b"$ ", b"\r\n$ "),
        (b"ash ash\r", b"ash ash\r\nThere is already a copy of ash running.\r\n$ "),
    ]
    robot = ScriptedRobot(script)
    with pytest.raises(ConsoleQuestionError, match="already a copy of ash"):
        async with robot:
            pass
    robot.assert_all_used()


@pytest.mark.parametrize(
    "line",
    [
        b"error: Straight-line moves are possible only in online mode",
        b"Straight-line moves are possible only in online mode",
        b"043 Straight-line moves are possible only in online mode",
        b"Robot must be in online mode for this command.",
    ],
)
async def test_device_error_is_reported_with_its_number_and_holds_motion(line: bytes) -> None:
    script = [
        *CONNECT_OFFLINE,
        *TEACH,
        _set_and_shift(b"wshift cur,0.000,0.000,0.000,0,0,0"),
        (b"moves cur\r", b"moves cur\r\n" + line + b"\r\n" + PROMPT),
        _ok(b"set cur = opgoal"),
        _w2(457.2, 0.0, 254.0),
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
        await robot.resume()  # checks the goal still exists, then one `w2`
        assert not robot.status().motion_held
    robot.assert_all_used()


async def test_a_lost_goal_is_reported_as_such() -> None:
    script = [
        *CONNECT_OFFLINE,
        *TEACH,
        _set_and_shift(b"wshift cur,0.001,0.000,0.000,0,0,0", b"error: variable not found.\r\n"),
    ]
    robot = ScriptedRobot(script, online=False)
    async with robot:
        await robot.teach_goal()
        with pytest.raises(GoalLostError, match="lost the taught goal"):
            await robot.move_absolute((0.001, 0.0, 0.0))
        assert robot.status().motion_held
    robot.assert_all_used()


async def test_pause_continue_then_the_button_is_a_wait_not_an_error() -> None:
    message = proto.POINT_OF_CONTROL_MESSAGE.encode()
    script = [
        *CONNECT_OFFLINE,
        *TEACH,
        _set_and_shift(b"wshift cur,0.000,0.000,0.000,0,0,0"),
        (b"move cur\r", b"move cur\r\n" + message + b"\r\n\r\n" + PROMPT),
        _ok(b"finish"),
        _w2(457.2, 0.0, 254.0),
    ]
    robot = ScriptedRobot(script, online=False)
    async with robot:
        await robot.teach_goal()
        result = await robot.move_absolute((0.0, 0.0, 0.0))
        assert result.actual.x == 457.2
        status = robot.status()
        assert status.link is LinkState.CONNECTED and status.point_of_control
    robot.assert_all_used()
    assert LinkState.AWAITING_POINT_OF_CONTROL in robot.link_history


async def test_the_point_of_control_wait_times_out_clearly() -> None:
    message = proto.POINT_OF_CONTROL_MESSAGE.encode()
    script = [
        *CONNECT_OFFLINE,
        *TEACH,
        _set_and_shift(b"wshift cur,0.000,0.000,0.000,0,0,0"),
        (b"move cur\r", b"move cur\r\n" + message + b"\r\n"),
        # the operator pressed at last: the move's prompt, Ctrl-E's, then the probe's answer
        _probe(2, before=b"\r\n" + PROMPT + b"\r\n" + PROMPT),
    ]
    robot = ScriptedRobot(script, online=False, point_of_control_timeout_s=0.1)
    async with robot:
        await robot.teach_goal()
        with pytest.raises(PointOfControlError, match="nobody pressed PAUSE/CONTINUE"):
            await robot.move_absolute((0.0, 0.0, 0.0))
        assert robot.status().motion_held
        assert robot._resync_task is not None
        await robot._resync_task  # the console answered the probe: synchronised again
        assert robot.status().link is LinkState.CONNECTED
    robot.assert_all_used()


async def test_create_it_question_is_answered_no() -> None:
    script = [
        *CONNECT_OFFLINE,
        _ok(b"new opgoal"),
        (b"here opgoal\r", b"here opgoal\r\nVariable 'opgoal' not found.\r\n  -- create it? "),
        (b"no\r", b"no\r\n" + PROMPT),
    ]
    robot = ScriptedRobot(script, online=False)
    async with robot:
        with pytest.raises(ConsoleQuestionError, match=r"create it.*answered 'no'"):
            await robot.teach_goal()
        assert robot.status().link is LinkState.CONNECTED
    robot.assert_all_used()


async def test_an_unknown_question_ends_the_command_and_resynchronises() -> None:
    script = [
        *CONNECT_OFFLINE,
        (b"w2\r", b"w2\r\nFormat the flash disk now? "),
        (b"\x05", b"\r\n" + PROMPT),
        _probe(2, before=b""),
        _w2(1.0, 2.0, 3.0),
    ]
    robot = ScriptedRobot(script, online=False)
    async with robot:
        with pytest.raises(ConsoleQuestionError, match="Format the flash disk"):
            await robot.actual_pose()
        assert (await robot.actual_pose()).position == (1.0, 2.0, 3.0)
        assert robot.status().extra["resyncs"] == "1"
    robot.assert_all_used()


async def test_readback_every_n_moves() -> None:
    move = [
        _set_and_shift(b"wshift cur,0.001,0.000,0.000,0,0,0"),
        _ok(b"move cur"),
        _ok(b"finish"),
    ]
    read_back = _w2(457.201, 0.0, 254.0)
    script = [*CONNECT_OFFLINE, *TEACH, *move, read_back, *move, *move, read_back]
    robot = ScriptedRobot(script, online=False, readback_every=2)
    async with robot:
        await robot.teach_goal()
        first = await robot.move_absolute((0.001, 0.0, 0.0))
        second = await robot.move_absolute((0.001, 0.0, 0.0))
        assert first.read_back and first.actual.x == 457.201
        assert not second.read_back and second.pose is None
        with pytest.raises(DeviceError, match="no read-back"):
            _ = second.actual
        third = await robot.move_absolute((0.001, 0.0, 0.0))
        assert third.read_back and third.actual.x == 457.201
    robot.assert_all_used()


@pytest.mark.parametrize("question", proto.KNOWN_QUESTIONS, ids=lambda q: q.kind)
async def test_each_known_question_ends_the_command_deliberately(
    question: proto.Question,
) -> None:
    """docs/reference/c500c-console.md "Questions": a question the driver knows an answer for gets
    it (and the prompt is awaited); one it must not answer (save, exit, which application) gets
    Ctrl-E and a resynchronisation. Either way the command fails clearly and the next one works."""
    asked = (b"w2\r", b"w2\r\nSomething happened.\r\n" + question.text.encode())
    if question.answer is not None:
        answer = question.answer.encode()
        after = [(answer + b"\r", answer + b"\r\n" + PROMPT)]
        expected = f"answered {question.answer!r}"
    else:
        after = [(b"\x05", b"\r\n" + PROMPT), _probe(2, before=b"")]
        expected = "does not answer"
    script = [*CONNECT_OFFLINE, asked, *after, _w2(1.0, 2.0, 3.0)]
    robot = ScriptedRobot(script, online=False)
    async with robot:
        with pytest.raises(ConsoleQuestionError, match=expected):
            await robot.actual_pose()
        assert (await robot.actual_pose()).position == (1.0, 2.0, 3.0)
    robot.assert_all_used()


async def test_another_applications_prompt_is_named() -> None:
    """The first thing a lab user may get wrong: robot.application. Three probe lines, each
    answered at another application's prompt, then a clear error instead of a bare timeout."""
    other = b"cell> "
    script = [_probe(1, other, b"\r\n" + other)]
    for n in (2, 3):
        probe = _probe(n, other, b"")
        script.append((probe[0].removeprefix(b"\x05"), probe[1]))
    robot = ScriptedRobot(script, command_timeout_s=0.05)
    with pytest.raises(DeviceTimeoutError, match=r"prompt is 'cell> '.*robot\.application"):
        async with robot:
            pass
    robot.assert_all_used()
