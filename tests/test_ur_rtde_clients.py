"""The UR emulator checked by clients nobody here wrote: ur-rtde's RTDEReceiveInterface,
RTDEIOInterface and DashboardClient (PyPI ``ur-rtde``), over loopback on UR's fixed ports, one
loopback address per test (tests/loopback.py). ur-rtde runs in a subprocess
(tests/ur_rtde_clients.py says why).
"""

from __future__ import annotations

import asyncio
import json
import math
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from daemon.arm.motors import arm_motors, heat_from_current_w
from daemon.run.states import RunState
from daemon.service import Daemon
from drivers.errors import ProtocolError
from drivers.sim.ur.controller import URControllerConfig
from drivers.sim.ur.emulator import UREmulator
from drivers.ur.modes import RobotMode, RuntimeState, SafetyMode
from drivers.ur.rtde_client import RtdeClient
from tests.fakes import params
from tests.helpers import REPO_ROOT
from tests.loopback import loopback_host
from tests.test_ur_program_pause import ur_settings

ANSWER_TIMEOUT_S = 30.0


class UrRtde:
    """ur-rtde's clients in a subprocess, one JSON answer per command."""

    def __init__(self, process: asyncio.subprocess.Process, host: str) -> None:
        self.process = process
        self.host = host  # the loopback address the clients dial (UR's fixed ports)

    async def ask(self, command: str) -> dict[str, Any]:
        assert self.process.stdin is not None and self.process.stdout is not None
        self.process.stdin.write(f"{command}\n".encode())
        await self.process.stdin.drain()
        async with asyncio.timeout(ANSWER_TIMEOUT_S):
            while True:  # ur-rtde prints its own progress lines on stdout: skip them
                line = await self.process.stdout.readline()
                assert line, "ur-rtde's process ended"
                if line.startswith(b"{"):
                    answer: dict[str, Any] = json.loads(line)
                    assert "error" not in answer, answer["error"]
                    return answer


@pytest.fixture
async def ur_rtde() -> AsyncIterator[UrRtde]:
    host = loopback_host()
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "tests.ur_rtde_clients",
        host,
        stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.DEVNULL,
        cwd=REPO_ROOT,
    )
    try:
        yield UrRtde(process, host)
    finally:
        if process.returncode is None:
            assert process.stdin is not None
            process.stdin.write(b"quit\n")
            try:
                await asyncio.wait_for(process.wait(), 10)
            except TimeoutError:
                process.kill()
                await process.wait()


async def settle(ur: UREmulator, seconds: float) -> None:
    """Let the emulator run ``seconds`` of its clock."""
    end = ur.now() + seconds
    while ur.now() < end:  # noqa: ASYNC110 -- the emulator's clock, read not awaited
        await asyncio.sleep(0.02)


async def test_receive_interface_reads_pose_joints_temperatures_and_modes(ur_rtde: UrRtde) -> None:
    async with UREmulator(URControllerConfig(autoplay=False), host=ur_rtde.host) as ur:
        state = await ur_rtde.ask("receive")
        controller = ur.controller
        assert state["connected"]
        assert state["timestamp"] > 0
        # the program is stopped at its first pose: joints and pose are the emulator's exactly
        assert state["q"] == pytest.approx(list(controller.player.joints(ur.now())), abs=1e-12)
        assert state["pose"] == pytest.approx(list(controller.tcp_pose(ur.now())), abs=1e-12)
        temperatures = state["temperatures"]
        assert len(temperatures) == 6
        for value in temperatures:  # the sensor's resolution, near the bench's 22 degC
            assert abs(value - 22.0) < 1.0
            assert value / 0.0625 == pytest.approx(round(value / 0.0625), abs=1e-9)
        assert state["robot_mode"] == RobotMode.RUNNING
        assert state["safety_mode"] == SafetyMode.NORMAL
        assert state["runtime_state"] == RuntimeState.STOPPED
        assert not state["protective_stopped"]

        ur.protective_stop()
        await settle(ur, 0.1)
        state = await ur_rtde.ask("receive")
        assert state["safety_mode"] == SafetyMode.PROTECTIVE_STOP
        assert state["protective_stopped"]
        assert ur.rtde.sessions and ur.rtde.sessions[0].frequency_hz == 500.0


@pytest.mark.slow
async def test_receive_interface_reads_the_motion_a_followed_run_heats_with(
    ur_rtde: UrRtde,
) -> None:
    """ur-rtde's getActualQd, getTargetQdd and getActualCurrent read the emulated arm's motion
    (what a followed run's measured heat is computed from: drivers/ur/motion.py) with the
    guide's semantics: the played program's joint speeds and accelerations at the package's
    timestamp, and motor currents whose copper loss, with the motor's resistance and friction
    (daemon/arm/motors.py heat_from_current_w), is the bench truth's heat of that motion."""
    async with UREmulator(host=ur_rtde.host) as ur:
        controller = ur.controller
        motors = arm_motors(controller.arm)
        moving = resting = 0
        async with asyncio.timeout(ANSWER_TIMEOUT_S):
            while moving < 3 or resting < 1:
                answer = await ur_rtde.ask("motion")
                t = answer["before"]
                if answer["after"] != t:
                    continue  # a package arrived between the getters
                sample = controller.player.sample(t)
                assert answer["qd"] == pytest.approx(list(sample.qd_rad_s), abs=1e-9)
                assert answer["qdd"] == pytest.approx(list(sample.qdd_rad_s2), abs=1e-9)
                current = np.array(answer["current"])
                heat = heat_from_current_w(motors, sample.qd_rad_s, current)
                truth = controller.bench.power(sample)
                np.testing.assert_allclose(heat * controller.bench.heat_scales, truth, rtol=1e-6)
                if np.any(np.abs(sample.qd_rad_s) > 0.05):
                    moving += 1
                else:
                    resting += 1
                    # at rest the shoulder and elbow motors hold the arm against gravity
                    assert abs(current[1]) > 0.1 and abs(current[2]) > 0.1
                await asyncio.sleep(0.05)


