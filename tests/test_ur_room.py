"""A UR's room thermometer (issue 31): a UR reports no air temperature, so a followed run reads
the lab's own (room.driver) as an A465 arm run does (issue 29). The UR bench has one
(drivers/sim/ur/room.py: the truth's room); a followed run reads it each step, records it
(``room_c``), the model's ambient follows it, a failed reading is flagged and the run goes on,
and the summary says when the run had none. That identification then blames a warming room
on the room and not on the joint sensors' offsets: tests/test_ur_identify_structure.py."""

from __future__ import annotations

import asyncio
import json
import sqlite3
from pathlib import Path
from typing import Any, Self

import pytest
from pydantic import ValidationError

from benchmarks.ur_recorded import emulated
from config.settings import Settings, load_settings
from daemon.run.followed.summary import followed_summary_rows
from daemon.service import Daemon
from daemon.storage.recorder import DATABASE_NAME
from drivers.base import RoomReading
from drivers.clock import Clock, make_clock
from drivers.errors import DeviceError
from drivers.sim.ur.room import SimURRoom
from tests.fakes import make_settings, params
from tests.helpers import REPO_ROOT
from tests.test_followed_kind import WAIT_S, FollowedDevices

UR5E = REPO_ROOT / "config" / "ur5e-sim.toml"
#: the fake room: 20 degC at the start, warming this fast (degC per run-clock second)
ROOM_START_C = 20.0
ROOM_RATE_C_PER_S = 0.5


