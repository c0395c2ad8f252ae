"""The C500C console commands the driver sends, as pure functions: which ones move the arm
(the hold refuses those), values rounded as the console takes them, and the move sequences
(docs/reference/c500c-console.md "Motion and locations", "The absolute-move sequence").
"""

from __future__ import annotations

from drivers.base import Vector3
from drivers.c500c.texts import ANGLE_DECIMALS, POSITION_DECIMALS

# --- command sequences -------------------------------------------------------------------------

#: Console commands that move the arm (docs/reference/c500c-console.md "Motion and locations"): a
#: held robot never sends them; everything else (`set`, `wshift`, `here`, `finish`, `w2`...) moves
#: nothing.
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
    """An angle as `wshift` takes it: 0.001 degree (docs/reference/c500c-console.md: mm and degrees,
    3 decimals)."""
    return float(f"{value_deg:.{ANGLE_DECIMALS}f}") + 0.0


def format_deg(value_deg: float) -> str:
    return f"{round_deg(value_deg):.{ANGLE_DECIMALS}f}"


#: One write to the console: the commands sent together (docs/reference/c500c-console.md: `set` and
#: `wshift` may go in one write, the 1,024-byte kernel FIFO holds them), each answered by its own
#: prompt.
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
    """The absolute-move sequence of docs/reference/c500c-console.md (thesis 6.4.4: every goal is
    defined from the operational goal), as writes, and the offset actually commanded after rounding
    to 0.001 mm. ``rotation_deg``: the wshift angles z-rot, y-rot, x-rot (degrees, sent with 0.001
    degree: :func:`round_deg`); zeros print as `0,0,0`, the bytes of a translation-only step.
    Without ``readback`` the `w2` at the end is left out."""
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


#: The console's speed setting (docs/reference/c500c-console.md "Motion and locations": `speed [%]`;
#: catalogue 015 `Illegal speed chosen` outside it): a whole percentage of the controller's maximum
#: speed.
MIN_SPEED_PERCENT = 1
MAX_SPEED_PERCENT = 100


def speed_command(percent: int) -> str:
    """`speed N` (docs/reference/c500c-console.md "Motion and locations"): the controller's speed
    for the motions that follow, in percent of its maximum. It moves nothing. The acceleration has
    no console command (docs/reference/c500c-console.md lists none): the controller keeps its
    own."""
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