@pytest.mark.slow
async def test_io_interface_sets_the_speed_slider_the_program_plays_at(ur_rtde: UrRtde) -> None:
    """ur-rtde's setSpeedSlider(0.5) reaches the emulated controller (speed_slider_mask and
    _fraction): getSpeedScaling reads 0.5 and the program's moves from then on run at most at
    half their taught joint speeds (the arm still moves: a followed run's measured heat is
    that slower motion's)."""
    async with UREmulator(host=ur_rtde.host) as ur:
        controller = ur.controller
        assert (await ur_rtde.ask("slider 0.5"))["ok"]
        await settle(ur, 0.05)
        assert controller.player.speed_fraction == 0.5
        assert (await ur_rtde.ask("motion"))["speed_scaling"] == 0.5
        await settle(ur, 2.5)  # the move in progress (at full speed) is over
        start = ur.now()
        await settle(ur, 8.0)  # more than one slowed cycle's moves
        duty = controller.duty
        limit = np.asarray(duty.max_speed_rad_s) * max(pose.speed for pose in duty.poses)
        times = np.arange(start, ur.now(), 0.005)
        ratio = max(
            float(np.max(np.abs(controller.player.sample(float(t)).qd_rad_s) / limit))
            for t in times
        )
        assert 0.2 < ratio <= 0.5 + 1e-9, ratio


async def test_io_interface_writes_the_upper_input_registers(ur_rtde: UrRtde) -> None:
    async with UREmulator(host=ur_rtde.host) as ur:
        assert (await ur_rtde.ask("io_int 42 7"))["ok"]
        assert (await ur_rtde.ask("io_double 46 -0.00025"))["ok"]
        await settle(ur, 0.05)
        assert ur.controller.inputs["input_int_register_42"] == 7
        assert ur.controller.inputs["input_double_register_46"] == -0.00025
        # read back through RTDE by a second client: the controller reports its inputs
        client = RtdeClient(ur_rtde.host, ur.rtde_port, 5.0)
        try:
            await client.connect()
            recipe = await client.setup_outputs(
                ["input_int_register_42", "input_double_register_46"], 50.0
            )
            await client.start()
            assert await client.read_data(recipe) == (7, -0.00025)
            # ur-rtde's IO interface owns input register 42 now: another client gets IN_USE
            with pytest.raises(ProtocolError, match="input_int_register_42 IN_USE"):
                await client.setup_inputs(["input_int_register_42"])
            # a name the controller does not know: NOT_FOUND, as the real controller answers
            with pytest.raises(ProtocolError, match="no_such_thing NOT_FOUND"):
                await client.setup_inputs(["no_such_thing"])
        finally:
            await client.aclose()


async def test_dashboard_client_plays_pauses_and_reads_the_program_state(ur_rtde: UrRtde) -> None:
    async with UREmulator(host=ur_rtde.host) as ur:
        assert (await ur_rtde.ask("dash programState"))["answer"] == "PLAYING thermocomp.urp"
        await ur_rtde.ask("dash pause")  # ur-rtde raises unless "Pausing program" comes back
        assert (await ur_rtde.ask("dash programState"))["answer"] == "PAUSED thermocomp.urp"
        paused_at = ur.controller.player.joints(ur.now())
        await settle(ur, 0.3)
        assert list(ur.controller.player.joints(ur.now())) == list(paused_at)  # halted
        await ur_rtde.ask("dash play")  # "Starting program"
        assert (await ur_rtde.ask("dash programState"))["answer"] == "PLAYING thermocomp.urp"
        await settle(ur, 1.5)  # the first pose's dwell is 1 s: then the arm moves
        moved = ur.controller.player.joints(ur.now()) - paused_at
        assert math.hypot(*moved) > 1e-3
        assert (await ur_rtde.ask("dash robotmode"))["answer"] == "Robotmode: RUNNING"
        assert (await ur_rtde.ask("dash safetystatus"))["answer"] == "Safetystatus: NORMAL"
        await ur_rtde.ask("dash stop")
        assert (await ur_rtde.ask("dash programState"))["answer"] == "STOPPED thermocomp.urp"
        assert ur.dashboard.commands[:2] == ["programState", "pause"]


async def test_dashboard_client_reads_the_program_paused_by_a_daemon_hold(
    ur_rtde: UrRtde, tmp_path: Path
) -> None:
    """A followed run's hold (robot.pause_program_on_hold, on by default) pauses the robot's
    program through the Dashboard Server: ur-rtde's DashboardClient reads it PAUSED, and
    PLAYING again after the run's resume."""
    settings = ur_settings(tmp_path, ur_rtde.host)
    async with Daemon(settings) as daemon:
        await daemon.start_run(params(settings))
        await daemon.wait_state(RunState.RUNNING)
        assert (await ur_rtde.ask("dash programState"))["answer"] == "PLAYING thermocomp.urp"
        await daemon.hold_robot()
        async with asyncio.timeout(ANSWER_TIMEOUT_S):
            while (answer := await ur_rtde.ask("dash programState"))["answer"] != (
                "PAUSED thermocomp.urp"
            ):
                assert answer["answer"] == "PLAYING thermocomp.urp"
                await asyncio.sleep(0.05)
        await daemon.resume()
        assert (await ur_rtde.ask("dash programState"))["answer"] == "PLAYING thermocomp.urp"
        await daemon.stop()
        assert (await ur_rtde.ask("dash programState"))["answer"] == "PAUSED thermocomp.urp"
