"""The CRS C500C `ash` console as pure functions: framing, echo, prompts, questions, `w0`/`w2`
tables, errors.

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
from typing import Literal

from drivers.base import Pose, Vector3
from drivers.errors import ProtocolError

DEVICE = "robot"

# --- from the firmware and the console capture (C500C.md) ---------------------------------------

#: Ctrl-E interrupts continuous displays; host scripts send it to get a clean line [capture].
CTRL_E = b"\x05"
#: The system shell's prompt; `ash <application>` starts the application shell from it.
SHELL_PROMPT = b"$ "
#: Every line the console prints ends with CR LF, echoes included [capture].
REPLY_LINE_END = b"\r\n"
#: The literal the firmware prints before shell errors [firmware]; motion errors may or may not
#: carry it (C500C.md "Errors"), so both forms are accepted.
ERROR_PREFIX = "error: "
#: Shell error texts, exactly as the firmware prints them [firmware].
SHELL_ERRORS: tuple[str, ...] = (
    "Unrecognized command.",
    "missing comma.",
    "too many arguments.",
    "missing number.",
    "variable not found.",
    "type mismatch.",
    "invalid argument.",
)
#: Motion error catalogue `sys004` (number -> text; `$1` is the joint number) [firmware].
MOTION_ERRORS: dict[int, str] = {
    1: "Joint $1 limit exceeded",
    3: "Location out of reach",
    5: "Not homed or not calibrated",
    7: "Arm power is OFF",
    15: "Illegal speed chosen",
    27: "Cannot perform requested motion in current stance",
    43: "Straight-line moves are possible only in online mode",
    44: "Halt() command invoked",
}
#: `ash`'s own text for a straight-line move without online mode [firmware]: the same fault as
#: catalogue error 043, so it is reported with that number.
ASH_ONLINE_ERROR = "Robot must be in online mode for this command."
ONLINE_ERROR_CODE = 43
#: What the robot library prints before it waits for the operator's button [firmware + capture]:
#: the console is blocked until PAUSE/CONTINUE is pressed; it is not an error.
POINT_OF_CONTROL_MESSAGE = "Press the PAUSE/CONTINUE button to gain robot point of control."
#: Messages after which the console does not do what was asked [firmware]: the command ends in
#: an error naming them.
BLOCKING_MESSAGES: tuple[str, ...] = (
    "There is already a copy of ash running.",
    "Please shut down the pendant so",
    "Ash doesn't have control.",
)
#: `w0`/`w2` print positions as `%+10.3f` [firmware]: 0.001 mm is the finest the console shows.
POSITION_DECIMALS = 3
#: Decimals of the angles `wshift` is given (C500C.md "The absolute-move sequence": 3).
ANGLE_DECIMALS = 3
#: The read-out's fixed texts [firmware].
ACTUAL_TITLE = "Actual Position :"
COMMANDED_TITLE = "Commanded Position :"
AXIS_HEADER = "Axis 1/7   Axis 2/8     Axis 3     Axis 4     Axis 5     Axis 6"
WORLD_HEADER = "X/TrackX   Y/TrackY          Z      Z-Rot      Y-Rot      X-Rot"
WORLD_UNITS_MM = ("(mm)", "(mm)", "(mm)", "(deg)", "(deg)", "(deg)")
WORLD_UNITS_IN = ("(in)", "(in)", "(in)", "(deg)", "(deg)", "(deg)")
#: The WORLD values line is indented by 8 spaces, `%+10.3f` each, one space apart [firmware].
WORLD_VALUES_INDENT = 8

# --- ASSUMED (no public source: correct here against the real controller) -----------------------
#
# 1. The host ends a command with CR (the console accepts CR or LF [capture]).
# 2. A command is acknowledged when a prompt comes back at the start of a line: `<app>> ` or
#    `<app>[<file>]> ` [firmware formats], or `$ ` when the console is at the system shell.
# 3. A motion error is one line: `error: <catalogue text>`, the bare text, or either with the
#    catalogue number first (`043 <text>`, `error: 043: <text>`); a shell error is one line.
# 4. Motion commands (`move`, `moves`, `wx`...) return the prompt when the motion has started;
#    `finish` returns it when the motion has ended.
# 5. Without the point of control, a motion command prints POINT_OF_CONTROL_MESSAGE on its own
#    line and then waits for the button; after the press it carries on (prompt when started).
# 6. Ctrl-E on an idle console prints CR LF and a fresh prompt; a line typed after it is read
#    as a new command. Little else about Ctrl-E is relied upon: the driver synchronises on the
#    echo of a probe line (SYNC_PROBE) and the prompt after it, never on silence; its first
#    probe follows Ctrl-E in the same write, later ones go alone (in case Ctrl-E made the
#    console drop what was typed right after it).
# 7. A question is printed without a line end and waits for one answer line; `new <name>`
#    creates a location variable (C500C.md: `help new`) and prints nothing, or an error line
#    when the name exists already (either is accepted).
# 8. The PULSES and JOINTS rows are the row name padded to 8 characters, then six values one
#    space apart (`%+10d` and `%+10.3f`); the lines for axes 7 and 8 are not printed on a
#    six-axis arm; the WORLD units line is `WORLD` padded to 8 then the six units, each
#    right-aligned in 10 characters, one space apart.
HOST_LINE_END = b"\r"
ROW_LABEL_WIDTH = 8
#: A word `ash` does not know: its echo is unique, its answer is one error line and the prompt,
#: and it changes nothing on the controller. The driver types it (with a counter) to find where
#: the console's output ends (connect and resynchronisation).
SYNC_PROBE = "tcsync"
# -------------------------------------------------------------------------------------------------

_SHELL_PROMPT_PATTERN = re.compile(rb"(?:(?<=\n)|\A)\$ ")
_DECIMAL = r"[+-]?\d+\.\d+"
_INTEGER = r"[+-]?\d+"


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


# --- questions ---------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Question:
    """A question the console asks and waits for an answer to [firmware]."""

    kind: str
    text: str
    answer: str | None  # what the driver answers deliberately; None: never answer it


#: The questions the firmware can ask (C500C.md "Questions"), matched at the end of what the
#: console printed. The driver creates its variables with `new` so "create it?" is not asked; if
#: it is all the same, it answers "no": a variable the driver did not create is an error.
KNOWN_QUESTIONS: tuple[Question, ...] = (
    Question("create-variable", "  -- create it? ", "no"),
    Question("yes-or-no", "Please answer 'yes' or 'no': ", "no"),
    Question("set-valid", "Set the valid flag anyway (y/n) ?", "n"),
    Question("save-first", "Variables have been changed -- save first? ", None),
    Question("exit", "Are you sure you want to exit? ", None),
    Question("application-name", "Application name > ", None),
)
#: How an unknown question ends (ASSUMED 7): a non-empty line without line end, ending so.
_QUESTION_END = re.compile(r"(\? ?|: |> )$")


def pending_line(buffer: bytes) -> str:
    """What follows the last line end of ``buffer``: a question, a prompt, or a line in transit."""
    return buffer[buffer.rfind(b"\n") + 1 :].decode("ascii", errors="replace")


def find_question(buffer: bytes) -> Question | None:
    """The known question ``buffer`` ends with (the console waits for an answer), if any."""
    tail = pending_line(buffer)
    for question in KNOWN_QUESTIONS:
        if tail.rstrip() == question.text.rstrip():
            return question
    return None


def may_be_question(buffer: bytes) -> bool:
    """Whether ``buffer`` ends like an unknown question: the driver treats it as one when
    nothing more comes for a while (a line in transit can end so by chance)."""
    tail = pending_line(buffer)
    return bool(tail.strip()) and _QUESTION_END.search(tail) is not None


def blocking_message(lines: Sequence[str]) -> str | None:
    """The first line saying the console will not do what was asked (BLOCKING_MESSAGES)."""
    for line in lines:
        if any(line.strip().startswith(message) for message in BLOCKING_MESSAGES):
            return line.strip()
    return None


# --- errors ------------------------------------------------------------------------------------


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
_LEADING_NUMBER = re.compile(
    r"^(?:sys004[-:. ]?)?(?P<code>\d{1,3})(?:[:.)-]\s*|\s+)(?P<text>\S.*)$"
)


def _known_text(text: str) -> ConsoleError | None:
    if text in SHELL_ERRORS:
        return ConsoleError(None, text)
    if text == ASH_ONLINE_ERROR:
        return ConsoleError(ONLINE_ERROR_CODE, text)
    for code, pattern in _CATALOGUE:
        if pattern.match(text):
            return ConsoleError(code, text)
    return None


def parse_error_line(line: str) -> ConsoleError | None:
    """The error a reply line reports, or ``None`` for an ordinary line (ASSUMED 3).

    Accepted: ``error: <text>`` (any text), a known text alone (shell errors, the motion
    catalogue, `ash`'s online-mode text), and either with a leading catalogue number, which then
    is the error's number."""
    text = line.strip()
    prefixed = text.startswith(ERROR_PREFIX)
    if prefixed:
        text = text[len(ERROR_PREFIX) :].strip()
    numbered = _LEADING_NUMBER.match(text)
    if numbered is not None:
        known = _known_text(numbered["text"])
        if known is not None or prefixed:
            return ConsoleError(int(numbered["code"]), numbered["text"])
    known = _known_text(text)
    if known is not None:
        return known
    return ConsoleError(None, text) if prefixed else None


def format_error(code: int | None, text: str | None = None) -> str:
    """The line the console prints for a motion error ``code`` (or a shell error ``text``)."""
    if code is None:
        assert text is not None
        return ERROR_PREFIX + text
    return ERROR_PREFIX + (text if text is not None else MOTION_ERRORS[code])


def first_error(lines: Sequence[str]) -> ConsoleError | None:
    for line in lines:
        error = parse_error_line(line)
        if error is not None:
            return error
    return None


def needs_point_of_control(text: str | bytes) -> bool:
    """Whether the console printed the PAUSE/CONTINUE request (it now waits for the button)."""
    needle = "PAUSE/CONTINUE"
    return (needle.encode() in text) if isinstance(text, bytes) else (needle in text)


# --- `w0` / `w2` position read-out -------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PositionTable:
    """What a `w0`/`w2` read-out says: WORLD (mm, degrees), and the joint rows when printed."""

    world: tuple[float, ...]
    joints: tuple[float, ...] | None = None
    pulses: tuple[int, ...] | None = None
    units: str = "mm"


_ROW = re.compile(r"^(?P<label>PULSES|JOINTS|WORLD):?(?P<rest>.*)$")
_WORLD_UNITS = re.compile(r"^WORLD:?\s*\((?P<unit>mm|in)\)")


_NUMBER = re.compile(r"[+-]?\d+(?:\.\d+)?")


def _six(text: str, pattern: str, what: str) -> list[str]:
    """Six numbers of a row; fixed-width cells may touch (`%+10.3f` of a wide value)."""
    cells = _NUMBER.findall(text)
    if (
        len(cells) != 6
        or _NUMBER.sub("", text).strip()
        or not all(re.fullmatch(pattern, cell) for cell in cells)
    ):
        raise ProtocolError(DEVICE, f"unreadable position read-out {what}: {text!r}")
    return cells


def parse_position_table(lines: Sequence[str]) -> PositionTable:
    """The read-out of `w0`/`w2` (C500C.md): the WORLD values are on the first non-empty line
    after the `WORLD (mm) ...` units line; the older single-line form `WORLD  v v v v v v` is
    accepted too. PULSES are integers, JOINTS and WORLD decimals. A read-out in inches is
    refused: at 0.001 in (25.4 um) the console's resolution is too coarse to compensate with,
    and a silent conversion would hide that (switch the controller to metric)."""
    world: tuple[float, ...] | None = None
    joints: tuple[float, ...] | None = None
    pulses: tuple[int, ...] | None = None
    units: str | None = None
    expect_world_values = False
    for line in lines:
        stripped = line.strip()
        if not stripped:
            continue
        if expect_world_values:
            if world is not None:
                raise ProtocolError(DEVICE, f"position read-out has WORLD twice: {line!r}")
            world = tuple(float(v) for v in _six(stripped, _DECIMAL, "WORLD values"))
            expect_world_values = False
            continue
        unit_line = _WORLD_UNITS.match(stripped)
        if unit_line is not None:
            units = unit_line["unit"]
            if units == "in":
                raise ProtocolError(
                    DEVICE,
                    "the console prints WORLD in inches (0.001 in = 25.4 um): switch the "
                    "controller to metric units",
                )
            expect_world_values = True
            continue
        row = _ROW.match(stripped)
        if row is None:
            continue  # title, column headers
        label, rest = row["label"], row["rest"]
        if label == "WORLD":  # the older single-line form
            if world is not None:
                raise ProtocolError(DEVICE, f"position read-out has WORLD twice: {line!r}")
            world = tuple(float(v) for v in _six(rest, _DECIMAL, "WORLD row"))
        elif label == "JOINTS":
            if joints is not None:
                raise ProtocolError(DEVICE, f"position read-out has JOINTS twice: {line!r}")
            joints = tuple(float(v) for v in _six(rest, _DECIMAL, "JOINTS row"))
        else:
            if pulses is not None:
                raise ProtocolError(DEVICE, f"position read-out has PULSES twice: {line!r}")
            pulses = tuple(int(float(v)) for v in _six(rest, rf"{_INTEGER}(?:\.\d+)?", "PULSES"))
    if expect_world_values:
        raise ProtocolError(DEVICE, "position read-out ends after the WORLD units line")
    if world is None:
        raise ProtocolError(DEVICE, "position read-out has no WORLD values")
    return PositionTable(world=world, joints=joints, pulses=pulses, units=units or "mm")


def parse_world_pose(lines: Sequence[str]) -> Pose:
    """The WORLD values of a `w0`/`w2` read-out as a :class:`Pose` (mm, degrees)."""
    return Pose(*parse_position_table(lines).world)


Layout = Literal["firmware", "single-line"]


def format_w_table(
    world: Sequence[float],
    joints: Sequence[float],
    pulses: Sequence[int],
    *,
    title: str = ACTUAL_TITLE,
    layout: Layout = "firmware",
) -> list[str]:
    """The lines of a `w0`/`w2` read-out as the emulator prints them: the firmware layout of
    C500C.md (ASSUMED 8 where it is not exact), or the older single-line layout this project
    used before (kept only for the parser's compatibility test)."""
    for label, values in (("PULSES", pulses), ("JOINTS", joints), ("WORLD", world)):
        if len(values) != 6:
            raise ValueError(f"{label}: six values expected, not {len(values)}")
    if layout == "single-line":
        header = " " * ROW_LABEL_WIDTH + "".join(f"{n:>10}" for n in "123456")
        return [
            header,
            f"{'PULSES:':<{ROW_LABEL_WIDTH}}" + "".join(f"{float(v):+10.3f}" for v in pulses),
            f"{'JOINTS:':<{ROW_LABEL_WIDTH}}" + "".join(f"{v:+10.3f}" for v in joints),
            f"{'WORLD:':<{ROW_LABEL_WIDTH}}" + "".join(f"{v:+10.3f}" for v in world),
        ]
    indent = " " * ROW_LABEL_WIDTH
    return [
        title,
        "",
        indent + "  " + AXIS_HEADER,
        f"{'PULSES':<{ROW_LABEL_WIDTH}}" + " ".join(f"{int(v):+10d}" for v in pulses),
        f"{'JOINTS':<{ROW_LABEL_WIDTH}}" + " ".join(f"{v:+10.3f}" for v in joints),
        "",
        indent + "  " + WORLD_HEADER,
        f"{'WORLD':<{ROW_LABEL_WIDTH}}" + " ".join(f"{unit:>10}" for unit in WORLD_UNITS_MM),
        " " * WORLD_VALUES_INDENT + " ".join(f"{v:+10.3f}" for v in world),
    ]


# --- command sequences -------------------------------------------------------------------------

#: Console commands that move the arm (C500C.md "Motion and locations"): a held robot never
#: sends them; everything else (`set`, `wshift`, `here`, `finish`, `w2`...) moves nothing.
MOTION_COMMANDS = frozenset(
    {
        "move", "moves", "ready", "home", "appro", "appros", "depart", "departs",
        "wx", "wy", "wz", "wxs", "wys", "wzs", "tx", "ty", "tz", "txs", "tys", "tzs",
        "joint", "nolimp", "limp",
    }
)  # fmt: skip


def is_motion_command(command: str) -> bool:
    """Whether ``command`` can move the arm (its first word is in MOTION_COMMANDS)."""
    return command.strip().split(" ", 1)[0].lower() in MOTION_COMMANDS


def round_mm(value_mm: float) -> float:
    """A distance as the console can take it: rounded to 0.001 mm (no negative zero)."""
    return float(f"{value_mm:.{POSITION_DECIMALS}f}") + 0.0


def format_mm(value_mm: float) -> str:
    return f"{round_mm(value_mm):.{POSITION_DECIMALS}f}"


def round_deg(value_deg: float) -> float:
    """An angle as `wshift` takes it: 0.001 degree (C500C.md: mm and degrees, 3 decimals)."""
    return float(f"{value_deg:.{ANGLE_DECIMALS}f}") + 0.0


def format_deg(value_deg: float) -> str:
    return f"{round_deg(value_deg):.{ANGLE_DECIMALS}f}"


#: One write to the console: the commands sent together (C500C.md: `set` and `wshift` may go in
#: one write, the 1,024-byte kernel FIFO holds them), each answered by its own prompt.
Write = tuple[str, ...]


def absolute_move_commands(
    offset_mm: Vector3,
    *,
    online: bool,
    goal: str = "opgoal",
    target: str = "cur",
    readback: bool = True,
    rotation_deg: Vector3 = (0.0, 0.0, 0.0),
) -> tuple[list[Write], Vector3]:
    """The absolute-move sequence of C500C.md (thesis 6.4.4: every goal is defined from the
    operational goal), as writes, and the offset actually commanded after rounding to 0.001 mm.
    ``rotation_deg``: the wshift angles z-rot, y-rot, x-rot (degrees, sent with 0.001 degree:
    :func:`round_deg`); zeros print as `0,0,0`, the bytes of a translation-only step. Without
    ``readback`` the `w2` at the end is left out."""
    commanded = (round_mm(offset_mm[0]), round_mm(offset_mm[1]), round_mm(offset_mm[2]))
    dx, dy, dz = (format_mm(v) for v in commanded)
    angles = [round_deg(v) for v in rotation_deg]
    rotation = ",".join(format_deg(v) for v in angles) if any(angles) else "0,0,0"
    writes: list[Write] = [
        (f"set {target} = {goal}", f"wshift {target},{dx},{dy},{dz},{rotation}"),
        (f"{'moves' if online else 'move'} {target}",),
        ("finish",),
    ]
    if readback:
        writes.append(("w2",))
    return writes, commanded


#: The console's speed setting (C500C.md "Motion and locations": `speed [%]`; catalogue 015
#: `Illegal speed chosen` outside it): a whole percentage of the controller's maximum speed.
MIN_SPEED_PERCENT = 1
MAX_SPEED_PERCENT = 100


def speed_command(percent: int) -> str:
    """`speed N` (C500C.md "Motion and locations"): the controller's speed for the motions
    that follow, in percent of its maximum. It moves nothing. The acceleration has no console
    command (C500C.md lists none): the controller keeps its own."""
    if isinstance(percent, bool) or not isinstance(percent, int):
        raise ValueError(f"a speed is a whole percentage, not {percent!r}")
    if not MIN_SPEED_PERCENT <= percent <= MAX_SPEED_PERCENT:
        raise ValueError(f"speed {percent} % is outside {MIN_SPEED_PERCENT}..{MAX_SPEED_PERCENT} %")
    return f"speed {percent}"


def incremental_move_commands(
    delta_mm: Vector3, *, readback: bool = True
) -> tuple[list[Write], Vector3]:
    """The incremental sequence (`wx`/`wy`/`wz`, kept to reproduce the thesis's comparison):
    one relative move per non-zero axis, then `finish` and the `w2` read-back."""
    commanded = (round_mm(delta_mm[0]), round_mm(delta_mm[1]), round_mm(delta_mm[2]))
    writes: list[Write] = [
        (f"w{axis} {format_mm(value)}",)
        for axis, value in zip("xyz", commanded, strict=True)
        if value != 0.0
    ]
    writes.append(("finish",))
    if readback:
        writes.append(("w2",))
    return writes, commanded
