"""The fast-path driver (drivers/c500c/server.py) against the emulated server program over a
real pseudo-terminal (and TCP): teach, move, read, errors, hold during a move, heartbeat loss,
every injected fault, cancellation."""

from __future__ import annotations

import asyncio
import dataclasses
import time
from collections.abc import AsyncIterator

import pytest
import serial_asyncio

from config.settings import RobotSettings
from drivers.base import LinkState
from drivers.c500c import server_protocol as proto
from drivers.c500c.server import C500CServerRobot
from drivers.errors import (
    DeviceError,
    DeviceReportedError,
    DeviceTimeoutError,
    GoalLostError,
    MotionHeldError,
    NotConnectedError,
    PointOfControlError,
    ProtocolError,
)
from drivers.sim.server_emulator import (
    C500CServerEmulator,
    ServerFaultKind,
    server_emulator_config,
)

# Generous against a loaded machine: a fault must outlast the timeout by a wide margin, and
# ordinary replies from the in-process emulator must never come near it.
COMMAND_TIMEOUT_S = 1.0
SILENCE_S = 4.0  # the emulated program's silence timeout; heartbeats every 0.25 s keep it calm
FAST = RobotSettings(
    driver="c500c-server",
    command_timeout_s=COMMAND_TIMEOUT_S,
    move_timeout_s=30.0,
    reconnect_max_backoff_s=0.2,
    heartbeat_s=0.25,
    server_silence_s=SILENCE_S,
)
LONG_MOVE_MS = 20_000.0  # a move nobody waits for: only a halt ends it early


def _emulator(move_ms: float = 1.0, silence_s: float = SILENCE_S) -> C500CServerEmulator:
    return C500CServerEmulator(
        server_emulator_config(paced=False, move_ms=move_ms, silence_timeout_s=silence_s)
    )


@pytest.fixture
async def emulator() -> AsyncIterator[C500CServerEmulator]:
    async with _emulator() as emu:
        yield emu


def _motion_requests(emulator: C500CServerEmulator) -> int:
    kinds = (proto.RequestType.MOVE_GOAL, proto.RequestType.MOVE_RELATIVE)
    return sum(r.type in kinds for r in emulator.requests)


async def test_teach_move_read_one_frame_each_way(emulator: C500CServerEmulator) -> None:
    async with C500CServerRobot(FAST, port=emulator.device_path) as robot:
        goal = await robot.teach_goal()
        assert goal.position == pytest.approx(emulator.goal[:3])  # type: ignore[index]
        errors = []
        for step in range(20):
            offset = (0.0001 * step, -0.0003 * step, 0.00006)
            result = await robot.move_absolute(offset)
            # The reply's pose is the controller's actual pose at 0.1 um resolution.
            assert result.actual.position == pytest.approx(emulator.state.actual[:3], abs=5e-5)
            assert result.bytes_sent == proto.MOVE_REQUEST_BYTES
            assert result.bytes_received == proto.REPLY_BYTES
            assert len(result.round_trips_s) == 1
            errors.append(result.actual.x - (goal.x + result.commanded_mm[0]))
        assert max(abs(e) for e in errors) < 0.005  # a few sigma of 0.9 um, no accumulation
        assert result.commanded_mm == (0.0019, -0.0057, 0.0001)  # quantised to 0.1 um
        pose = await robot.actual_pose()
        assert pose.position == pytest.approx(emulator.state.actual[:3], abs=5e-5)
        assert robot.status().link is LinkState.CONNECTED
        assert robot.status().point_of_control is True
    types = [r.type for r in emulator.requests]
    assert types[0] is proto.RequestType.HEARTBEAT  # the handshake
    assert types.count(proto.RequestType.MOVE_GOAL) == 20
    assert emulator.discarded == []


