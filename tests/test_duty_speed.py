"""Issue 20, a played duty cycle in the drivers: `speed N` on the console (exact exchanges and
the emulator over a real pty), the joint-space emulator's joint speed scaled by the setting,
and the paced virtual clock the bench plays it on."""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator

import numpy as np
import pytest

from config.settings import RobotSettings
from daemon.arm.duty import trapezoid_timing
from daemon.arm.kinematics import forward
from daemon.arm.loading import load_arm
from drivers.c500c.robot import C500CRobot
from drivers.clock import FollowingClock, VirtualClock
from drivers.errors import DeviceError, MotionHeldError
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.joint_arm import JointArm, JointArmConfig, location_of
from tests.c500c_scripted import (
    PROMPT,
    ScriptedRobot,
    ok_exchange,
    probe_exchange,
    w2_exchange,
)

GOAL = (457.2, 0.0, 254.0, 0.0, 90.0, 0.0)


def _speed_set_shift(speed: bytes | None) -> tuple[bytes, bytes]:
    """One write: [speed N,] set cur = opgoal, wshift (drivers/c500c/robot.py move_absolute)."""
    lines = [b"set cur = opgoal", b"wshift cur,0.000,0.000,0.000,0,0,0"]
    if speed is not None:
        lines.insert(0, speed)
    return (
        b"".join(line + b"\r" for line in lines),
        b"".join(line + b"\r\n" + PROMPT for line in lines),
    )


def _move() -> list[tuple[bytes, bytes]]:
    return [ok_exchange(b"moves cur"), ok_exchange(b"finish"), w2_exchange(GOAL)]


CONNECT = [probe_exchange(), ok_exchange(b"new cur"), ok_exchange(b"online on")]
ZERO = (0.0, 0.0, 0.0)


async def test_speed_is_sent_only_when_it_changes_and_again_after_a_resume() -> None:
    script = [
        *CONNECT,
        ok_exchange(b"new opgoal"),
        ok_exchange(b"here opgoal"),
        w2_exchange(GOAL),
        _speed_set_shift(b"speed 80"),
        *_move(),
        _speed_set_shift(None),  # 80 % again: nothing to send
        *_move(),
        _speed_set_shift(b"speed 30"),
        *_move(),
        _speed_set_shift(None),  # no speed asked: the controller's current one
        *_move(),
        # resume: the controller may have restarted at its own speed, so 30 % is sent again
        ok_exchange(b"set cur = opgoal"),
        w2_exchange(GOAL),
        _speed_set_shift(b"speed 30"),
        *_move(),
    ]
    robot = ScriptedRobot(script)
    async with robot:
        await robot.teach_goal()
        await robot.move_absolute(ZERO, speed_percent=80)
        await robot.move_absolute(ZERO, speed_percent=80)
        await robot.move_absolute(ZERO, speed_percent=30)
        await robot.move_absolute(ZERO)
        await robot.stop()
        with pytest.raises(MotionHeldError):  # held: refused after the speed check too
            await robot.move_absolute(ZERO, speed_percent=30)
        await robot.resume()
        await robot.move_absolute(ZERO, speed_percent=30)
    robot.assert_all_used()


@pytest.mark.parametrize("bad", [0, 101, -5, 50.5, True])
async def test_a_speed_outside_1_to_100_percent_is_refused_before_anything_is_sent(
    bad: object,
) -> None:
    script = [*CONNECT, ok_exchange(b"new opgoal"), ok_exchange(b"here opgoal"), w2_exchange(GOAL)]
    robot = ScriptedRobot(script)  # nothing beyond the teach: a byte more fails the script
    async with robot:
        await robot.teach_goal()
        with pytest.raises(DeviceError, match="speed"):
            await robot.move_absolute(ZERO, speed_percent=bad)  # type: ignore[arg-type]
    robot.assert_all_used()


# --- the joint-space emulator ----------------------------------------------------------------

ARM = load_arm("crs-a465")
MAX_SPEED = (180.0, 180.0, 180.0, 172.0, 173.0, 225.0)
MAX_ACCEL = (360.0, 360.0, 360.0, 345.0, 345.0, 450.0)
START = (0.0, 35.0, 55.0, 0.0, 20.0, 0.0)
TARGET_Q = np.radians([40.0, 45.0, 40.0, 0.0, 25.0, 10.0])


def expected_duration(
    percent: int, q0: np.ndarray | None = None, q1: np.ndarray = TARGET_Q
) -> float:
    """The synchronised trapezoid of daemon/arm/duty.py: the normalised profile's limits are
    the tightest of the moving joints' speed x percent / |dq| and acceleration / |dq| (the
    acceleration is not scaled: no console command sets it)."""
    delta = np.abs(q1 - (np.radians(START) if q0 is None else q0))
    moving = delta > 0
    speed = np.min(np.radians(MAX_SPEED)[moving] * percent / 100.0 / delta[moving])
    accel = np.min(np.radians(MAX_ACCEL)[moving] / delta[moving])
    return trapezoid_timing(1.0, float(speed), float(accel))[0]


