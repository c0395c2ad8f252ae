"""The CRS C500C `ash` console's fixed texts and what this project had to assume about it.

The firmware's texts (prompts, line ends, error catalogues, the `w0`/`w2` layout) come from the
project's shared notes (docs/reference/c500c-console.md, beside DESIGN.md); everything no public
source confirms is collected in the single block ``ASSUMED`` below, so that a session on the real
controller corrects it in one place. The functions built on them are :mod:`drivers.c500c.protocol`
(framing), :mod:`drivers.c500c.replies` (questions, errors), :mod:`drivers.c500c.position`
(`w0`/`w2`) and :mod:`drivers.c500c.commands` (command sequences).
"""

from __future__ import annotations

DEVICE = "robot"

# --- from the firmware and the console capture (docs/reference/c500c-console.md)
# ---------------------------------------

#: Ctrl-E interrupts continuous displays; host scripts send it to get a clean line [capture].
CTRL_E = b"\x05"
#: The system shell's prompt; `ash <application>` starts the application shell from it.
SHELL_PROMPT = b"$ "
#: Every line the console prints ends with CR LF, echoes included [capture].
REPLY_LINE_END = b"\r\n"
#: The literal the firmware prints before shell errors [firmware]; motion errors may or may not
#: carry it (docs/reference/c500c-console.md "Errors"), so both forms are accepted.
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
#: Decimals of the angles `wshift` is given (docs/reference/c500c-console.md "The absolute-move
#: sequence": 3).
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
#    creates a location variable (docs/reference/c500c-console.md: `help new`) and prints nothing,
# or an error line    when the name exists already (either is accepted).
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