class FakeRoom:
    """A thermometer whose room warms linearly on the run's clock; ``fail`` makes every read
    a DeviceError (a sensor unplugged)."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.fail = False
        self.reads = 0

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def read(self) -> RoomReading:
        self.reads += 1
        if self.fail:
            raise DeviceError("room", "28-000000000000: CRC check failed")
        now = self.clock.now()
        return RoomReading(ROOM_START_C + ROOM_RATE_C_PER_S * now, now, "fake")


class RoomDevices(FollowedDevices):
    def __init__(self, clock: Clock) -> None:
        super().__init__(clock)
        self.room = FakeRoom(clock)


def ur_settings(**room: str) -> Settings:
    data = load_settings(UR5E).model_dump()
    data["room"].update(room)
    return Settings.model_validate(data)


def test_the_ur_bench_has_a_room_thermometer_and_hardware_needs_a_real_one() -> None:
    """room.driver sim is the UR bench's (bench.enabled, ur-rtde), refused on a real UR in one
    message that names the real sensor; the bench's reads the truth's room."""
    assert ur_settings(driver="sim").room.driver == "sim"
    data = load_settings(UR5E).model_dump()
    data["room"]["driver"] = "sim"
    data["bench"]["enabled"] = False
    with pytest.raises(ValidationError) as refused:
        Settings.model_validate(data)
    assert "room.driver w1" in str(refused.value)
    controller = emulated(1, {"ambient_drift_c_per_h": 1.0})
    start = controller.room_temperature(0.0)
    assert start == pytest.approx(controller.bench.config.ambient_c, abs=0.1)
    # an hour later the sensor read the room warmed by 1 degC (less its 2-minute lag)
    assert controller.room_temperature(3600.0) - start == pytest.approx(1.0, abs=0.1)


async def test_the_ur_bench_room_reads_at_the_controllers_cycle() -> None:
    controller = emulated(1, {"ambient_drift_c_per_h": 3600.0 / 100.0})  # 1 degC / 100 s
    clock = make_clock("virtual")
    async with SimURRoom(controller, clock) as room:
        first = await room.read()
        controller.time_s = 100.0  # as the emulator's cycle leaves it
        second = await room.read()
    assert first.sensor == "sim" and first.timestamp_s == clock.now()
    # the lagged sensor (120 s) on a ramp of 1 degC per 100 s: 1 - 1.2 (1 - e^-100/120) =
    # 0.32 degC after 100 s (to its 1/16 degC resolution and noise)
    assert second.temperature_c - first.temperature_c == pytest.approx(0.32, abs=0.1)


async def follow(
    tmp_path: Path, devices: FollowedDevices, clock: Clock, steps: int = 5
) -> dict[str, Any]:
    settings = make_settings(
        tmp_path,
        scheduler={"step_s": 0.2, "duration_s": 600.0},
        # the model alone: the fake's joint temperatures are constant and would pin the joints
        model={"prediction": "model"},
        room={"driver": "w1"},  # the fake stands in for the lab's DS18B20
        arm={"enabled": True, "arm_file": "ur5e", "duty_cycle": "ur5e-pick-and-place"},
    )
    robot = devices.robot
    async with Daemon(settings, clock=clock, open_devices=lambda _s, _c: devices) as daemon:
        await daemon.start_run(params(settings, time_scale=600.0))
        async with asyncio.timeout(WAIT_S):
            while len(robot.written) < steps:  # noqa: ASYNC110 -- the fake has no event
                await asyncio.sleep(0.01)
        final = await daemon.stop()
    summary = final["summary"]
    assert isinstance(summary, dict)
    return summary


def rows(data_dir: Path) -> list[tuple[Any, ...]]:
    with sqlite3.connect(data_dir / DATABASE_NAME) as db:
        return db.execute("SELECT room_c, flags, model_temperatures_json FROM steps").fetchall()


async def test_a_followed_run_records_the_room_and_its_model_follows_it(tmp_path: Path) -> None:
    """Each step reads the room before the model; the readings are recorded, the summary has
    them, and the model's ambient is the room read, not model.ambient_c: the cold arm starts
    at the first reading (20 degC), a run without a thermometer at 22 degC."""
    clock = make_clock("virtual")
    devices = RoomDevices(clock)
    summary = await follow(tmp_path / "with", devices, clock)
    recorded = rows(tmp_path / "with")
    assert recorded and all(isinstance(room, float) for room, _, _ in recorded)
    assert [room for room, _, _ in recorded] == sorted(room for room, _, _ in recorded)
    room = summary["room"]
    assert isinstance(room, dict) and room["measured"] and room["readings"] == len(recorded)
    assert room["first_c"] == recorded[0][0] and room["last_c"] == recorded[-1][0]
    assert ("room: last reading", room["last_c"], "degC") in followed_summary_rows(summary)
    # the same run without a thermometer: the model's joints are the heat's alone
    clock_bare = make_clock("virtual")
    summary_bare = await follow(tmp_path / "without", FollowedDevices(clock_bare), clock_bare)
    room_bare = summary_bare["room"]
    assert not room_bare["measured"] and room_bare["readings"] == 0
    assert "no room thermometer" in room_bare["note"]
    assert ("room", "not measured: the model held model.ambient_c (room.driver)", "") in (
        followed_summary_rows(summary_bare)
    )
    recorded_bare = rows(tmp_path / "without")
    assert all(room is None for room, _, _ in recorded_bare)
    # the wrist's joint node at the first step: little heat yet, so nearly the ambient
    first = json.loads(recorded[0][2])
    first_bare = json.loads(recorded_bare[0][2])
    wrist = sorted(first)[-1]
    assert first[wrist] == pytest.approx(ROOM_START_C, abs=0.3), first
    assert first_bare[wrist] == pytest.approx(22.0, abs=0.3), first_bare


async def test_a_failed_room_reading_is_flagged_and_the_run_goes_on(tmp_path: Path) -> None:
    clock = make_clock("virtual")
    devices = RoomDevices(clock)
    devices.room.fail = True
    summary = await follow(tmp_path, devices, clock)
    recorded = rows(tmp_path)
    assert recorded
    assert all(room is None and "room-error" in flags for room, flags, _ in recorded)
    room = summary["room"]
    assert isinstance(room, dict) and not room["measured"] and room["errors"] == len(recorded)
    assert devices.robot.written  # corrections still written
