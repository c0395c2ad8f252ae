"""The emulated C500C's state: what the controller knows (arm power, homed, online, point of
control, the commanded and actual locations, named locations, the speed setting) and what it
logs (command lines, motions), with the emulator's constants. The `ash` interpreter that
changes it is drivers/sim/ash.py.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

from drivers.c500c import protocol as proto

#: Emulator simplification: a location farther than this from the base is out of reach (mm).
REACH_MM = 900.0
#: Where the emulated arm starts: x, y, z (mm), z-rot, y-rot, x-rot (degrees).
START_POSE: tuple[float, ...] = (457.200, 0.000, 254.000, 0.000, 90.000, 0.000)
#: The console's speed setting when the controller starts (`speed` prints it; `speed N` sets it,
#: docs/reference/c500c-console.md "Motion and locations"). The emulated arm's joint speeds scale
#: with it (drivers/sim/joint_arm.py).
START_SPEED_PERCENT = 10
#: Command lines the emulator keeps for inspection (tests, drills): the latest ones only.
COMMAND_LOG_LINES = 10_000
Location = tuple[float, float, float, float, float, float]


def as_location(values: Sequence[float]) -> Location:
    """Six numbers (x, y, z mm; z-rot, y-rot, x-rot degrees) as a location."""
    if len(values) != 6:
        raise ValueError(f"a location has six values, not {len(values)}")
    x, y, z, z_rot, y_rot, x_rot = (float(v) for v in values)
    return (x, y, z, z_rot, y_rot, x_rot)


class ConsoleCommandError(Exception):
    """A command failed; ``line`` is what the console prints."""

    def __init__(self, line: str) -> None:
        super().__init__(line)
        self.line = line


#: Console commands that start a motion (the ones the emulator knows).
MOTION_WORDS = ("move", "moves", "wx", "wy", "wz", "wxs", "wys", "wzs")
#: How the controller's console comes back after a restart: the boot ends at the system shell.
RESTART_BANNER = "CROS restarted"


@dataclass(frozen=True, slots=True)
class MotionRecord:
    """One motion the emulated arm performed (tests read them: a played duty cycle's order,
    speeds and dwells)."""

    start_s: float
    end_s: float
    target: Location
    speed_percent: int


@dataclass
class ConsoleState:
    """What the emulated controller knows. Tests may read and change it."""

    arm_power: bool
    homed: bool
    online: bool
    point_of_control: bool
    commanded: Location
    actual: Location
    previous_actual: Location
    in_shell: bool = False
    awaiting_button: bool = False  # a motion waits for PAUSE/CONTINUE
    restarts: int = 0
    speed_percent: int = START_SPEED_PERCENT
    motion_end_s: float = 0.0
    locations: dict[str, Location] = field(default_factory=dict)
    # The latest command lines received, in order (bounded: a sim daemon runs for days at
    # ~250 lines a second), and how many were ever received (fault injection counts them).
    commands: deque[str] = field(default_factory=lambda: deque(maxlen=COMMAND_LOG_LINES))
    received: int = 0

    #: every motion started, in order (bounded like ``commands``): its start and end on the
    #: emulator's clock, the location it was commanded to and the speed setting it ran at
    motions: deque[MotionRecord] = field(default_factory=lambda: deque(maxlen=COMMAND_LOG_LINES))
    motion_count: int = 0  # every motion ever started (``motions`` keeps the latest)

    def log_command(self, line: str) -> None:
        self.commands.append(line)
        self.received += 1

    def motion_commands(self) -> list[str]:
        """The logged command lines that start a motion (what a held robot must never get)."""
        return [c for c in self.commands if proto.is_motion_command(c)]
