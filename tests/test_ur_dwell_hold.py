"""The program holds a measured pose's dwell while the PC takes its frames (issue 31): the
frames register (drivers/ur/registers.py), the main program's tc_wait_for_frames
(controller/ur/thermocomp_offset.script) as the emulator plays it (drivers/sim/ur/player.py,
program.py ``holds_dwell``), the driver's hold_dwell / release_dwell (drivers/ur/robot.py) and
the followed run's measurement asking for it (daemon/run/followed/measure.py).

Why: on a loaded PC the frames took 0.8-2.9 s against dwells of 0.5-1 s, and every
measurement of a followed run was thrown away (the program had left its pose).
"""

from __future__ import annotations

import asyncio
import dataclasses

import numpy as np
import pytest

from daemon.arm.run import ToolMeasurement
from daemon.arm.types import FloatArray
from daemon.run.followed.measure import MOVED, DwellHold, DwellMeasurement
from drivers.base import OffsetRobotState
from drivers.errors import DeviceError, DeviceTimeoutError
from drivers.sim.ur.controller import URController, URControllerConfig
from drivers.sim.ur.program import FRAMES_TIMEOUT_S, ProgramLimits
from drivers.ur.rtde_protocol import CONTROLLER_CYCLE_S
from tests.loopback import loopback_host
from tests.test_ur_followed_measure import SIGMA_MM, Rows, measure_now, record, state
from tests.test_ur_robot import bench, until

CYCLE = CONTROLLER_CYCLE_S
#: pose 6 of ur5e-pick-and-place (the fixture): measured, a 0.5 s dwell
PLACE = 6
#: the driver writes its heartbeat every robot.ur_heartbeat_s (0.1 s): 50 cycles
HEARTBEAT_CYCLES = 50


class Controller:
    """The emulated controller cycled by hand (no network), the PC's heartbeat written."""

    def __init__(self, config: URControllerConfig | None = None) -> None:
        self.c = URController(config or URControllerConfig())
        self.cycle = 0
        self.sequence = 0
        self.heartbeat = True

    @property
    def frames(self) -> str:
        return self.c.registers.frames

    def at_pose(self) -> int:
        value = self.c.outputs[self.c.registers.at_pose]
        assert isinstance(value, int)
        return value

    def run_to(self, t_s: float, each: list[tuple[float, int]] | None = None) -> None:
        while self.cycle * CYCLE < t_s - 1e-9:
            self.cycle += 1
            if self.heartbeat and self.cycle % HEARTBEAT_CYCLES == 0:
                self.sequence += 1
                self.c.write_input(self.c.registers.sequence, self.sequence)
            self.c.cycle(self.cycle * CYCLE)
            if each is not None:
                each.append((self.cycle * CYCLE, self.at_pose()))

    def place_dwell(self) -> tuple[float, float]:
        """When the robot arrives at the fixture in its first cycle, and the dwell's end."""
        duty = self.c.duty
        arrival = duty.arrival_times_s()[PLACE - 1]
        return arrival, arrival + duty.poses[PLACE - 1].dwell_s


def last_at(trace: list[tuple[float, int]], pose: int) -> float:
    return max(t for t, at in trace if at == pose)


def test_a_measured_dwell_is_held_while_the_pc_takes_frames_and_ends_when_it_is_done() -> None:
    bench_ = Controller()
    arrival, end = bench_.place_dwell()
    bench_.run_to(arrival + 0.1)
    assert bench_.at_pose() == PLACE
    bench_.c.write_input(bench_.frames, PLACE)
    trace: list[tuple[float, int]] = []
    bench_.run_to(end + 2.0, trace)
    # two seconds past the taught dwell: still at the pose, at rest, the register says so
    assert all(at == PLACE for _, at in trace)
    q = bench_.c.player.joints(end + 2.0)
    assert q == pytest.approx(bench_.c.duty.poses[PLACE - 1].q_rad, abs=1e-12)
    bench_.c.write_input(bench_.frames, 0)  # the frames are in
    trace.clear()
    bench_.run_to(end + 2.5, trace)
    assert trace[0][1] == 0  # let go in the next cycle
    assert np.max(np.abs(bench_.c.player.joints(end + 2.5) - q)) > 1e-3  # moving on


