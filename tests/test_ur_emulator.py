"""The UR emulator's own behaviour: the output frequency honoured, the guide's NOT_FOUND and
IN_USE answers, the Dashboard's protective-stop recovery, and the taught program's "at measured
pose" register over a whole cycle (no network)."""

from __future__ import annotations

import asyncio
import itertools
import math

import pytest

from drivers.errors import ProtocolError
from drivers.sim.ur.controller import URController, URControllerConfig
from drivers.sim.ur.emulator import UREmulator
from drivers.ur import rtde_protocol as rtde
from drivers.ur.dashboard_client import DashboardClient
from drivers.ur.modes import RuntimeState, SafetyMode
from drivers.ur.rtde_client import RtdeClient
from tests.loopback import loopback_host


async def connected(host: str, port: int) -> RtdeClient:
    client = RtdeClient(host, port, 5.0)
    await client.connect()
    return client


@pytest.mark.parametrize("frequency_hz", [500.0, 125.0, 30.0])
async def test_the_output_frequency_is_honoured_cycle_by_cycle(frequency_hz: float) -> None:
    host = loopback_host()
    async with UREmulator(host=host) as ur:
        client = await connected(host, ur.rtde_port)
        try:
            assert client.controller_version == (5, 15, 0, 0)
            recipe = await client.setup_outputs(["timestamp"], frequency_hz)
            await client.start()
            stamps = []
            for _ in range(60):
                (stamp,) = await client.read_data(recipe)
                assert isinstance(stamp, float)
                stamps.append(stamp)
        finally:
            await client.aclose()
    steps = [b - a for a, b in itertools.pairwise(stamps)]
    cycle = rtde.CONTROLLER_CYCLE_S
    # every package is one whole number of 2 ms cycles after the one before, none lost or
    # repeated, and on average exactly 1/f apart (a timestamp is its cycle's, not the wall's)
    assert all(s > 0 and s / cycle == pytest.approx(round(s / cycle), abs=1e-6) for s in steps)
    assert (stamps[-1] - stamps[0]) / len(steps) == pytest.approx(1 / frequency_hz, rel=0.02)
    assert max(steps) <= math.ceil(rtde.MAX_FREQUENCY_HZ / frequency_hz) * cycle + 1e-9


async def test_unknown_outputs_are_not_found_and_a_refused_recipe_gets_id_zero() -> None:
    host = loopback_host()
    async with UREmulator(host=host) as ur:
        client = await connected(host, ur.rtde_port)
        try:
            reply = await client.request(
                rtde.setup_outputs(125.0, ["timestamp", "actual_qqq"]),
                rtde.PackageType.CONTROL_PACKAGE_SETUP_OUTPUTS,
            )
            assert rtde.parse_setup_reply(reply) == (0, ("DOUBLE", "NOT_FOUND"))
            with pytest.raises(ProtocolError, match="recipe refused"):
                await client.setup_outputs(["timestamp"], 501.0)  # over the 500 Hz loop
        finally:
            await client.aclose()


async def test_a_fieldbus_makes_the_lower_registers_in_use() -> None:
    config = URControllerConfig(fieldbus=True)
    host = loopback_host()
    async with UREmulator(config, host=host) as ur:
        client = await connected(host, ur.rtde_port)
        try:
            with pytest.raises(ProtocolError, match="input_int_register_3 IN_USE"):
                await client.setup_inputs(["input_int_register_3"])
            recipe = await client.setup_inputs(["input_int_register_24"])  # the upper range
            assert recipe.id > 0
        finally:
            await client.aclose()


async def test_protective_stop_pauses_and_the_dashboard_recovers() -> None:
    host = loopback_host()
    async with UREmulator(host=host) as ur:
        dashboard = DashboardClient(host, ur.dashboard_port, 5.0)
        ur.protective_stop()
        assert await dashboard.safety_status() == "PROTECTIVE_STOP"
        assert await dashboard.program_state() == "PAUSED"
        assert await dashboard.command("play") == "Failed to execute: play"
        assert await dashboard.command("unlock protective stop") == "Protective stop releasing"
        await dashboard.play()
        assert await dashboard.program_state() == "PLAYING"
        ur.operator_stop()
        assert await dashboard.program_state() == "STOPPED"
        assert ur.controller.runtime_state is RuntimeState.STOPPED
        assert ur.controller.safety_mode is SafetyMode.NORMAL
        assert await dashboard.command("frobnicate") == "could not understand: 'frobnicate'"
        ur.drop_connections()  # nothing is connected now: a no-op
        await asyncio.sleep(0)


def test_the_program_reports_each_measured_pose_while_it_dwells_there() -> None:
    controller = URController(URControllerConfig())
    duty = controller.duty
    measured = {i + 1 for i, pose in enumerate(duty.poses) if pose.measure}
    arrivals = duty.arrival_times_s()
    seen: dict[int, list[float]] = {}
    cycle = rtde.CONTROLLER_CYCLE_S
    for k in range(1, round(duty.period_s * 1.5 / cycle)):
        t = k * cycle
        controller.cycle(t)
        at = controller.outputs[controller.registers.at_pose]
        assert isinstance(at, int)
        if at:
            seen.setdefault(at, []).append(t)
    assert set(seen) == measured == {1, 6}
    # pose 6 (the fixture): from its arrival for its dwell, each cycle (the player follows the
    # duty cycle's own plan to the controller cycle)
    place = seen[6]
    assert place[0] == pytest.approx(arrivals[5], abs=cycle)
    assert place[-1] - place[0] == pytest.approx(duty.poses[5].dwell_s, abs=2 * cycle)
    # the joints at the fixture are the taught pose's
    q = controller.player.joints(place[0] + 0.1)
    assert q == pytest.approx(duty.poses[5].q_rad, abs=1e-9)
