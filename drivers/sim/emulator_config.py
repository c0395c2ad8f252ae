"""The C500C emulator's configuration: what it emulates (application, arm states, layout, an
arm in joint space), how it paces and moves, and the faults it injects (:func:`parse_faults`).
The emulator itself is drivers/sim/emulator.py.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Literal

from config import faults as fault_specs
from config.faults import Fault
from drivers.c500c import protocol as proto
from drivers.clock import Clock
from drivers.sim.ash_state import START_POSE

if TYPE_CHECKING:
    from drivers.sim.joint_arm import JointArmConfig

#: How long a `stall` fault lasts when the spec gives no duration (s).
DEFAULT_STALL_S = 5.0
#: How long a `delay` fault delays an answer when the spec gives no duration (s).
DEFAULT_DELAY_S = 1.0

FaultKind = Literal["drop", "corrupt", "delay", "stall", "close", "restart"]
#: The link's faults: each is over once the driver has reconnected.
FAULT_KINDS: tuple[FaultKind, ...] = ("drop", "corrupt", "delay", "stall", "close")
#: Faults of the controller itself: a restart forgets every variable (the taught goal too).
CONTROLLER_FAULT_KINDS: tuple[FaultKind, ...] = ("restart",)


def parse_faults(spec: str) -> tuple[Fault[FaultKind], ...]:
    """Parse ``KIND[=SECONDS][@N|%P],...`` (the spec of config/faults.py): e.g.
    ``drop@5,delay=2@7,corrupt%0.01,close@20``. ``@N`` strikes at the N-th command line, ``%P``
    at every command with probability P. Raises ValueError with a message naming the bad item.

    Each fault applies to the answer of a command line. drop: the command runs but its answer
    (lines and prompt) is lost; corrupt: one byte of the answer is replaced by a byte the
    console never sends; delay: the answer comes ``seconds`` late; stall: the console ignores
    everything for ``seconds``; close: the link closes (a pty is replaced by a fresh one behind
    the same path, a TCP client is disconnected); restart: the command is not executed, the
    controller restarts (every variable forgotten, online off) and its console is back at the
    system shell `$ `.
    """
    return fault_specs.parse_faults(spec, FAULT_KINDS + CONTROLLER_FAULT_KINDS)


@dataclass(frozen=True, slots=True)
class EmulatorConfig:
    application: str = "ash"
    seed: int = 1
    noise_um: float = 0.9  # 1-sigma per axis; 0.9 reproduces the thesis's S_x (Table 6.1)
    move_ms: float = 5.0
    baudrate: int = 57600
    paced: bool = True
    arm_power: bool = True
    homed: bool = True
    online: bool = False  # as a real controller starts; the driver turns it on
    point_of_control: bool = True
    start_in_shell: bool = False  # start at the system shell `$ ` instead of the ash prompt
    start_pose: tuple[float, ...] = START_POSE
    #: how `w0`/`w2` print: the firmware's layout (docs/reference/c500c-console.md); "single-line"
    #: is this project's older layout, kept only for the driver's compatibility test
    layout: proto.Layout = "firmware"
    faults: tuple[Fault[FaultKind], ...] = ()
    #: an arm in joint space (issue 20; drivers/sim/joint_arm.py): its pose is its joints, world
    #: moves go through its inverse kinematics, `w2` prints its JOINTS and PULSES; None: the
    #: emulator of before (no kinematics), and start_pose is where it starts
    joint_arm: JointArmConfig | None = None
    #: the clock the emulated arm's motions are timed on (issue 20, a played duty cycle on the
    #: arm bench: the run's clock, so that a virtual run's dwells and moves share one time);
    #: None: the serving event loop's ``time()`` (wall time), as before
    clock: Clock | None = None


def emulator_config(
    *,
    seed: int = 1,
    noise_um: float = 0.9,
    move_ms: float = 5.0,
    baudrate: int = 57600,
    paced: bool = True,
    faults: str = "",
    application: str = "ash",
    layout: proto.Layout = "firmware",
) -> EmulatorConfig:
    """An :class:`EmulatorConfig` from the command line's or the settings' plain values."""
    if noise_um < 0 or move_ms < 0:
        raise ValueError("noise and move time must not be negative")
    return replace(
        EmulatorConfig(),
        seed=seed,
        noise_um=noise_um,
        move_ms=move_ms,
        baudrate=baudrate,
        paced=paced,
        faults=parse_faults(faults),
        application=application,
        layout=layout,
    )