def test_the_hold_ends_at_its_timeout_or_when_the_pc_goes_silent() -> None:
    assert ProgramLimits().frames_timeout_s == FRAMES_TIMEOUT_S
    timeout_s = 1.0
    bench_ = Controller(URControllerConfig(limits=ProgramLimits(frames_timeout_s=timeout_s)))
    arrival, end = bench_.place_dwell()
    bench_.run_to(arrival + 0.1)
    bench_.c.write_input(bench_.frames, PLACE)  # and never cleared
    trace: list[tuple[float, int]] = []
    bench_.run_to(end + timeout_s + 1.0, trace)
    assert last_at(trace, PLACE) == pytest.approx(end + timeout_s, abs=2 * CYCLE)

    silent = Controller()
    arrival, end = silent.place_dwell()
    silent.run_to(arrival + 0.1)
    silent.c.write_input(silent.frames, PLACE)
    silent.run_to(end + 0.3)
    silent.heartbeat = False  # the PC dies with its frames register at 6
    last_heartbeat = (silent.cycle // HEARTBEAT_CYCLES) * HEARTBEAT_CYCLES  # its cycle
    trace.clear()
    silent.run_to(end + 2.0, trace)
    watchdog_s = silent.c.config.limits.watchdog_s
    assert last_at(trace, PLACE) == pytest.approx(
        last_heartbeat * CYCLE + watchdog_s, abs=2 * CYCLE
    )


@pytest.mark.parametrize("case", ["another pose", "a program without the wait"])
def test_frames_of_another_pose_or_a_program_without_the_wait_hold_nothing(case: str) -> None:
    bench_ = Controller(URControllerConfig(waits_for_frames=case == "another pose"))
    arrival, end = bench_.place_dwell()
    bench_.run_to(arrival + 0.1)
    bench_.c.write_input(bench_.frames, 1 if case == "another pose" else PLACE)
    trace: list[tuple[float, int]] = []
    bench_.run_to(end + 0.5, trace)
    assert last_at(trace, PLACE) == pytest.approx(end, abs=2 * CYCLE)


@pytest.mark.slow
async def test_the_driver_holds_the_dwell_over_rtde_until_it_releases_it() -> None:
    async with bench(loopback_host()) as (ur, robot):
        assert isinstance(robot, DwellHold)
        frames = robot.registers.frames
        assert ur.controller.inputs[frames] == 0
        with pytest.raises(ValueError, match="1 or more"):
            await robot.hold_dwell(0)
        await until(lambda: robot.robot_state().at_pose == PLACE, 30.0)
        held = await robot.hold_dwell(PLACE)
        assert held.at_pose == PLACE and ur.controller.inputs[frames] == PLACE
        # a second and a half later (the taught dwell is 0.5 s): still there, at rest
        end = ur.now() + 1.5
        while ur.now() < end:
            await asyncio.sleep(0.02)
            assert robot.robot_state().at_pose == PLACE
        robot.release_dwell()
        await until(lambda: robot.robot_state().at_pose == 0, 5.0)
        assert ur.controller.inputs[frames] == 0
        # a new link starts with no frames in flight (a PC that died mid-frames left them)
        ur.controller.write_input(frames, PLACE)
        ur.drop_connections()
        await until(lambda: ur.controller.inputs[frames] == 0, 30.0)


class Hold:
    """A robot's dwell hold (DwellHold): what it answers, and its calls in order."""

    def __init__(self, answer: OffsetRobotState | Exception) -> None:
        self.answer = answer
        self.calls: list[str] = []

    async def hold_dwell(self, pose: int) -> OffsetRobotState:
        self.calls.append(f"hold {pose}")
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer

    def release_dwell(self) -> None:
        self.calls.append("release")


class LoggedMeter:
    def __init__(self, log: list[str], fail: Exception | None = None) -> None:
        self.log = log
        self.fail = fail

    async def measure(
        self, expected_pose: FloatArray, frames: int | None = None
    ) -> ToolMeasurement:
        self.log.append("frames")
        if self.fail is not None:
            raise self.fail
        return ToolMeasurement(np.eye(4), SIGMA_MM, True, {})


async def test_the_measurement_takes_its_frames_inside_the_hold() -> None:
    hold = Hold(state(2))
    dwell = DwellMeasurement(LoggedMeter(hold.calls), lambda q: np.eye(4), lambda: state(2), 6)
    dwell = dataclasses.replace(dwell, hold=hold)
    measured, _, flags = await measure_now(dwell, state(2), Rows())
    assert measured is not None and MOVED not in flags
    assert hold.calls == ["hold 2", "frames", "release"]


@pytest.mark.parametrize(
    "answer",
    [state(0), state(2, instance=8), state(2, speed=0.05), DeviceTimeoutError("robot", "late")],
    ids=["left", "restarted", "moving", "no read-back"],
)
async def test_a_hold_that_came_too_late_takes_no_frames(
    answer: OffsetRobotState | Exception,
) -> None:
    hold = Hold(answer)
    dwell = DwellMeasurement(LoggedMeter(hold.calls), lambda q: np.eye(4), lambda: state(2), 6)
    dwell = dataclasses.replace(dwell, hold=hold)
    measured, row, flags = await measure_now(dwell, state(2), Rows())
    assert measured is None and row is not None and MOVED in flags
    assert hold.calls == ["hold 2", "release"]  # released, never a frame
    assert "pose 2" in row.error


async def test_the_hold_is_released_when_the_cameras_fail_or_the_wait_gives_up() -> None:
    hold = Hold(state(2))
    failing = LoggedMeter(hold.calls, DeviceError("camera", "no frame"))
    dwell = dataclasses.replace(
        DwellMeasurement(failing, lambda q: np.eye(4), lambda: state(2), 6), hold=hold
    )
    _, _, flags = await measure_now(dwell, state(2), Rows())
    assert "camera-error" in flags and hold.calls[-1] == "release"

    class Stuck:
        async def measure(
            self, expected_pose: FloatArray, frames: int | None = None
        ) -> ToolMeasurement:
            await asyncio.Event().wait()
            raise AssertionError

    hold = Hold(state(2))
    dwell = dataclasses.replace(
        DwellMeasurement(Stuck(), lambda q: np.eye(4), lambda: state(2), 6), hold=hold
    )
    flags_: list[str] = []
    assert dwell.start(state(2), record(), flags_)
    await asyncio.sleep(0.01)
    await dwell.collect(Rows(), wait_s=0.05)  # gives up: the task is cancelled
    assert hold.calls == ["hold 2", "release"]
