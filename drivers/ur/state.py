"""What the UR driver reads (drivers/ur/robot.py): the state packages the controller streams,
decoded into a drivers.base.OffsetRobotState, the sequence arithmetic of the registers the
program echoes, and the watch that tells a restarted offset program from a running one.

The other half, what the driver writes (the correction, the sequence and the hold flag), stays
in the robot: a hold's bytes must follow its permit change with no await in between.
"""

from __future__ import annotations

import time

from drivers.base import OffsetRobotState
from drivers.ur.modes import RuntimeState
from drivers.ur.registers import MM_PER_M, RegisterMap
from drivers.ur.rtde_protocol import Recipe, Value

#: The sequence register is an INT32: it runs 1 .. 2^31 - 1 and wraps to 1 (0 is "no target
#: yet" for the program).
SEQUENCE_MAX = (1 << 31) - 1
#: A sequence further behind the last one than this has wrapped (2^30: two years at 500 Hz).
SEQUENCE_WRAP_GAP = 1 << 30
STATE_OUTPUTS = (
    "timestamp",
    "actual_q",
    "actual_qd",
    # the motor heat of a followed run (drivers/ur/motion.py, daemon/run/followed/heat.py)
    "target_qdd",
    "actual_TCP_pose",
    "actual_TCP_speed",
    "joint_temperatures",
    "robot_mode",
    "safety_mode",
    "runtime_state",
)


def next_sequence(sequence: int) -> int:
    """The sequence after ``sequence`` (1 .. SEQUENCE_MAX, wrapping to 1)."""
    return sequence % SEQUENCE_MAX + 1


def at_or_past(sequence: int, echoed: int) -> bool:
    """The controller's ``echoed`` sequence is at ``sequence`` or past it (or wrapped past)."""
    gap = sequence - echoed
    return gap <= 0 or gap > SEQUENCE_WRAP_GAP


def decode_state(
    registers: RegisterMap, recipe: Recipe, values: tuple[Value, ...]
) -> OffsetRobotState:
    """One state package (the output recipe: STATE_OUTPUTS, the program's output registers),
    in the daemon's units (mm, rad)."""
    named = dict(zip(recipe.names, values, strict=True))

    def floats(name: str) -> tuple[float, ...]:
        value = named[name]
        assert isinstance(value, tuple)
        return tuple(float(v) for v in value)

    def integer(name: str) -> int:
        return int(named[name])  # type: ignore[arg-type]

    pose = floats("actual_TCP_pose")
    speed = floats("actual_TCP_speed")
    applied = [float(named[name]) for name in registers.applied]  # type: ignore[arg-type]
    return OffsetRobotState(
        timestamp_s=float(named["timestamp"]),  # type: ignore[arg-type]
        received_s=time.monotonic(),
        joints_rad=floats("actual_q"),
        joint_speeds_rad_s=floats("actual_qd"),
        tcp_pose=(*(v * MM_PER_M for v in pose[:3]), *pose[3:]),  # type: ignore[arg-type]
        tcp_speed=(*(v * MM_PER_M for v in speed[:3]), *speed[3:]),  # type: ignore[arg-type]
        joint_temperatures_c=floats("joint_temperatures"),
        robot_mode=integer("robot_mode"),
        safety_mode=integer("safety_mode"),
        runtime_state=integer("runtime_state"),
        at_pose=integer(registers.at_pose),
        accepted_sequence=integer(registers.accepted_sequence),
        program_status=integer(registers.status),
        applied_offset_mm=(applied[0] * MM_PER_M, applied[1] * MM_PER_M, applied[2] * MM_PER_M),
        applied_rotation_rad=(applied[3], applied[4], applied[5]),
        program_instance=integer(registers.instance),
    )


class ProgramWatch:
    """After a run starts following the offset program (:meth:`follow`), its restart -- seen
    stopped, a new instance, or its accepted sequence gone back -- means its offset state is
    gone: :meth:`check` says so once, and :attr:`lost` keeps why until the next follow."""

    def __init__(self) -> None:
        self._following = False  # follow() was called: a program restart is a fault
        self.lost: str | None = None  # why the followed program's state is gone
        self._accepted_max = 0  # the highest sequence the followed program accepted
        self._instance = 0  # the followed program's instance (drivers/ur/registers.py)

    def follow(self, state: OffsetRobotState) -> None:
        """Follow the program as it is in ``state`` from here on."""
        self._following = True
        self.lost = None
        self._accepted_max = state.accepted_sequence
        self._instance = state.program_instance

    def check(self, state: OffsetRobotState) -> str | None:
        """Why the program's offset state is gone, when ``state`` first shows it; else None."""
        if not self._following or self.lost is not None:
            return None
        accepted = state.accepted_sequence
        if state.runtime_state == RuntimeState.STOPPED:
            lost = "the offset program was stopped"
        elif state.program_instance != self._instance:
            # a stop and a play between two state packages: nothing else need show it (a
            # fresh program held from its start accepts nothing, like the old one)
            lost = "the offset program restarted (a new program instance)"
        elif accepted < self._accepted_max and self._accepted_max - accepted < SEQUENCE_WRAP_GAP:
            lost = "the offset program restarted (its accepted sequence went back)"
        else:
            self._accepted_max = accepted
            return None
        self.lost = lost
        return lost


def state_modes(state: OffsetRobotState | None) -> dict[str, str]:
    """The robot's, safety, runtime and program modes of ``state`` for its status' extras
    (none before the first package)."""
    if state is None:
        return {}
    return {
        "robot_mode": str(state.robot_mode),
        "safety_mode": str(state.safety_mode),
        "runtime_state": str(state.runtime_state),
        "program_status": str(state.program_status),
    }