async def test_incremental_moves_start_from_the_actual_pose(emulator: C500CServerEmulator) -> None:
    async with C500CServerRobot(FAST, port=emulator.device_path) as robot:
        start = await robot.actual_pose()
        result = await robot.move_incremental((0.010, 0.0, -0.002))
    assert result.actual.x == pytest.approx(start.x + 0.010, abs=0.005)
    assert result.actual.z == pytest.approx(start.z - 0.002, abs=0.005)
    moves = [r for r in emulator.requests if r.type is proto.RequestType.MOVE_RELATIVE]
    assert [m.offset for m in moves] == [(0.01, 0.0, -0.002, 0.0, 0.0, 0.0)]


async def test_a_move_needs_a_taught_goal(emulator: C500CServerEmulator) -> None:
    async with C500CServerRobot(FAST, port=emulator.device_path) as robot:
        with pytest.raises(DeviceError, match="teach_goal"):
            await robot.move_absolute((0.001, 0.0, 0.0))
    assert _motion_requests(emulator) == 0


@pytest.mark.parametrize(
    ("setup", "offset", "code"),
    [
        ("online", (0.001, 0.0, 0.0), 43),
        ("arm_power", (0.001, 0.0, 0.0), 7),
        ("homed", (0.001, 0.0, 0.0), 5),
        (None, (900.0, 0.0, 0.0), 3),
    ],
)
async def test_catalogue_errors_pass_through(
    emulator: C500CServerEmulator, setup: str | None, offset: tuple[float, float, float], code: int
) -> None:
    async with C500CServerRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        if setup is not None:
            setattr(emulator.state, setup, False)
        with pytest.raises(DeviceReportedError) as caught:
            await robot.move_absolute(offset)
        assert caught.value.code == code
        assert robot.status().motion_held  # an error holds motion until resume()
        assert robot.status().link is LinkState.CONNECTED  # the link itself is fine
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.0, 0.0, 0.0))


async def test_point_of_control_missing_is_reported(emulator: C500CServerEmulator) -> None:
    emulator.state.point_of_control = False
    async with C500CServerRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        assert robot.status().point_of_control is False
        with pytest.raises(PointOfControlError):
            await robot.move_absolute((0.001, 0.0, 0.0))


async def test_hold_halts_a_move_in_progress_without_waiting_behind_it() -> None:
    async with (
        _emulator(move_ms=LONG_MOVE_MS) as emulator,
        C500CServerRobot(FAST, port=emulator.device_path) as robot,
    ):
        goal = await robot.teach_goal()
        start = emulator.state.actual
        move = asyncio.create_task(robot.move_absolute((0.5, 0.0, 0.0)))
        await asyncio.wait_for(emulator.motion_started.wait(), 5.0)
        assert emulator.moving
        started = time.perf_counter()
        await robot.stop()
        stop_s = time.perf_counter() - started
        with pytest.raises(DeviceReportedError) as caught:
            await move
        assert caught.value.code == 44 and "Halt() command invoked" in str(caught.value)
        # The move would have taken 20 s: the HOLD overtook it.
        assert stop_s < LONG_MOVE_MS / 1000 / 4
        assert emulator.halts == 1 and emulator.held and not emulator.moving
        assert emulator.state.actual == start  # halted where it was, never at the target
        # Held: no motion frame is written until resume().
        before = _motion_requests(emulator)
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.001, 0.0, 0.0))
        assert _motion_requests(emulator) == before
        await robot.resume()
        assert not emulator.held
        emulator.console.config = dataclasses.replace(emulator.console.config, move_ms=1.0)
        result = await robot.move_absolute((0.001, 0.0, 0.0))
        assert result.actual.x == pytest.approx(goal.x + 0.001, abs=0.005)


async def test_hold_contract_refuses_motion_from_the_call_of_stop(
    emulator: C500CServerEmulator,
) -> None:
    async with C500CServerRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        stop = asyncio.create_task(robot.stop())  # not yet run: stop() is only called below
        await asyncio.sleep(0)  # stop() runs up to its first await: the hold is in place
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.001, 0.0, 0.0))
        await stop
    assert _motion_requests(emulator) == 0
    assert [r.type for r in emulator.requests][-1] is proto.RequestType.HOLD