def test_the_joint_speed_scales_with_the_speed_setting() -> None:
    config = JointArmConfig(ARM, START, max_speed_deg_s=MAX_SPEED, max_accel_deg_s2=MAX_ACCEL)
    target = location_of(forward(ARM, TARGET_Q))
    for percent in (100, 40, 5):
        arm = JointArm(config)
        end = arm.move_to(target, 0.0, np.zeros(3), speed_percent=percent)
        assert end == pytest.approx(expected_duration(percent), rel=1e-9)
        # no joint beyond its scaled speed limit anywhere on the way
        times = np.linspace(0.0, end, 400)
        speeds = np.array([np.degrees(np.abs(arm.sample(t).qd_rad_s)) for t in times])
        assert np.all(speeds <= np.array(MAX_SPEED) * percent / 100.0 * (1 + 1e-9))
        assert np.degrees(arm.sample(end).q_rad) == pytest.approx(np.degrees(TARGET_Q), abs=1e-6)


def test_without_joint_limits_the_speed_setting_scales_the_one_speed() -> None:
    # the emulator of before: speed_deg_s at the console's start setting (10 %)
    target = location_of(forward(ARM, TARGET_Q))
    durations = {}
    for percent in (10, 20):
        arm = JointArm(JointArmConfig(ARM, START, speed_deg_s=10.0, acceleration_deg_s2=1e6))
        durations[percent] = arm.move_to(target, 0.0, np.zeros(3), speed_percent=percent)
    distance = math.degrees(float(np.max(np.abs(TARGET_Q - np.radians(START)))))
    assert durations[10] == pytest.approx(distance / 10.0 + 10.0 / 1e6, rel=1e-9)
    assert durations[20] == pytest.approx(distance / 20.0 + 20.0 / 1e6, rel=1e-9)


@pytest.fixture
async def played_emulator() -> AsyncIterator[tuple[C500CEmulator, VirtualClock]]:
    clock = VirtualClock()
    config = EmulatorConfig(
        paced=False,
        noise_um=0.0,
        joint_arm=JointArmConfig(ARM, START, max_speed_deg_s=MAX_SPEED, max_accel_deg_s2=MAX_ACCEL),
        clock=clock,
    )
    async with C500CEmulator(config) as emulator:
        yield emulator, clock


async def test_the_console_driver_sets_the_emulated_arms_speed_over_a_pty(
    played_emulator: tuple[C500CEmulator, VirtualClock],
) -> None:
    emulator, clock = played_emulator
    settings = RobotSettings(command_timeout_s=2.0, move_timeout_s=5.0)
    async with C500CRobot(settings, port=emulator.device_path) as robot:
        await robot.teach_goal()  # where the arm starts: START
        goal = location_of(forward(ARM, TARGET_Q))
        here = emulator.actual_pose()
        offset = (goal[0] - here[0], goal[1] - here[1], goal[2] - here[2])
        await robot.move_absolute(offset, speed_percent=40)
        first = emulator.state.motions[-1]
        assert first.speed_percent == 40
        # timed on the run's (virtual) clock: `finish` waited for the motion's end on it
        joints = emulator.console.joint_arm
        assert joints is not None
        q0, q1 = joints.joints_at(first.start_s), joints.joints_at(first.end_s)
        assert np.max(np.abs(q1 - q0)) > 0.1  # a real move, of several joints
        duration = expected_duration(40, q0, q1)
        assert first.end_s - first.start_s == pytest.approx(duration, rel=1e-9)
        assert clock.now() == pytest.approx(first.end_s)
        await robot.move_absolute(ZERO, speed_percent=40)  # back at the start, 40 % again
    commands = list(emulator.state.commands)
    assert commands.count("speed 40") == 1
    assert emulator.state.speed_percent == 40
    assert emulator.state.motion_count == len(emulator.state.motions) == 2


# --- the paced virtual clock -----------------------------------------------------------------


async def test_a_follower_waits_for_the_pacer_and_the_pacer_stops_at_its_deadline() -> None:
    clock = VirtualClock()
    follower = FollowingClock(clock)
    seen: list[tuple[str, float]] = []

    async def step() -> None:
        await follower.sleep_until(10.0)
        seen.append(("step", clock.now()))

    with clock.pacing():
        stepper = asyncio.create_task(step())
        await asyncio.sleep(0)
        assert clock.now() == 0.0 and not stepper.done()  # a follower does not jump the time
        for deadline in (4.0, 8.0, 12.0, 16.0):
            await clock.sleep_until(deadline)
            seen.append(("pace", clock.now()))
    await stepper
    # the follower woke at its own deadline, on the pacer's way from 8 to 12
    assert seen == [("pace", 4.0), ("pace", 8.0), ("step", 10.0), ("pace", 12.0), ("pace", 16.0)]


async def test_without_a_pacer_a_follower_sleeps_as_anyone() -> None:
    clock = VirtualClock()
    waiting = asyncio.create_task(FollowingClock(clock).sleep_until(5.0))
    with clock.pacing():
        await asyncio.sleep(0)
        assert not waiting.done()
    await waiting  # the pacer left: the follower jumps the time itself
    assert clock.now() == 5.0
    await FollowingClock(clock).sleep_until(7.0)
    assert clock.now() == 7.0
