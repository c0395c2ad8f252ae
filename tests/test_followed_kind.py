"""Issue 27: a third run kind touches the factory and its own files only. The skeleton of
"followed" (daemon/run/followed/: the robot plays its own program, the daemon follows it and
writes corrections) runs through the daemon against the suite's fake offset robot
(tests/fakes.py FakeOffsetRobot, under the Robot contract: tests/contract/). That nothing
outside the factory and the kinds' packages names a kind: tests/test_kind_isolation.py."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Self

from daemon.run.states import RunState
from daemon.service import Daemon
from drivers.base import OffsetRobot
from drivers.clock import Clock, make_clock
from tests.fakes import (
    HEAT_W,
    FakeBench,
    FakeCamera,
    FakeIr,
    FakeOffsetRobot,
    make_settings,
    params,
)

WAIT_S = 60.0


class FollowedDevices:
    def __init__(self, clock: Clock) -> None:
        self.robot = FakeOffsetRobot()
        self.camera = FakeCamera(FakeBench(clock, HEAT_W))
        self.ir = FakeIr(clock)

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None


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
        assert isinstance(robot, OffsetRobot)  # what the factory chooses the kind by
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


async def test_a_followed_run_says_it_does_not_adapt(tmp_path: Path) -> None:
    """arm.adapt on a followed run (issue 29): the followed run has no online adaptation; the
    run's record says so (snapshot ``adapt`` false and why) instead of ignoring it silently."""
    from daemon.run.followed.build import NOT_ADAPTING

    settings = make_settings(
        tmp_path,
        scheduler={"step_s": 0.2, "duration_s": 600.0},
        arm={
            "enabled": True,
            "arm_file": "ur5e",
            "duty_cycle": "ur5e-pick-and-place",
            "adapt": True,
        },
    )
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    devices = FollowedDevices(clock)
    async with Daemon(settings, clock=clock, open_devices=lambda _s, _c: devices) as daemon:
        info = await daemon.start_run(params(settings))
        await daemon.wait_state(RunState.RUNNING)
        await daemon.stop()
        assert daemon.recorder is not None
        row = daemon.recorder.run(info["id"])
    assert row is not None and row.network is not None
    assert row.network["adapt"] is False and row.network["adapt_note"] == NOT_ADAPTING