async def test_heartbeats_keep_a_long_move_alive() -> None:
    # The move lasts two and a half silence periods; the host's heartbeats overlap it.
    settings = FAST.model_copy(update={"server_silence_s": 1.0, "heartbeat_s": 0.1})
    async with (
        _emulator(move_ms=2500.0, silence_s=1.0) as emulator,
        C500CServerRobot(settings, port=emulator.device_path) as robot,
    ):
        await robot.teach_goal()
        result = await robot.move_absolute((0.002, 0.0, 0.0))
        assert robot.heartbeats >= 10
    assert emulator.halts == 0 and not emulator.held
    assert result.actual.x == pytest.approx(emulator.state.actual[0])


async def _raw(path: str) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return await serial_asyncio.open_serial_connection(url=path, baudrate=115200)


class _Replies(proto.FrameDecoder):
    """A raw client's decoder that keeps the frames one read brought beyond the first."""

    def __init__(self) -> None:
        super().__init__()
        self.waiting: list[proto.Frame] = []


async def _exchange(
    reader: asyncio.StreamReader,
    writer: asyncio.StreamWriter,
    decoder: _Replies,
    data: bytes | None,
) -> proto.Reply:
    if data is not None:
        writer.write(data)
    while not decoder.waiting:
        for event in decoder.feed(await asyncio.wait_for(reader.read(256), 10.0)):
            assert isinstance(event, proto.Frame), event
            decoder.waiting.append(event)
    return proto.parse_reply(decoder.waiting.pop(0))


async def test_heartbeat_loss_halts_the_emulated_controller() -> None:
    """A host that falls silent mid-move: the program halts (044) and holds until RELEASE."""
    async with _emulator(move_ms=LONG_MOVE_MS, silence_s=0.3) as emulator:
        reader, writer = await _raw(emulator.device_path)
        decoder = _Replies()
        try:
            teach = proto.encode_request(1, proto.RequestType.TEACH_GOAL)
            assert (await _exchange(reader, writer, decoder, teach)).ok
            move = proto.encode_request(2, proto.RequestType.MOVE_GOAL, (1.0, 0, 0, 0, 0, 0))
            writer.write(move)
            # ... and nothing more: the reply to the move comes when the watchdog halts it.
            reply = await _exchange(reader, writer, decoder, None)
            assert (reply.sequence, reply.status) == (2, proto.Status.HALTED)
            assert reply.flags & proto.Flag.HELD and reply.flags & proto.Flag.SILENCE_HALTED
            assert emulator.halts == 1 and emulator.held
            again = proto.encode_request(3, proto.RequestType.MOVE_GOAL, (0, 0, 0, 0, 0, 0))
            assert (await _exchange(reader, writer, decoder, again)).status == proto.Status.HELD
            release = proto.encode_request(4, proto.RequestType.RELEASE)
            released = await _exchange(reader, writer, decoder, release)
            assert released.ok and not released.flags & proto.Flag.HELD
        finally:
            writer.close()


async def test_a_silence_halt_is_seen_by_the_driver_and_holds_motion() -> None:
    async with (
        _emulator(silence_s=0.5) as emulator,
        C500CServerRobot(FAST, port=emulator.device_path) as robot,
    ):
        await robot.teach_goal()
        emulator.inject_server_fault("silence", 1.5)  # the next reply never comes
        with pytest.raises(DeviceTimeoutError):
            await robot.actual_pose()
        await robot.wait_connected(10.0)
        assert emulator.held and robot.status().motion_held
        await robot.resume()
        await robot.move_absolute((0.001, 0.0, 0.0))
        assert not emulator.held


