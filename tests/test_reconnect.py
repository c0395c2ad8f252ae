"""drivers/reconnect.py: one reconnection at a time, the capped back-off, the lock, the hooks."""

from __future__ import annotations

import asyncio
import itertools

import pytest

from config.settings import RobotSettings
from drivers.base import LinkState
from drivers.c500c.robot import C500CRobot
from drivers.errors import DeviceError, NotConnectedError
from drivers.reconnect import RECONNECT_BACKOFF_FACTOR, Reconnector, backoffs
from drivers.sim.emulator import C500CEmulator, EmulatorConfig


def test_backoff_doubles_from_the_first_wait_up_to_the_cap() -> None:
    assert RECONNECT_BACKOFF_FACTOR == 2.0
    assert list(itertools.islice(backoffs(0.5, 3.0), 6)) == [0.5, 1.0, 2.0, 3.0, 3.0, 3.0]
    # a first wait above the cap is the caller's; every later one is capped
    assert list(itertools.islice(backoffs(0.5, 0.2), 3)) == [0.5, 0.2, 0.2]


class _Link:
    """Attempts that fail ``failures`` times, with every wait and hook recorded."""

    def __init__(self, failures: int) -> None:
        self.failures = failures
        self.calls = 0
        self.waits: list[float] = []
        self.events: list[str] = []
        self.lock = asyncio.Lock()
        self.locked_during_attempt: list[bool] = []

    async def attempt(self) -> None:
        self.calls += 1
        self.locked_during_attempt.append(self.lock.locked())
        self.events.append(f"attempt {self.calls}")
        if self.calls <= self.failures:
            raise NotConnectedError("device", f"still gone ({self.calls})")

    async def sleep(self, seconds: float) -> None:
        self.waits.append(seconds)
        self.events.append(f"wait {seconds:g}")
        await asyncio.sleep(0)

    async def before(self) -> None:
        self.events.append("before")

    def reconnector(self, **options: object) -> Reconnector:
        return Reconnector(
            "device",
            self.attempt,
            first_backoff_s=lambda: 0.5,
            max_backoff_s=lambda: 2.0,
            on_failure=lambda err: self.events.append(f"failed: {err}"),
            on_success=lambda: self.events.append("connected"),
            sleep=self.sleep,
            **options,  # type: ignore[arg-type]
        )


async def test_attempts_until_one_succeeds_with_capped_waits() -> None:
    link = _Link(failures=4)
    reconnector = link.reconnector()
    reconnector.start()
    assert reconnector.task is not None
    await asyncio.wait_for(reconnector.task, 5.0)
    assert reconnector.attempts == 5 and link.calls == 5
    assert link.waits == [0.5, 1.0, 2.0, 2.0]
    assert link.events[:3] == ["attempt 1", "failed: device: still gone (1)", "wait 0.5"]
    assert link.events[-1] == "connected"
    assert not reconnector.running
    assert link.locked_during_attempt == [False] * 5  # no lock given


async def test_wait_first_and_before_for_a_camera_just_pulled() -> None:
    link = _Link(failures=1)
    reconnector = link.reconnector(wait_first=True, before=link.before, lock=link.lock)
    reconnector.start()
    assert reconnector.task is not None
    await asyncio.wait_for(reconnector.task, 5.0)
    assert link.events == [
        "before",
        "wait 0.5",
        "attempt 1",
        "failed: device: still gone (1)",
        "wait 1",
        "attempt 2",
        "connected",
    ]
    assert link.locked_during_attempt == [True, True]  # every attempt under the driver's lock


async def test_one_reconnection_at_a_time_and_cancel_stops_it() -> None:
    link = _Link(failures=10**9)  # never comes back
    reconnector = link.reconnector()
    reconnector.start()
    first = reconnector.task
    reconnector.start()  # a second fault while reconnecting: the same task goes on
    assert reconnector.task is first and reconnector.running
    while link.calls < 3:  # noqa: ASYNC110 (the recorded sleep yields once per wait)
        await asyncio.sleep(0)
    await reconnector.cancel()
    assert first is not None and first.cancelled()
    assert reconnector.task is None and not reconnector.running
    calls = link.calls
    await asyncio.sleep(0)
    assert link.calls == calls  # nothing runs after the cancel


async def test_an_error_that_is_no_device_error_ends_the_task_and_is_reported(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Issue 26: a bug in an attempt ends the task (no loop), with its traceback in the log,
    and is reported to the driver (its link goes to ``fault``), never silently."""

    async def broken() -> None:
        raise ValueError("a bug, not a link fault")

    fatal: list[BaseException] = []
    reconnector = Reconnector(
        "device",
        broken,
        first_backoff_s=lambda: 0.01,
        max_backoff_s=lambda: 0.01,
        on_fatal=fatal.append,
    )
    reconnector.start()
    assert reconnector.task is not None
    await asyncio.wait_for(reconnector.task, 5.0)  # ended, not raised into the close
    assert reconnector.attempts == 1
    assert len(fatal) == 1 and isinstance(fatal[0], ValueError)
    assert isinstance(reconnector.fatal, ValueError)
    record = next(r for r in caplog.records if "unexpected error" in r.getMessage())
    assert record.exc_info is not None  # with its traceback
    await reconnector.cancel()


async def test_a_console_link_whose_reconnection_breaks_says_fault_not_reconnecting() -> None:
    emulator = C500CEmulator(EmulatorConfig(paced=False, move_ms=1.0))
    async with (
        emulator,
        C500CRobot(
            RobotSettings(command_timeout_s=1.0), port=emulator.device_path, first_backoff_s=0.01
        ) as robot,
    ):
        await robot.teach_goal()

        async def broken() -> None:
            raise RuntimeError("a bug in the connect")

        robot._reconnector._attempt = broken  # its reconnection attempts hit a bug
        emulator.inject("close")
        with pytest.raises(DeviceError):
            await robot.actual_pose()
        async with asyncio.timeout(10.0):
            while robot.status().link is not LinkState.FAULT:  # noqa: ASYNC110 -- no event
                await asyncio.sleep(0.01)
        status = robot.status()
        assert status.motion_held and "a bug in the connect" in (status.last_error or "")
