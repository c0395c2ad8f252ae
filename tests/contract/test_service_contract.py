"""The Robot contract at the service (issue 26): a hold answered while a run's start is being
built is never undone by that start, whichever robot is under it (tests/contract/adapters.py):
the run is cancelled before any motion command reaches the robot."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any, Self

from config import Settings
from daemon.run.states import RunState
from daemon.service import Daemon
from drivers.clock import Clock, make_clock
from tests.contract.adapters import Subject
from tests.fakes import HEAT_W, FakeBench, FakeCamera, FakeIr, make_settings, params

WAIT_S = 60.0


class SubjectDevices:
    """The fakes' camera and IR reader around the robot under the contract (already open)."""

    def __init__(self, clock: Clock, robot: Any) -> None:
        self.robot = robot
        self.camera = FakeCamera(FakeBench(clock, HEAT_W))
        self.ir = FakeIr(clock)

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None


async def test_a_hold_during_a_starts_build_is_never_undone_by_it(
    subject: Subject, tmp_path: Path
) -> None:
    settings: Settings = make_settings(tmp_path, scheduler={"step_s": 0.2})
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    devices = SubjectDevices(clock, subject.robot)
    written = subject.written()
    async with Daemon(settings, clock=clock, open_devices=lambda _s, _c: devices) as daemon:
        start = asyncio.ensure_future(daemon.start_run(params(settings)))
        await asyncio.sleep(0)  # the request arrived: its ticket is taken, the build awaits
        await daemon.hold_robot("the operator's hold")
        await start
        info = await asyncio.wait_for(daemon.wait_run(), WAIT_S)
        assert info["state"] == RunState.STOPPED.value and "start cancelled" in info["reason"]
        assert subject.written() == written and subject.robot.permit.held
