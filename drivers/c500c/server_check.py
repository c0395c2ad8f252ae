"""``thermocomp robot check`` for the fast path (``robot.driver = "c500c-server"``): connect to
the program on the controller (controller/PROTOCOL.md), read the actual pose and report the
program's state flags; move nothing (no teach, no release, no move: a read only)."""

from __future__ import annotations

import json
from contextlib import AsyncExitStack
from dataclasses import asdict, dataclass
from typing import Any

from config import Settings
from drivers.c500c import server_protocol as proto
from drivers.c500c.server import C500CServerRobot
from drivers.factory import emulated_server


@dataclass(frozen=True, slots=True)
class ServerCheckReport:
    port: str
    baudrate: int
    program: str
    link: str
    goal_taught: bool
    held: bool
    moving: bool
    point_of_control: bool
    silence_halted: bool
    world: tuple[float, ...]
    bytes_sent: int
    bytes_received: int

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def json(self) -> str:
        return json.dumps(self.as_dict(), indent=2)

    def text(self) -> str:
        def yes(value: bool) -> str:
            return "yes" if value else "no"

        x, y, z, z_rot, y_rot, x_rot = self.world
        return "\n".join(
            [
                f"port             {self.port} ({self.baudrate} baud, the fast path)",
                f"program          {self.program}",
                f"link             {self.link}",
                f"goal taught      {yes(self.goal_taught)}",
                f"held             {yes(self.held)}"
                + (" (the host fell silent)" if self.silence_halted else ""),
                f"moving           {yes(self.moving)}",
                f"point of control {yes(self.point_of_control)}",
                f"pose WORLD (mm)  x {x:+.4f}  y {y:+.4f}  z {z:+.4f}  "
                f"z-rot {z_rot:+.4f}  y-rot {y_rot:+.4f}  x-rot {x_rot:+.4f}",
                f"bytes            {self.bytes_sent} sent, {self.bytes_received} received",
                "moved            nothing",
            ]
        )


async def run_server_check(settings: Settings, *, port: str | None) -> ServerCheckReport:
    """Check the program on ``port`` (default ``robot.server_port``, or the emulated program
    when the bench is enabled)."""
    robot_settings = settings.robot
    async with AsyncExitStack() as stack:
        if port is None and settings.bench.enabled:
            emulator = emulated_server(settings, seed=settings.bench.seed)
            await stack.enter_async_context(emulator)
            port = emulator.device_path
        robot = C500CServerRobot(robot_settings, port=port)
        async with robot:
            pose = await robot.actual_pose()
            status = robot.status()
        flags = proto.Flag(int(status.extra.get("controller_flags") or 0))
        return ServerCheckReport(
            port=robot.port,
            baudrate=robot_settings.server_baudrate,
            program=status.extra.get("program", ""),
            link=status.link.value,
            goal_taught=bool(flags & proto.Flag.GOAL_TAUGHT),
            held=bool(flags & proto.Flag.HELD),
            moving=bool(flags & proto.Flag.MOVING),
            point_of_control=bool(flags & proto.Flag.POINT_OF_CONTROL),
            silence_halted=bool(flags & proto.Flag.SILENCE_HALTED),
            world=(pose.x, pose.y, pose.z, pose.z_rot, pose.y_rot, pose.x_rot),
            bytes_sent=int(status.extra["bytes_sent"]),
            bytes_received=int(status.extra["bytes_received"]),
        )
    raise AssertionError("unreachable")  # pragma: no cover (the stack never swallows)