@pytest.mark.parametrize(
    ("kind", "expected"),
    [
        ("crc", ProtocolError),
        # A short frame is found out by the next frame (a heartbeat's reply at the latest):
        # its length swallows the next frame's start and the CRC fails.
        ("short", ProtocolError),
        ("sequence", ProtocolError),
        ("silence", DeviceTimeoutError),
        ("close", NotConnectedError),
    ],
)
async def test_each_fault_is_reported_recovered_and_holds_motion(
    emulator: C500CServerEmulator, kind: ServerFaultKind, expected: type[DeviceError]
) -> None:
    async with C500CServerRobot(FAST, port=emulator.device_path, first_backoff_s=0.05) as robot:
        await robot.teach_goal()
        await robot.move_absolute((0.002, 0.0, 0.0))
        emulator.inject_server_fault(kind, 2.5 * COMMAND_TIMEOUT_S)
        with pytest.raises(expected):
            await robot.actual_pose()  # the fault strikes this request's reply
        status = robot.status()
        assert status.motion_held and status.last_error
        assert status.link in (LinkState.RECONNECTING, LinkState.CONNECTED)

        await robot.wait_connected(10.0)
        before = _motion_requests(emulator)
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.004, 0.0, 0.0))
        assert _motion_requests(emulator) == before  # nothing sent

        await robot.resume()
        result = await robot.move_absolute((0.004, 0.0, 0.0))
        assert result.actual.x == pytest.approx(robot.goal.x + 0.004, abs=0.005)  # type: ignore[union-attr]
        assert int(robot.status().extra["reconnect_attempts"]) >= 1
    assert [k for _, k in emulator.server_faults_applied] == [kind]
    assert robot.link_history[:4] == [
        LinkState.DISCONNECTED,
        LinkState.CONNECTING,
        LinkState.CONNECTED,
        LinkState.RECONNECTING,
    ]
    assert robot.link_history[-2:] == [LinkState.CONNECTED, LinkState.DISCONNECTED]


async def test_a_cancelled_request_never_desynchronises_the_link() -> None:
    async with (
        _emulator(move_ms=300.0) as emulator,
        C500CServerRobot(FAST, port=emulator.device_path) as robot,
    ):
        await robot.teach_goal()
        move = asyncio.create_task(robot.move_absolute((0.003, 0.0, 0.0)))
        await asyncio.wait_for(emulator.motion_started.wait(), 5.0)
        move.cancel()
        with pytest.raises(asyncio.CancelledError):
            await move
        # The move's late reply arrives while these wait for theirs: recognised, dropped.
        poses = [await robot.actual_pose() for _ in range(3)]
        while emulator.moving:
            await robot.actual_pose()
        await robot.actual_pose()  # after the move's reply has been sent
        assert robot.stray_replies == 1
        assert robot.status().link is LinkState.CONNECTED
        # a cut move holds until an explicit resume (the Robot contract, tests/contract/): the
        # caller cannot know how far it got
        assert robot.status().motion_held
        assert robot.link_history[-1] is LinkState.CONNECTED and len(poses) == 3


async def test_goal_lost_by_a_restarted_program_refuses_resume(
    emulator: C500CServerEmulator,
) -> None:
    async with C500CServerRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        await robot.stop()
        del emulator.state.locations["opgoal"]  # the program restarted: its goal is gone
        with pytest.raises(GoalLostError, match="lost the taught goal"):
            await robot.resume()
        assert robot.status().motion_held


async def test_over_tcp() -> None:
    config = server_emulator_config(paced=False, move_ms=1.0)
    async with C500CServerEmulator(config, transport="tcp") as emulator:
        assert emulator.device_path.startswith("socket://")
        async with C500CServerRobot(FAST, port=emulator.device_path) as robot:
            await robot.teach_goal()
            result = await robot.move_absolute((0.001, 0.0, 0.0))
    assert result.actual.position == pytest.approx(emulator.state.actual[:3], abs=5e-5)


