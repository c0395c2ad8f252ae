"""The robot-side program's rules (controller/ur/thermocomp_offset.script) as one pure step
function: the UR emulator runs it every controller cycle, and the tests check the rules on it
and that the script's constants are these.

Each controller cycle (2 ms on the e-Series) the script's thread reads the registers
(drivers/ur/registers.py) and decides the offset to apply with ``path_offset_set``:

1. **Heartbeat watchdog.** The sequence register must change within ``watchdog_s``; when it
   has not, the PC is silent and the offset is FROZEN where it is (never a jump back to zero:
   a thermal correction of 100 um dropped at once is a 100 um step of the tool).
2. **Hold flag.** Set: the offset is frozen where it is.
3. **Limits.** A target whose translation is longer than ``max_offset_m`` or whose rotation
   vector is longer than ``max_rotation_rad``, or any component not finite, is refused: the
   offset stays frozen where it is (a PC that sends such a value is wrong; following it
   partly would still be following it) and the status says so.
4. **Rate limit.** Otherwise the applied offset moves towards the target by at most
   ``max_speed_m_s`` (translation) and ``max_angular_speed_rad_s`` (rotation) per second,
   so no value a PC sends can jerk the arm (the script manual warns that discontinuous
   offsets cause protective stops).

Rotations are small (thermal corrections are tens of urad): the rate limit moves the rotation
vector component-wise towards the target, which for such angles is the rotation between them
to better than 1e-9 rad.

Before the first target the offset is zero and STATUS_WAITING is set; a sequence of 0 is "no
target yet" (the driver's first write is 1).

**Holding a dwell for the frames** (the main program's ``tc_wait_for_frames(k)``, after the
Wait of measured pose k; drivers/ur/robot.py ``hold_dwell``). The program stays at rest on
pose k past its taught dwell while the frames register (input int B+2) says k, until it says
anything else, the PC is silent (the watchdog above), or FRAMES_TIMEOUT_S have passed since
the taught dwell ended: :func:`holds_dwell`. The emulator's taught program
(drivers/sim/ur/player.py) asks it at the end of every measured dwell.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import dataclass, field

from drivers.ur.registers import (
    STATUS_HELD,
    STATUS_RATE_LIMITED,
    STATUS_REFUSED,
    STATUS_SILENT,
    STATUS_WAITING,
)
from drivers.ur.rtde_protocol import CONTROLLER_CYCLE_S

Offset = tuple[float, float, float, float, float, float]
ZERO_OFFSET: Offset = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

# The script's constants (controller/ur/thermocomp_offset.script; tests/test_ur_program.py
# checks they are equal).
#: The largest correction followed: 2 mm and 2 mrad, about 25 times the UR5e bench's
#: uncompensated warm-up drift (79.5 um, issue 31): room for a real arm's larger drift, and
#: small against a taught path's clearances.
MAX_OFFSET_M = 0.002
MAX_ROTATION_RAD = 0.002
#: The fastest the offset changes: 1 mm/s and 1 mrad/s; a thermal drift changes by um per
#: minute, and a new model value (10-125 Hz) is reached within a few cycles.
MAX_SPEED_M_S = 0.001
MAX_ANGULAR_SPEED_RAD_S = 0.001
#: The PC's heartbeat must change the sequence within this (s); the driver writes at least
#: every robot.ur_heartbeat_s (default 0.1 s).
WATCHDOG_S = 0.5
#: The longest the main program holds a measured pose's dwell for the PC's frames
#: (tc_wait_for_frames, module docstring): a measurement takes ~0.1 s on an idle PC and
#: 0.8-2.9 s on a loaded one (closing note of 2026-11-27); a PC slower than this is in trouble,
#: and the production program must not stand still longer for it (the frames are then thrown
#: away by the PC: the program left during them).
FRAMES_TIMEOUT_S = 5.0


@dataclass(frozen=True, slots=True)
class ProgramLimits:
    max_offset_m: float = MAX_OFFSET_M
    max_rotation_rad: float = MAX_ROTATION_RAD
    max_speed_m_s: float = MAX_SPEED_M_S
    max_angular_speed_rad_s: float = MAX_ANGULAR_SPEED_RAD_S
    watchdog_s: float = WATCHDOG_S
    cycle_s: float = CONTROLLER_CYCLE_S
    frames_timeout_s: float = FRAMES_TIMEOUT_S

    @property
    def watchdog_cycles(self) -> int:
        return max(1, round(self.watchdog_s / self.cycle_s))


@dataclass(frozen=True, slots=True)
class ProgramInputs:
    """What the program reads from the input registers in one cycle."""

    sequence: int = 0
    hold: int = 0
    target: Sequence[float] = ZERO_OFFSET


#: The largest program instance (the script: floor(random() * INSTANCE_MAX) + 1).
INSTANCE_MAX = 1_000_000_000


@dataclass(slots=True)
class OffsetProgram:
    """The program's state and its step (module docstring)."""

    limits: ProgramLimits = field(default_factory=ProgramLimits)
    applied: Offset = ZERO_OFFSET
    accepted_sequence: int = 0
    status: int = STATUS_WAITING
    _last_sequence: int = 0
    _silent_cycles: int = 0
    cycles: int = 0
    #: drawn once when the program starts, as the script's random() (registers.py)
    instance: int = field(default_factory=lambda: random.randint(1, INSTANCE_MAX))

    @property
    def pc_silent(self) -> bool:
        """The heartbeat watchdog has fired (the script's global ``tc_pc_silent``)."""
        return self._silent_cycles >= self.limits.watchdog_cycles

    def step(self, inputs: ProgramInputs) -> Offset:
        """One controller cycle: the offset to apply (``applied`` afterwards)."""
        self.cycles += 1
        limits = self.limits
        if inputs.sequence != self._last_sequence:
            self._last_sequence = inputs.sequence
            self._silent_cycles = 0
        else:
            self._silent_cycles += 1
        if inputs.sequence == 0 and self.accepted_sequence == 0:
            self.status = STATUS_WAITING
            return self.applied
        status = 0
        if self._silent_cycles >= limits.watchdog_cycles:
            status |= STATUS_SILENT
        if inputs.hold != 0:
            status |= STATUS_HELD
        if status:
            self.status = status
            return self.applied  # frozen where it is
        target = tuple(float(v) for v in inputs.target)
        if not within_limits(target, limits):
            self.status = STATUS_REFUSED
            return self.applied
        self.accepted_sequence = inputs.sequence
        applied, limited = _towards(self.applied, target, limits)
        self.applied = applied
        self.status = STATUS_RATE_LIMITED if limited else 0
        return applied


