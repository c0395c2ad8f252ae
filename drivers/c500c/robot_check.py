"""``thermocomp robot check``: the first command a lab user runs on a real C500C controller.

It connects to the console as configured, synchronises on a prompt (starting `ash` from the
system shell if need be), reports the prompt and application, what is known of arm power,
homing, online mode and point of control, reads `w2` and prints what it parsed. It moves
nothing and changes nothing on the controller: no variable is created and `online` is not
switched (the console has no known query for arm power, homing or point of control: the first
motion command tells, so they are reported as unknown). ``--transcript FILE`` writes every byte
exchanged (JSON lines, drivers/c500c/console.py) so that a user can send a real controller's
transcript back and a test can replay it.

With ``robot.driver = "sim"`` it checks the emulator, started in-process on a pty.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from contextlib import AsyncExitStack
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from config import Settings, load_settings
from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, add_config_argument
from drivers.c500c import protocol as proto
from drivers.c500c.console import Transcript
from drivers.c500c.robot import C500CRobot
from drivers.errors import DeviceError

UNKNOWN = "unknown (no console query; the first motion command tells)"


@dataclass(frozen=True, slots=True)
class CheckReport:
    port: str
    baudrate: int
    flow_control: str
    prompt: str
    application: str
    link: str
    arm_power: bool | None
    homed: bool | None
    online: bool | None
    point_of_control: bool | None
    world: tuple[float, ...]
    joints: tuple[float, ...] | None
    pulses: tuple[int, ...] | None
    units: str
    w2_lines: tuple[str, ...]
    bytes_sent: int
    bytes_received: int

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def text(self) -> str:
        def known(value: bool | None) -> str:
            return UNKNOWN if value is None else ("yes" if value else "no")

        x, y, z, z_rot, y_rot, x_rot = self.world
        rows = [
            f"port             {self.port} ({self.baudrate} baud, "
            f"flow control {self.flow_control})",
            f"prompt           {self.prompt!r}",
            f"application      {self.application}",
            f"link             {self.link}",
            f"arm power        {known(self.arm_power)}",
            f"homed            {known(self.homed)}",
            f"online           {known(self.online)}",
            f"point of control {known(self.point_of_control)}",
            f"w2 WORLD ({self.units})  x {x:+.3f}  y {y:+.3f}  z {z:+.3f}  "
            f"z-rot {z_rot:+.3f}  y-rot {y_rot:+.3f}  x-rot {x_rot:+.3f}",
        ]
        if self.joints is not None:
            rows.append("w2 JOINTS (deg)  " + "  ".join(f"{v:+.3f}" for v in self.joints))
        if self.pulses is not None:
            rows.append("w2 PULSES        " + "  ".join(f"{v:+d}" for v in self.pulses))
        rows.append(f"bytes            {self.bytes_sent} sent, {self.bytes_received} received")
        rows.append("moved            nothing")
        return "\n".join(rows)


async def check(robot: C500CRobot) -> CheckReport:
    """Connect ``robot`` (made with ``prepare=False``), read `w2`, and report; move nothing."""
    async with robot:
        lines = await robot.read_position_lines()
        table = proto.parse_position_table(lines)
        status = robot.status()
        application = status.extra["prompt"].split("[", 1)[0].removesuffix("> ")
    return CheckReport(
        port=robot.port,
        baudrate=robot.settings.baudrate,
        flow_control=robot.settings.flow_control,
        prompt=status.extra["prompt"],
        application=application,
        link=status.link.value,
        arm_power=status.arm_power,
        homed=status.homed,
        online=status.online,
        point_of_control=status.point_of_control,
        world=table.world,
        joints=table.joints,
        pulses=table.pulses,
        units=table.units,
        w2_lines=tuple(lines),
        bytes_sent=robot.bytes_sent,
        bytes_received=robot.bytes_received,
    )


async def run_check(
    settings: Settings, *, port: str | None, transcript: Transcript | None
) -> CheckReport:
    robot_settings = settings.robot
    async with AsyncExitStack() as stack:
        if port is None and robot_settings.driver == "sim":
            # lazy: the emulator (NumPy) loads only when it is checked, not for --help
            from drivers.sim.emulator import C500CEmulator, EmulatorConfig

            emulator = C500CEmulator(
                EmulatorConfig(
                    application=robot_settings.application,
                    seed=settings.bench.seed,
                    baudrate=robot_settings.baudrate,
                    paced=robot_settings.emulator_paced,
                )
            )
            await stack.enter_async_context(emulator)
            port = emulator.device_path
        robot = C500CRobot(robot_settings, port=port, transcript=transcript, prepare=False)
        return await check(robot)
    raise AssertionError("unreachable")  # pragma: no cover (the stack never swallows)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "robot",
        help="check the robot controller's console (moves nothing)",
        description="thermocomp robot check: connect to the C500C console as configured, "
        "report the prompt, application, arm power, homing, online mode and point of control, "
        "read w2 and print what was parsed. Nothing moves, nothing on the controller changes. "
        "With robot.driver = c500c-server: connect to the program on the controller (the fast "
        "path), read the pose and report its state flags.",
    )
    commands = parser.add_subparsers(dest="robot_command", metavar="COMMAND", required=True)
    check_parser = commands.add_parser(
        "check", help="connect, report, read w2; move nothing", description=__doc__
    )
    add_config_argument(check_parser)
    check_parser.add_argument(
        "--port", help="serial device or socket:// URL (default: robot.port, or the emulator)"
    )
    check_parser.add_argument(
        "--transcript", type=Path, metavar="FILE", help="write every byte exchanged (JSON lines)"
    )
    check_parser.add_argument("--json", action="store_true", help="print the report as JSON")
    check_parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    settings = load_settings(args.config)
    if settings.robot.driver == "c500c-server":
        return _run_server(settings, args)
    transcript = Transcript() if args.transcript is not None else None
    status = EXIT_OK
    try:
        report = asyncio.run(run_check(settings, port=args.port, transcript=transcript))
    except DeviceError as err:
        print(f"thermocomp robot check: {err}", file=sys.stderr)
        status = EXIT_FAILURE
    else:
        print(json.dumps(report.as_dict(), indent=2) if args.json else report.text())
    if transcript is not None:
        transcript.write(args.transcript)
        print(f"transcript: {args.transcript} ({len(transcript.entries)} chunks)", file=sys.stderr)
    return status


def _run_server(settings: Settings, args: argparse.Namespace) -> int:
    """The fast path: the program on the controller (drivers/c500c/server_check.py)."""
    if args.transcript is not None:
        print(
            "thermocomp robot check: --transcript records the console's text; the fast path "
            "speaks binary frames (robot.driver = c500c-server)",
            file=sys.stderr,
        )
        return EXIT_USAGE
    # lazy: the fast path's check opens devices (drivers.factory: NumPy, OpenCV) when it runs,
    # not for --help
    from drivers.c500c.server_check import run_server_check

    try:
        report = asyncio.run(run_server_check(settings, port=args.port))
    except DeviceError as err:
        print(f"thermocomp robot check: {err}", file=sys.stderr)
        return EXIT_FAILURE
    print(report.json() if args.json else report.text())
    return EXIT_OK