async def test_no_controller_fails_the_connect_cleanly(tmp_path: object) -> None:
    with pytest.raises(NotConnectedError):
        async with C500CServerRobot(FAST, port="/nonexistent/tty"):
            pass


async def test_the_emulated_program_refuses_what_the_specification_refuses() -> None:
    async with _emulator(move_ms=LONG_MOVE_MS) as emulator:
        reader, writer = await _raw(emulator.device_path)
        decoder = _Replies()
        offset = (0.001, 0, 0, 0, 0, 0)
        try:
            unknown = await _exchange(reader, writer, decoder, proto.encode_frame(1, 0x42))
            assert (unknown.request, unknown.status) == (0x42, proto.Status.BAD_REQUEST)
            short_body = proto.encode_frame(2, proto.RequestType.MOVE_GOAL, b"\x00" * 5)
            bad = await _exchange(reader, writer, decoder, short_body)
            assert bad.status == proto.Status.BAD_REQUEST
            early = proto.encode_request(3, proto.RequestType.MOVE_GOAL, offset)
            assert (await _exchange(reader, writer, decoder, early)).status == 1001
            teach = proto.encode_request(4, proto.RequestType.TEACH_GOAL)
            taught = await _exchange(reader, writer, decoder, teach)
            assert taught.ok and taught.flags & proto.Flag.GOAL_TAUGHT
            writer.write(proto.encode_request(5, proto.RequestType.MOVE_GOAL, offset))
            await asyncio.wait_for(emulator.motion_started.wait(), 5.0)
            second = proto.encode_request(6, proto.RequestType.MOVE_RELATIVE, offset)
            busy = await _exchange(reader, writer, decoder, second)
            assert (busy.sequence, busy.status) == (6, proto.Status.BUSY)
            assert busy.flags & proto.Flag.MOVING
            reteach = proto.encode_request(7, proto.RequestType.TEACH_GOAL)
            assert (await _exchange(reader, writer, decoder, reteach)).status == proto.Status.BUSY
            hold = await _exchange(
                reader, writer, decoder, proto.encode_request(8, proto.RequestType.HOLD)
            )
            assert hold.sequence == 8 and hold.ok and hold.flags & proto.Flag.HELD
            halted = await _exchange(reader, writer, decoder, None)
            assert (halted.sequence, halted.status) == (5, proto.Status.HALTED)
            assert not halted.flags & proto.Flag.SILENCE_HALTED
        finally:
            writer.close()
    # Garbage between frames was skipped, never answered.
    assert emulator.discarded == []


async def test_stop_with_the_link_down_still_holds_and_returns(
    emulator: C500CServerEmulator,
) -> None:
    async with C500CServerRobot(FAST, port=emulator.device_path, first_backoff_s=5.0) as robot:
        await robot.teach_goal()
        emulator.inject_server_fault("close")
        with pytest.raises(NotConnectedError):
            await robot.actual_pose()
        assert robot.status().link is LinkState.RECONNECTING
        await robot.stop()  # nothing can carry HOLD now: the program's silence timeout will
        assert robot.status().motion_held
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.001, 0.0, 0.0))


async def test_a_hold_during_resume_survives_it(emulator: C500CServerEmulator) -> None:
    """Issue 26: the fast path's resume() cleared its hold unconditionally, so a hold that
    came while the resume awaited the program's replies was released by it and the next
    MOVE_GOAL went out."""
    async with C500CServerRobot(FAST, port=emulator.device_path) as robot:
        await robot.teach_goal()
        await robot.stop()
        resume = asyncio.create_task(robot.resume())
        await asyncio.sleep(0)  # the resume runs until it awaits the program's first reply
        await robot.stop()  # the operator's hold, answered while the resume is under way
        with pytest.raises(MotionHeldError):
            await resume
        assert robot.status().motion_held
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.001, 0.0, 0.0))
    assert _motion_requests(emulator) == 0
