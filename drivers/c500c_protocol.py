"""The CRS C500C `ash` console as pure functions: framing, echo, prompt, `w0`/`w2` tables, errors.

No I/O here: the driver (drivers/c500c.py) and the emulator (drivers/sim/emulator.py) both build
on these functions, and tests replay exact byte exchanges through them. What public sources
confirm is in the project's shared notes (C500C.md, beside DESIGN.md); everything this project
had to assume is collected in the single block ``ASSUMED`` below, so that a session on the real
controller corrects it in one place.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

from drivers.base import Pose, Vector3
from drivers.errors import ProtocolError

DEVICE = "robot"

# --- confirmed (C500C.md "Confirmed from public sources") ---------------------------------------

#: Ctrl-E interrupts continuous displays; sending it first gives a clean line.
CTRL_E = b"\x05"
#: The system shell's prompt; `ash [application]` starts the application shell from it.
SHELL_PROMPT = b"$ "
#: Shell error texts, exactly as the firmware prints them.
SHELL_ERRORS: tuple[str, ...] = (
    "Unrecognized command.",
    "missing comma.",
    "too many arguments.",
    "missing number.",
    "variable not found.",
    "type mismatch.",
    "invalid argument.",
)
#: Motion error catalogue `sys004` (number -> text; `$1` is the joint number).
MOTION_ERRORS: dict[int, str] = {
    1: "Joint $1 limit exceeded",
    3: "Location out of reach",
    5: "Not homed or not calibrated",
    7: "Arm power is OFF",
    15: "Illegal speed chosen",
    27: "Cannot perform requested motion in current stance",
    43: "Straight-line moves are possible only in online mode",
}
#: What the controller prints when the operator must take the point of control.
POINT_OF_CONTROL_MESSAGE = "Press the PAUSE/CONTINUE button to gain robot point of control."
#: `w0`/`w2` print every value as `%+10.3f`: 0.001 mm is the finest position the console shows.
POSITION_DECIMALS = 3
W_TABLE_ROWS = ("PULSES", "JOINTS", "WORLD")

# --- ASSUMED (C500C.md "Assumed"; no public source: correct here against the real controller) ---
#
# 1. The host ends a command with CR (the console accepts CR or LF).
# 2. The echo of a typed command is the command's text followed by CRLF; every reply line ends
#    with CRLF; the command is acknowledged when the prompt `<application>> ` (no line end)
#    comes back at the start of a line.
# 3. A motion error is one line `error: <catalogue text>` (no number: the driver looks the number
#    up in MOTION_ERRORS); a shell error is its text alone on a line.
# 4. Motion commands (`move`, `moves`, `wx`...) return the prompt at once; `finish` returns it
#    when the motion has ended.
# 5. When the point of control is missing, a motion command prints POINT_OF_CONTROL_MESSAGE on
#    its own line and returns to the prompt without moving (it does not wait for the button).
# 6. Ctrl-E on an idle console discards any half-typed line and prints CRLF and a fresh prompt.
# 7. The `w0`/`w2` table is a header line, then one line per row of W_TABLE_ROWS:
#    the row name padded to 8 characters followed by six `%+10.3f` values
#    (PULSES and JOINTS: joints 1..6; WORLD: X, Y, Z, Z-Rot, Y-Rot, X-Rot).
HOST_LINE_END = b"\r"
REPLY_LINE_END = b"\r\n"
ERROR_PREFIX = "error: "
W_TABLE_HEADER = "        " + "".join(f"{name:>10}" for name in ("1", "2", "3", "4", "5", "6"))
W_TABLE_LABEL_WIDTH = 8
# -------------------------------------------------------------------------------------------------

_VALUE_PATTERN = r"[ ]*[+-]\d+\.\d{3}"  # `%+10.3f`: right-aligned, signed, three decimals
_ROW_PATTERN = re.compile(
    rf"^(?P<label>[A-Z]+):?[ ]*(?P<values>(?:{_VALUE_PATTERN}){{6}})$",
)
_VALUE = re.compile(r"[+-]\d+\.\d{3}")


def prompt_for(application: str) -> bytes:
    """The `ash` prompt of ``application``: ``<application name>> ``."""
    return f"{application}> ".encode("ascii")


def encode_command(command: str) -> bytes:
    """One console command as the bytes to send: printable ASCII, then the host line end."""
    if not command or not command.isascii() or not command.isprintable():
        raise ValueError(f"not a console command: {command!r}")
    return command.encode("ascii") + HOST_LINE_END


def find_prompt(buffer: bytes, prompt: bytes) -> int | None:
    """Where the reply ends: the index just past a prompt that sits at the start of a line and
    ends the buffer; ``None`` while the reply is incomplete."""
    if not buffer.endswith(prompt):
        return None
    start = len(buffer) - len(prompt)
    if start == 0 or buffer[:start].endswith(b"\n"):
        return len(buffer)
    return None


def is_console_text(data: bytes) -> bool:
    """Whether ``data`` holds only what the console prints: printable ASCII, CR and LF."""
    return all(0x20 <= byte <= 0x7E or byte in b"\r\n" for byte in data)


def split_reply(raw: bytes, command: str, prompt: bytes) -> list[str]:
    """The reply lines of ``command`` from the raw bytes up to and including the prompt.

    Checks the echo, the character set and the line ends; anything else is a
    :class:`ProtocolError` (a garbled reply is an error, never a guess).
    """
    if find_prompt(raw, prompt) is None:
        raise ProtocolError(DEVICE, f"{command!r}: reply does not end with the prompt: {raw!r}")
    body = raw[: len(raw) - len(prompt)]
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


@dataclass(frozen=True, slots=True)
class ConsoleError:
    """An error line of the console: a catalogue number (motion errors) and its text."""

    code: int | None
    text: str


def _catalogue_patterns() -> list[tuple[int, re.Pattern[str]]]:
    return [
        (code, re.compile("^" + re.escape(text).replace(re.escape("$1"), r"\d+") + "$"))
        for code, text in MOTION_ERRORS.items()
    ]


_CATALOGUE = _catalogue_patterns()


def parse_error_line(line: str) -> ConsoleError | None:
    """The error a reply line reports, or ``None`` for an ordinary line."""
    if line in SHELL_ERRORS:
        return ConsoleError(None, line)
    if line.startswith(ERROR_PREFIX):
        text = line[len(ERROR_PREFIX) :]
        for code, pattern in _CATALOGUE:
            if pattern.match(text):
                return ConsoleError(code, text)
        return ConsoleError(None, text)
    return None


def format_error(code: int | None, text: str | None = None) -> str:
    """The line the console prints for a motion error ``code`` (or a shell error ``text``)."""
    if code is None:
        assert text is not None
        return text
    return ERROR_PREFIX + (text if text is not None else MOTION_ERRORS[code])


def first_error(lines: Sequence[str]) -> ConsoleError | None:
    for line in lines:
        error = parse_error_line(line)
        if error is not None:
            return error
    return None


def needs_point_of_control(lines: Sequence[str]) -> bool:
    """Whether the reply asks the operator to press PAUSE/CONTINUE."""
    return any("PAUSE/CONTINUE" in line for line in lines)


def parse_w_table(lines: Sequence[str]) -> dict[str, tuple[float, ...]]:
    """The rows of a `w0`/`w2` table: name -> six values. Every row must be present, once."""
    rows: dict[str, tuple[float, ...]] = {}
    for line in lines:
        if line.strip() == W_TABLE_HEADER.strip() or not line.strip():
            continue
        match = _ROW_PATTERN.match(line)
        if match is None or match["label"] not in W_TABLE_ROWS or match["label"] in rows:
            raise ProtocolError(DEVICE, f"unreadable position table line: {line!r}")
        rows[match["label"]] = tuple(float(v) for v in _VALUE.findall(match["values"]))
    missing = [row for row in W_TABLE_ROWS if row not in rows]
    if missing:
        raise ProtocolError(DEVICE, f"position table lacks row(s) {', '.join(missing)}")
    return rows


def parse_world_pose(lines: Sequence[str]) -> Pose:
    """The WORLD row of a `w0`/`w2` table as a :class:`Pose` (mm, degrees)."""
    return Pose(*parse_w_table(lines)["WORLD"])


def format_w_table(
    world: Sequence[float], joints: Sequence[float], pulses: Sequence[float]
) -> list[str]:
    """The lines of a `w0`/`w2` table (the emulator prints them; ASSUMED layout 7)."""
    out = [W_TABLE_HEADER]
    for label, values in (("PULSES", pulses), ("JOINTS", joints), ("WORLD", world)):
        if len(values) != 6:
            raise ValueError(f"{label}: six values expected, not {len(values)}")
        cells = "".join(f"{value:+10.3f}" for value in values)
        out.append(f"{label + ':':<{W_TABLE_LABEL_WIDTH}}{cells}")
    return out


def round_mm(value_mm: float) -> float:
    """A distance as the console can take it: rounded to 0.001 mm (no negative zero)."""
    return float(f"{value_mm:.{POSITION_DECIMALS}f}") + 0.0


def format_mm(value_mm: float) -> str:
    return f"{round_mm(value_mm):.{POSITION_DECIMALS}f}"


def absolute_move_commands(
    offset_mm: Vector3, *, online: bool, goal: str = "opgoal", target: str = "cur"
) -> tuple[list[str], Vector3]:
    """The absolute-move sequence of C500C.md (thesis 6.4.4: every goal is defined from the
    operational goal) and the offset actually commanded after rounding to 0.001 mm."""
    commanded = (round_mm(offset_mm[0]), round_mm(offset_mm[1]), round_mm(offset_mm[2]))
    dx, dy, dz = (format_mm(v) for v in commanded)
    commands = [
        f"set {target} = {goal}",
        f"wshift {target},{dx},{dy},{dz},0,0,0",
        f"{'moves' if online else 'move'} {target}",
        "finish",
        "w2",
    ]
    return commands, commanded


def incremental_move_commands(delta_mm: Vector3) -> tuple[list[str], Vector3]:
    """The incremental sequence (`wx`/`wy`/`wz`, kept to reproduce the thesis's comparison):
    one relative move per non-zero axis, then `finish` and the `w2` read-back."""
    commanded = (round_mm(delta_mm[0]), round_mm(delta_mm[1]), round_mm(delta_mm[2]))
    commands = [
        f"w{axis} {format_mm(value)}"
        for axis, value in zip("xyz", commanded, strict=True)
        if value != 0.0
    ]
    return [*commands, "finish", "w2"], commanded
