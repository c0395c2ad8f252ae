"""What a UR reports about itself for ``thermocomp devices check`` (drivers.base.
RobotDescription): over RTDE the protocol version it accepted, the controller's version, the
robot, safety and runtime modes, the joints, TCP and joint temperatures, whether the input
registers are ours and whether the offset program (controller/ur/thermocomp_offset.script)
answers in its output registers; over the Dashboard Server the program's state, PolyScope's
version and Remote Control.

A problem is what would stop a followed run or its hold, one line each, saying what to do:
the arm not running, a safety stop, the program stopped, the offset program silent (not in
the program, or another REG_BASE), and -- with robot.pause_program_on_hold -- a Dashboard
that does not answer or a robot in Local Control (the Dashboard's ``pause`` needs Remote
Control; UR's Dashboard Server manual, e-Series).
"""

from __future__ import annotations

import math
from typing import Protocol

from config.settings import RobotSettings
from drivers.base import OffsetRobotState, RobotDescription
from drivers.errors import DeviceError
from drivers.ur import registers as regs
from drivers.ur.dashboard_client import DashboardClient
from drivers.ur.modes import RobotMode, RuntimeState, SafetyMode
from drivers.ur.rtde_protocol import PROTOCOL_VERSION


class URRobot(Protocol):
    """What the description reads of drivers/ur/robot.py URRobot (which imports this module)."""

    @property
    def settings(self) -> RobotSettings: ...

    @property
    def registers(self) -> regs.RegisterMap: ...

    @property
    def dashboard(self) -> DashboardClient: ...

    @property
    def controller_version(self) -> tuple[int, int, int, int] | None: ...

    async def read_state(self) -> OffsetRobotState: ...


#: Safety modes a followed run can go on in.
SAFE_MODES = (SafetyMode.NORMAL, SafetyMode.REDUCED)
STATUS_WORDS = (
    (regs.STATUS_HELD, "held"),
    (regs.STATUS_SILENT, "PC silent"),
    (regs.STATUS_REFUSED, "target refused"),
    (regs.STATUS_RATE_LIMITED, "rate limited"),
    (regs.STATUS_WAITING, "no target yet"),
)


def _name(enum: type[RobotMode] | type[SafetyMode] | type[RuntimeState], value: int) -> str:
    try:
        return enum(value).name
    except ValueError:
        return f"unknown ({value})"


def status_words(status: int) -> str:
    words = [word for bit, word in STATUS_WORDS if status & bit]
    return ", ".join(words) if words else "normal"


def _span(names: tuple[str, ...]) -> str:
    numbers = [int(name.rsplit("_", 1)[1]) for name in names]
    return f"{min(numbers)}-{max(numbers)}" if len(numbers) > 1 else str(numbers[0])


async def describe_ur(robot: URRobot) -> RobotDescription:
    """The UR's description (module docstring). Raises DeviceError when RTDE gives no state
    (the link is the check's one failure then); a Dashboard that fails is a problem."""
    settings, registers = robot.settings, robot.registers
    state = await robot.read_state()  # a heartbeat read back: the link is live
    facts: list[tuple[str, str]] = []
    problems: list[tuple[str, str]] = []
    version = robot.controller_version
    facts.append(
        (
            "RTDE",
            f"{settings.host}:{settings.rtde_port}, protocol version {PROTOCOL_VERSION} "
            f"accepted, state at {settings.rtde_frequency_hz:g} Hz",
        )
    )
    facts.append(("controller", ".".join(map(str, version)) if version else "unknown"))
    mode = _name(RobotMode, state.robot_mode)
    facts.append(("robot mode", mode))
    if state.robot_mode != RobotMode.RUNNING:
        problems.append(
            ("robot mode", f"{mode}, not RUNNING: power the arm on and release its brakes")
        )
    safety = _name(SafetyMode, state.safety_mode)
    facts.append(("safety", safety))
    if state.safety_mode not in SAFE_MODES:
        problems.append(("safety", f"{safety}: clear it on the pendant"))
    runtime = _name(RuntimeState, state.runtime_state)
    facts.append(("program (RTDE)", runtime))
    if state.runtime_state in (RuntimeState.STOPPED, RuntimeState.STOPPING):
        problems.append(
            (
                "program",
                "STOPPED: load the production program with thermocomp_offset.script and "
                "play it (controller/ur/README.md)",
            )
        )
    facts.append(("joints", " ".join(f"{math.degrees(q):.2f}" for q in state.joints_rad) + " deg"))
    x, y, z = state.tcp_pose[:3]
    facts.append(("TCP", f"x {x:.3f} y {y:.3f} z {z:.3f} mm (base frame)"))
    facts.append(
        (
            "joint temperatures",
            " ".join(f"{t:.2f}" for t in state.joint_temperatures_c) + " degC",
        )
    )
    facts.append(
        (
            "registers",
            f"input int {_span((registers.sequence, registers.hold, registers.frames))} and double "
            f"{_span(registers.target)} set up by this PC (free: no other RTDE client holds "
            f"them); output int {_span(registers.outputs[:4])}, double "
            f"{_span(registers.applied)}",
        )
    )
    if state.program_instance == 0:
        facts.append(("offset program", "silent (no instance in its output register)"))
        if state.runtime_state not in (RuntimeState.STOPPED, RuntimeState.STOPPING):
            problems.append(
                (
                    "offset program",
                    f"silent in {registers.instance}: put thermocomp_offset.script in the "
                    f"program's Before Start with REG_BASE = {registers.base} "
                    "(controller/ur/README.md)",
                )
            )
    else:
        facts.append(
            (
                "offset program",
                f"running (instance {state.program_instance}, status "
                f"{state.program_status}: {status_words(state.program_status)}, at pose "
                f"{state.at_pose or '-'})",
            )
        )
    await _dashboard(robot, facts, problems)
    return RobotDescription(tuple(facts), tuple(problems))


async def _dashboard(
    robot: URRobot, facts: list[tuple[str, str]], problems: list[tuple[str, str]]
) -> None:
    settings = robot.settings
    needed = settings.pause_program_on_hold
    dashboard = robot.dashboard
    try:
        program = await dashboard.command("programState")
        polyscope = await dashboard.command("PolyscopeVersion")
        remote = await dashboard.command("isInRemoteControl")
    except DeviceError as err:
        facts.append(("Dashboard", f"no answer: {err.message}"))
        if needed:
            problems.append(
                (
                    "Dashboard",
                    f"{err.message}: a hold cannot pause the program (robot."
                    "pause_program_on_hold; port robot.dashboard_port)",
                )
            )
        return
    facts.append(("Dashboard", f"{settings.host}:{settings.dashboard_port}, {polyscope}"))
    facts.append(("program (Dashboard)", program))
    facts.append(("remote control", remote))
    if needed and remote.strip().lower() != "true":
        problems.append(
            (
                "remote control",
                "the robot is in Local Control: the Dashboard cannot pause the program on a "
                "hold (switch to Remote Control on the pendant, or set "
                "robot.pause_program_on_hold = false)",
            )
        )
