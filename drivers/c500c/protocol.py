"""The CRS C500C `ash` console as pure functions: framing (the host's line end, the echo,
prompts, a reply split into lines, the synchronisation probe), and the one name every user of
the console protocol imports (``from drivers import c500c_protocol as proto``).

No I/O here: the driver (drivers/c500c/robot.py) and the emulator (drivers/sim/emulator.py) both
build on these functions, and tests replay exact byte exchanges through them. The protocol is split
by job, each part re-exported here: the firmware's texts and the single block ``ASSUMED`` of what
no public source confirms (drivers/c500c/texts.py), questions and error lines
(drivers/c500c/replies.py), the `w0`/`w2` read-out (drivers/c500c/position.py) and the command
sequences (drivers/c500c/commands.py).
"""

from __future__ import annotations

import re

from drivers.c500c.commands import (
    MAX_SPEED_PERCENT,
    MIN_SPEED_PERCENT,
    MOTION_COMMANDS,
    Write,
    absolute_move_commands,
    format_deg,
    format_mm,
    incremental_move_commands,
    is_motion_command,
    round_deg,
    round_mm,
    speed_command,
)
from drivers.c500c.position import (
    Layout,
    PositionTable,
    format_w_table,
    parse_position_table,
    parse_world_pose,
)
from drivers.c500c.replies import (
    KNOWN_QUESTIONS,
    ConsoleError,
    Question,
    blocking_message,
    find_question,
    first_error,
    format_error,
    may_be_question,
    needs_point_of_control,
    parse_error_line,
    pending_line,
)
from drivers.c500c.texts import (
    ACTUAL_TITLE,
    ANGLE_DECIMALS,
    ASH_ONLINE_ERROR,
    AXIS_HEADER,
    BLOCKING_MESSAGES,
    COMMANDED_TITLE,
    CTRL_E,
    DEVICE,
    ERROR_PREFIX,
    HOST_LINE_END,
    MOTION_ERRORS,
    ONLINE_ERROR_CODE,
    POINT_OF_CONTROL_MESSAGE,
    POSITION_DECIMALS,
    REPLY_LINE_END,
    ROW_LABEL_WIDTH,
    SHELL_ERRORS,
    SHELL_PROMPT,
    SYNC_PROBE,
    WORLD_HEADER,
    WORLD_UNITS_IN,
    WORLD_UNITS_MM,
    WORLD_VALUES_INDENT,
)
from drivers.errors import ProtocolError

__all__ = [
    "ACTUAL_TITLE",
    "ANGLE_DECIMALS",
    "ASH_ONLINE_ERROR",
    "AXIS_HEADER",
    "BLOCKING_MESSAGES",
    "COMMANDED_TITLE",
    "CTRL_E",
    "DEVICE",
    "ERROR_PREFIX",
    "HOST_LINE_END",
    "KNOWN_QUESTIONS",
    "MAX_SPEED_PERCENT",
    "MIN_SPEED_PERCENT",
    "MOTION_COMMANDS",
    "MOTION_ERRORS",
    "ONLINE_ERROR_CODE",
    "POINT_OF_CONTROL_MESSAGE",
    "POSITION_DECIMALS",
    "REPLY_LINE_END",
    "ROW_LABEL_WIDTH",
    "SHELL_ERRORS",
    "SHELL_PROMPT",
    "SYNC_PROBE",
    "WORLD_HEADER",
    "WORLD_UNITS_IN",
    "WORLD_UNITS_MM",
    "WORLD_VALUES_INDENT",
    "ConsoleError",
    "Layout",
    "PositionTable",
    "Prompt",
    "Question",
    "Write",
    "absolute_move_commands",
    "blocking_message",
    "encode_command",
    "find_probe_answer",
    "find_prompt",
    "find_question",
    "find_shell_prompt",
    "first_error",
    "format_deg",
    "format_error",
    "format_mm",
    "format_w_table",
    "incremental_move_commands",
    "is_console_text",
    "is_motion_command",
    "may_be_question",
    "needs_point_of_control",
    "parse_error_line",
    "parse_position_table",
    "parse_world_pose",
    "pending_line",
    "prompt_for",
    "prompt_or_shell_pattern",
    "prompt_pattern",
    "round_deg",
    "round_mm",
    "speed_command",
    "split_reply",
    "sync_probe",
]

_SHELL_PROMPT_PATTERN = re.compile(rb"(?:(?<=\n)|\A)\$ ")


