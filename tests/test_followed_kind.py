"""Issue 27: a third run kind touches the factory and its own files only. The skeleton of
"followed" (daemon/run/followed/: the robot plays its own program, the daemon follows it and
writes corrections) runs through the daemon against a minimal fake offset robot that keeps the
Robot contract's hold rules; and nothing outside the factory chooses on a run's kind."""

from __future__ import annotations

import ast
import asyncio
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Self

import pytest

from daemon.run.states import RunState
from daemon.service import Daemon
from drivers.base import ZERO_ROTATION, LinkState, OffsetRobot, RobotStatus, Vector3
from drivers.clock import Clock, make_clock
from drivers.errors import DeviceError, MotionHeldError
from drivers.goals import require_finite, require_target
from drivers.permit import MotionPermit, Ticket
from tests.fakes import HEAT_W, FakeBench, FakeCamera, FakeIr, make_settings, params

REPO = Path(__file__).resolve().parent.parent
WAIT_S = 60.0


class FakeOffsetRobot:
    """A robot that plays its own program (drivers/base.py OffsetRobot), as small as the hold
    rules allow: the permit checked under the lock right before a correction is "written"."""

    def __init__(self) -> None:
        self.permit = MotionPermit()
        self.written: list[tuple[Vector3, Vector3]] = []
        self.lock = asyncio.Lock()
        self.at_pose = 1
        self.followed = 0

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def set_correction(
        self, offset_mm: Vector3, rotation_rad: Vector3 = ZERO_ROTATION
    ) -> int:
        require_target(offset_mm, "correction", "robot")
        require_finite(rotation_rad, "rotation", "robot")
        async with self.lock:
            self.permit.require()
            self.written.append((offset_mm, rotation_rad))
            return len(self.written)

    def robot_state(self) -> SimpleNamespace:
        # a UR5e at a pose of its program, its joints warmer than the 22 degC room
        return SimpleNamespace(
            at_pose=self.at_pose,
            joints_rad=(0.0, -1.745, 1.745, -1.571, -1.571, 0.0),
            joint_temperatures_c=(30.0, 34.0, 31.0, 28.0, 27.0, 26.0),
            tcp_pose=(400.0, 100.0, 300.0, 0.0, 3.14, 0.0),
        )

    async def follow_program(self) -> SimpleNamespace:
        self.followed += 1
        return self.robot_state()

    async def stop(self) -> None:
        self.permit.hold("stopped by request")

    async def resume(self, ticket: Ticket | None = None) -> None:
        async with self.lock:
            self.permit.release(ticket if ticket is not None else self.permit.ticket())

    def status(self) -> RobotStatus:
        return RobotStatus(
            LinkState.CONNECTED, motion_held=self.permit.held, hold_reason=self.permit.reason
        )


class FollowedDevices:
    def __init__(self, clock: Clock) -> None:
        self.robot = FakeOffsetRobot()
        self.camera = FakeCamera(FakeBench(clock, HEAT_W))
        self.ir = FakeIr(clock)

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None


async def test_the_fake_offset_robot_keeps_the_hold_rules() -> None:
    robot = FakeOffsetRobot()
    assert isinstance(robot, OffsetRobot)
    before = robot.permit.ticket()
    stop = asyncio.ensure_future(robot.stop())
    await asyncio.sleep(0)
    assert robot.permit.held  # before stop() is awaited to its end
    with pytest.raises(MotionHeldError):
        await robot.set_correction((0.001, 0.0, 0.0))
    await stop
    with pytest.raises(MotionHeldError):
        await robot.resume(before)  # a request from before the hold releases nothing
    await robot.resume()
    with pytest.raises(DeviceError, match="refused"):
        await robot.set_correction((math.nan, 0.0, 0.0))
    with pytest.raises(DeviceError, match="refused"):
        await robot.set_correction((2000.0, 0.0, 0.0))
    await robot.set_correction((0.001, 0.0, 0.0))
    assert len(robot.written) == 1


async def test_a_followed_run_writes_corrections_and_none_after_a_hold(tmp_path: Path) -> None:
    settings = make_settings(
        tmp_path,
        scheduler={"step_s": 0.2, "duration_s": 600.0},
        model={"prediction": "model+ir"},
        arm={"enabled": True, "arm_file": "ur5e", "duty_cycle": "ur5e-pick-and-place"},
    )
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    devices = FollowedDevices(clock)
    robot = devices.robot
    async with Daemon(settings, clock=clock, open_devices=lambda _s, _c: devices) as daemon:
        info = await daemon.start_run(params(settings))
        session = daemon._session
        assert session is not None and session.kind.name == "followed"
        await daemon.wait_state(RunState.RUNNING)
        assert robot.followed == 1  # the run took the program as it is
        async with asyncio.timeout(WAIT_S):
            while len(robot.written) < 3:  # noqa: ASYNC110 -- the fake has no event
                await asyncio.sleep(0.01)
        await daemon.hold_robot()
        written = len(robot.written)
        assert daemon.run is not None and daemon.run.state is RunState.PAUSED
        await asyncio.sleep(1.0)  # five step periods
        assert len(robot.written) == written  # nothing written after the hold
        await daemon.resume()
        async with asyncio.timeout(WAIT_S):
            while len(robot.written) <= written:  # noqa: ASYNC110
                await asyncio.sleep(0.01)
        final = await daemon.stop()
    assert final["state"] == "stopped" and final["id"] == info["id"]
    assert final["summary"]["kind"] == "followed"
    assert final["summary"]["corrections_written"] == len(robot.written)


def test_nothing_outside_the_factory_chooses_on_a_runs_kind() -> None:
    """No isinstance on a run's work or kind in the daemon, but in daemon/run/kinds.py."""
    kinds = {"RunWork", "ArmRunWork", "TwoLinkKind", "ArmKind", "FollowedKind", "OffsetRobot"}
    found: list[str] = []
    for path in sorted((REPO / "daemon").rglob("*.py")):
        if path == REPO / "daemon" / "run" / "kinds.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance":
                names = {n.id for n in ast.walk(node.args[1]) if isinstance(n, ast.Name)}
                if names & kinds:
                    found.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert found == []
