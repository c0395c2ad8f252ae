"""Which RTDE registers the UR driver and the robot-side program (controller/ur/
thermocomp_offset.script) share, relative to one base register (robot.register_base).

Everything is in the controller's units on the wire: metres and a rotation vector in radians
(a URScript pose, the unit path_offset_set takes), base frame. The driver converts from the
daemon's millimetres.

PC -> robot (input registers, written by the UR driver):

    input_int_register_{B}        sequence: +1 on every write (the heartbeat; wraps at 2^31)
    input_int_register_{B+1}      hold: 1 freezes the offset where it is, 0 follows
    input_int_register_{B+2}      frames: k while the PC takes the tool cameras' frames at
                                  measured pose k (the program holds that dwell until it is
                                  0 again, at most FRAMES_TIMEOUT_S: tc_wait_for_frames), else 0
    input_double_register_{B..B+5}  the correction target dx, dy, dz (m), rx, ry, rz (rad)

robot -> PC (output registers, written by the program every controller cycle):

    output_int_register_{B}       at measured pose: k (1-based index of the taught pose the
                                  program dwells at, a measured one), 0 elsewhere
    output_int_register_{B+1}     the sequence of the last target the program accepted
    output_int_register_{B+2}     status bits (STATUS_*)
    output_int_register_{B+3}     the program's instance: a random number drawn once when the
                                  program starts, so a restart shows even when it happens
                                  between two state packages (its other outputs may repeat)
    output_double_register_{B..B+5}  the offset applied now (m, rad)

B is 24..41 (registers 0-23 collide with the fieldbus adapters: the upper range; B+5 <= 46
keeps register 47 free, which ur-rtde's RTDEIOInterface uses as its command register).

The frames register has a recipe of its own (:attr:`RegisterMap.frames_inputs`): a
measurement's start and end write it, never the correction nor the hold flag. It moves
nothing: it only makes the program stay at rest on a measured pose longer (a safe side), so it
is written whether the correction is held or not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.base import Vector3
from drivers.errors import DeviceError
from drivers.goals import require_finite
from drivers.ur.rtde_variables import double_input, double_output, int_input, int_output

#: The default base register and the allowed range of bases (module docstring).
DEFAULT_REGISTER_BASE = 24
REGISTER_BASE_MIN = 24
REGISTER_BASE_MAX = 41

#: Status bits of output_int_register_{B+2}.
STATUS_HELD = 1  # the hold flag is set: offset frozen
STATUS_SILENT = 2  # the heartbeat watchdog fired: offset frozen
STATUS_REFUSED = 4  # the last target was over a limit or not finite: offset frozen
STATUS_RATE_LIMITED = 8  # the offset is still moving towards the target at the rate limit
STATUS_WAITING = 16  # no target received since the program started: offset zero

#: The six components of a correction on the wire.
AXES = ("dx", "dy", "dz", "rx", "ry", "rz")
MM_PER_M = 1000.0


def wire_target(
    offset_mm: Vector3,
    rotation_rad: Vector3,
    limit_mm: float,
    limit_rad: float,
    *,
    device: str,
) -> tuple[float, ...]:
    """A correction (mm, rotation vector in rad) as the six target registers (m, rad); a
    DeviceError before any byte when not finite or over the PC's limits
    (robot.correction_limit_mm / _rad)."""
    require_finite(offset_mm, "correction", device)
    require_finite(rotation_rad, "correction rotation", device)
    length = math.hypot(*offset_mm)
    angle = math.hypot(*rotation_rad)
    if length > limit_mm:
        raise DeviceError(
            device, f"refused correction of {length:.4f} mm > robot.correction_limit_mm {limit_mm}"
        )
    if angle > limit_rad:
        raise DeviceError(
            device,
            f"refused correction rotation of {angle:.6f} rad > robot.correction_limit_rad "
            f"{limit_rad}",
        )
    return (*(v / MM_PER_M for v in offset_mm), *(float(v) for v in rotation_rad))


@dataclass(frozen=True, slots=True)
class RegisterMap:
    """The register names of one base (module docstring)."""

    base: int = DEFAULT_REGISTER_BASE

    def __post_init__(self) -> None:
        if not REGISTER_BASE_MIN <= self.base <= REGISTER_BASE_MAX:
            raise ValueError(
                f"register base {self.base} outside {REGISTER_BASE_MIN}..{REGISTER_BASE_MAX}"
            )

    @property
    def sequence(self) -> str:
        return int_input(self.base)

    @property
    def hold(self) -> str:
        return int_input(self.base + 1)

    @property
    def frames(self) -> str:
        return int_input(self.base + 2)

    @property
    def frames_inputs(self) -> tuple[str, ...]:
        """The driver's frames recipe: the frames register alone (module docstring)."""
        return (self.frames,)

    @property
    def target(self) -> tuple[str, ...]:
        return tuple(double_input(self.base + i) for i in range(len(AXES)))

    @property
    def inputs(self) -> tuple[str, ...]:
        """The driver's correction recipe, in order: a correction and the hold flag."""
        return (self.sequence, self.hold, *self.target)

    @property
    def hold_inputs(self) -> tuple[str, ...]:
        """The driver's hold recipe: the heartbeat and the hold flag, never the correction
        registers (a hold, a heartbeat or a resume writes nothing into them)."""
        return (self.sequence, self.hold)

    @property
    def at_pose(self) -> str:
        return int_output(self.base)

    @property
    def accepted_sequence(self) -> str:
        return int_output(self.base + 1)

    @property
    def status(self) -> str:
        return int_output(self.base + 2)

    @property
    def instance(self) -> str:
        return int_output(self.base + 3)

    @property
    def applied(self) -> tuple[str, ...]:
        return tuple(double_output(self.base + i) for i in range(len(AXES)))

    @property
    def outputs(self) -> tuple[str, ...]:
        return (self.at_pose, self.accepted_sequence, self.status, self.instance, *self.applied)