def holds_dwell(
    pose: int, frames: int, pc_silent: bool, held_s: float, limits: ProgramLimits
) -> bool:
    """``tc_wait_for_frames(pose)`` goes on waiting this cycle (module docstring): the frames
    register still says this pose, the PC is not silent, and the hold has lasted
    ``held_s`` < FRAMES_TIMEOUT_S."""
    return frames == pose and not pc_silent and held_s < limits.frames_timeout_s


def within_limits(target: Sequence[float], limits: ProgramLimits) -> bool:
    """Six finite components, translation and rotation within the program's limits. Written
    as the script writes it: a comparison that is false for NaN refuses it."""
    if len(target) != 6:
        return False
    if not all(abs(v) <= 1.0 for v in target):  # also false for NaN and infinities
        return False
    translation = math.sqrt(target[0] ** 2 + target[1] ** 2 + target[2] ** 2)
    rotation = math.sqrt(target[3] ** 2 + target[4] ** 2 + target[5] ** 2)
    return translation <= limits.max_offset_m and rotation <= limits.max_rotation_rad


def _limited_step(
    now: tuple[float, float, float], goal: tuple[float, float, float], largest: float
) -> tuple[tuple[float, float, float], bool]:
    delta = (goal[0] - now[0], goal[1] - now[1], goal[2] - now[2])
    length = math.sqrt(delta[0] ** 2 + delta[1] ** 2 + delta[2] ** 2)
    if length <= largest:
        return goal, False
    scale = largest / length
    return (now[0] + delta[0] * scale, now[1] + delta[1] * scale, now[2] + delta[2] * scale), True


def _towards(
    applied: Offset, target: Sequence[float], limits: ProgramLimits
) -> tuple[Offset, bool]:
    """One cycle's move of the applied offset towards ``target`` at the rate limits."""
    position, limited_p = _limited_step(
        (applied[0], applied[1], applied[2]),
        (target[0], target[1], target[2]),
        limits.max_speed_m_s * limits.cycle_s,
    )
    rotation, limited_r = _limited_step(
        (applied[3], applied[4], applied[5]),
        (target[3], target[4], target[5]),
        limits.max_angular_speed_rad_s * limits.cycle_s,
    )
    return (*position, *rotation), limited_p or limited_r