def prompt_pattern(application: str) -> re.Pattern[bytes]:
    """The two `ash` prompt forms of ``application`` [firmware]: ``<app>> `` and
    ``<app>[<file>]> ``, each only at the start of a line."""
    name = re.escape(application.encode("ascii"))
    return re.compile(rb"(?:(?<=\n)|\A)" + name + rb"(?:\[[^\]\r\n]+\])?> ")


def prompt_or_shell_pattern(application: str) -> re.Pattern[bytes]:
    """Either `ash` prompt form of ``application`` or the system shell's `$ `."""
    name = re.escape(application.encode("ascii"))
    return re.compile(rb"(?:(?<=\n)|\A)(?:" + name + rb"(?:\[[^\]\r\n]+\])?> |\$ )")


def prompt_for(application: str, file: str | None = None) -> bytes:
    """The `ash` prompt of ``application`` (with the open file, if any), as it is printed."""
    return (f"{application}[{file}]> " if file else f"{application}> ").encode("ascii")


def encode_command(command: str) -> bytes:
    """One console command as the bytes to send: printable ASCII, then the host line end."""
    if not command or not command.isascii() or not command.isprintable():
        raise ValueError(f"not a console command: {command!r}")
    return command.encode("ascii") + HOST_LINE_END


Prompt = bytes | re.Pattern[bytes]


def _prompt_regex(prompt: Prompt) -> re.Pattern[bytes]:
    if isinstance(prompt, bytes):
        return re.compile(rb"(?:(?<=\n)|\A)" + re.escape(prompt))
    return prompt


def find_prompt(buffer: bytes, prompt: Prompt) -> int | None:
    """Where the first reply in ``buffer`` ends: the index just past the first prompt that sits
    at the start of a line; ``None`` while no reply is complete. A buffer may hold more than one
    reply (commands written together): the rest belongs to the next command."""
    match = _prompt_regex(prompt).search(buffer)
    return None if match is None else match.end()


def find_shell_prompt(buffer: bytes) -> int | None:
    """Like :func:`find_prompt` for the system shell's `$ `."""
    match = _SHELL_PROMPT_PATTERN.search(buffer)
    return None if match is None else match.end()


def is_console_text(data: bytes) -> bool:
    """Whether ``data`` holds only what the console prints: printable ASCII, CR and LF."""
    return all(0x20 <= byte <= 0x7E or byte in b"\r\n" for byte in data)


def split_reply(raw: bytes, command: str, prompt: Prompt) -> list[str]:
    """The reply lines of ``command`` from the raw bytes up to and including the prompt.

    Checks the echo, the character set and the line ends; anything else is a
    :class:`ProtocolError` (a garbled reply is an error, never a guess).
    """
    end = find_prompt(raw, prompt)
    if end != len(raw):
        raise ProtocolError(DEVICE, f"{command!r}: reply does not end with the prompt: {raw!r}")
    match = _prompt_regex(prompt).search(raw)
    assert match is not None
    body = raw[: match.start()]
    if not is_console_text(body):
        raise ProtocolError(DEVICE, f"{command!r}: unexpected bytes in reply: {raw!r}")
    echo = command.encode("ascii") + REPLY_LINE_END
    if not body.startswith(echo):
        raise ProtocolError(DEVICE, f"{command!r}: echo missing or garbled: {raw!r}")
    body = body[len(echo) :]
    if body and not body.endswith(REPLY_LINE_END):
        raise ProtocolError(DEVICE, f"{command!r}: reply line not terminated: {raw!r}")
    lines = body.split(REPLY_LINE_END)[:-1] if body else []
    if any(b"\r" in line or b"\n" in line for line in lines):
        raise ProtocolError(DEVICE, f"{command!r}: stray line end in reply: {raw!r}")
    return [line.decode("ascii") for line in lines]


def sync_probe(counter: int) -> str:
    """The probe line of synchronisation attempt ``counter`` (ASSUMED 6)."""
    return f"{SYNC_PROBE}{counter}"


def find_probe_answer(buffer: bytes, probe: str, prompt: Prompt) -> int | None:
    """Where the answer to ``probe`` ends in ``buffer``: past the prompt that follows the probe's
    echo line; ``None`` until both have arrived. Anything before the echo (a cut command's late
    answer, Ctrl-E's prompt) is what synchronisation discards."""
    echo = probe.encode("ascii") + REPLY_LINE_END
    at = buffer.rfind(echo)  # whatever precedes it (a prompt, `^E`...) is discarded
    if at < 0:
        return None
    after = at + len(echo)
    end = find_prompt(buffer[after:], prompt)
    return None if end is None else after + end
