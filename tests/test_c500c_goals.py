"""Issue 20 in the drivers: absolute moves with a rotation and several named taught goals, on
the console (exact exchanges, tests/c500c_scripted.py, and the emulator over a real pty) and on
the fast path (framing, and the emulated program over a real pty)."""

from __future__ import annotations

import math
from collections.abc import AsyncIterator

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from config.settings import RobotSettings
from daemon.arm.types import Pose6
from drivers.base import DEFAULT_GOAL, GoalRobot, Pose
from drivers.c500c import server_protocol as proto
from drivers.c500c.robot import C500CRobot
from drivers.c500c.server import C500CServerRobot
from drivers.errors import DeviceError, GoalLostError, MotionHeldError, ProtocolError
from drivers.goals import goal_variable, rotation_zyx_deg
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.server_emulator import (
    C500CServerEmulator,
    goal_location,
    server_emulator_config,
)
from tests.c500c_scripted import (
    PROMPT,
    ScriptedRobot,
    ok_exchange,
    probe_exchange,
    w2_exchange,
)

GOAL = (457.2, 0.0, 254.0, 0.0, 90.0, 0.0)  # the emulator's start pose (drivers/sim/ash_state.py)


def _rotvec(z_deg: float, y_deg: float, x_deg: float) -> tuple[float, float, float]:
    """The rotation vector of intrinsic z-y-x angles (the oracle's direction of the mapping)."""
    x, y, z = Rotation.from_euler("ZYX", [z_deg, y_deg, x_deg], degrees=True).as_rotvec()
    return (float(x), float(y), float(z))


# --- the rotation and goal names (drivers/goals.py) ------------------------------------------


@pytest.mark.parametrize(
    ("rotation_rad", "expected_deg"),
    [
        ((0.0, 0.0, math.radians(0.5)), (0.5, 0.0, 0.0)),  # about z: z-rot only
        ((0.0, math.radians(-0.25), 0.0), (0.0, -0.25, 0.0)),  # about y: y-rot only
        ((math.radians(1.0), 0.0, 0.0), (0.0, 0.0, 1.0)),  # about x: x-rot only
        (_rotvec(0.3, -0.2, 0.1), (0.3, -0.2, 0.1)),  # all three, through SciPy's inverse
    ],
)
def test_rotation_vector_to_wshift_angles(
    rotation_rad: tuple[float, float, float], expected_deg: tuple[float, float, float]
) -> None:
    assert rotation_zyx_deg(rotation_rad, "robot") == pytest.approx(expected_deg, abs=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_the_driver_and_the_arm_model_agree_on_the_angles(seed: int) -> None:
    """drivers/goals.py converts with SciPy itself (a driver imports no model code); it must
    give Pose6.zyx_deg's angles, the gimbal lock (y = 90 deg) included."""
    rng = np.random.default_rng(seed)
    rotations = [tuple(rng.normal(0.0, 0.5, 3)), (0.0, math.pi / 2, 0.0)]
    for rotation in rotations:
        pose = Pose6(np.zeros(3), np.array(rotation, dtype=np.float64))
        assert rotation_zyx_deg(rotation, "robot") == pytest.approx(pose.zyx_deg(), abs=1e-9)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_a_non_finite_rotation_is_refused(bad: float) -> None:
    with pytest.raises(DeviceError, match="non-finite rotation"):
        rotation_zyx_deg((0.0, bad, 0.0), "robot")


def test_goal_variables() -> None:
    assert goal_variable(DEFAULT_GOAL, "robot") == "opgoal"
    assert goal_variable("p1", "robot") == "g_p1"
    assert goal_variable("Pick_2", "robot") == "g_Pick_2"
    for bad in ("", "1p", "cur x", "p-1", "a" * 15, "move;here"):
        with pytest.raises(DeviceError, match="goal name"):
            goal_variable(bad, "robot")


def test_both_drivers_are_goal_robots() -> None:
    robots: list[GoalRobot] = [
        C500CRobot(RobotSettings(), port="unused"),
        C500CServerRobot(RobotSettings(driver="c500c-server"), port="unused"),
    ]  # mypy checks the signatures; the defaults keep drivers.base.Robot's
    assert all(r.taught_goals() == {} for r in robots)


# --- the console: exact exchanges ------------------------------------------------------------


def _set_and_shift(goal: bytes, shift: bytes, answer: bytes = b"") -> tuple[bytes, bytes]:
    set_cur = b"set cur = " + goal
    return (
        set_cur + b"\r" + shift + b"\r",
        set_cur + b"\r\n" + answer + PROMPT + shift + b"\r\n" + PROMPT,
    )


CONNECT = [probe_exchange(), ok_exchange(b"new cur"), ok_exchange(b"online on")]
P1 = (460.0, 10.0, 250.0, 1.0, 89.0, 0.5)


async def test_rotated_wshift_exchange() -> None:
    rotated = (457.212, 0.0, 254.0, 0.3, 89.8, 0.1)
    script = [
        *CONNECT,
        ok_exchange(b"new opgoal"),
        ok_exchange(b"here opgoal"),
        w2_exchange(GOAL),
        _set_and_shift(b"opgoal", b"wshift cur,0.012,0.000,0.000,0.300,-0.200,0.100"),
        ok_exchange(b"moves cur"),
        ok_exchange(b"finish"),
        w2_exchange(rotated),
        # a rotation about z alone, rounded to the console's 0.001 degree
        _set_and_shift(b"opgoal", b"wshift cur,0.000,0.000,0.000,-0.001,0.000,0.000"),
        ok_exchange(b"moves cur"),
        ok_exchange(b"finish"),
        w2_exchange(GOAL),
    ]
    robot = ScriptedRobot(script)
    async with robot:
        await robot.teach_goal()
        result = await robot.move_absolute((0.0121, 0.0, 0.0), _rotvec(0.3, -0.2, 0.1))
        assert result.commanded_rotation_deg == pytest.approx((0.3, -0.2, 0.1), abs=1e-12)
        assert result.actual == Pose(*rotated)
        assert result.goal == DEFAULT_GOAL
        small = await robot.move_absolute((0.0, 0.0, 0.0), (0.0, 0.0, math.radians(-0.0012)))
        assert small.commanded_rotation_deg == (-0.001, 0.0, 0.0)
    robot.assert_all_used()


async def test_named_goals_exchange_and_resume_checks_every_goal() -> None:
    script = [
        *CONNECT,
        ok_exchange(b"new opgoal"),
        ok_exchange(b"here opgoal"),
        w2_exchange(GOAL),
        # docs/reference/c500c-console.md "Questions": created with `new` before `here`
        ok_exchange(b"new g_p1"),
        ok_exchange(b"here g_p1"),
        w2_exchange(P1),
        _set_and_shift(b"g_p1", b"wshift cur,0.001,0.000,-0.002,0,0,0"),
        ok_exchange(b"moves cur"),
        ok_exchange(b"finish"),
        w2_exchange((460.001, 10.0, 249.998, 1.0, 89.0, 0.5)),
        _set_and_shift(b"opgoal", b"wshift cur,0.000,0.000,0.000,0,0,0"),
        ok_exchange(b"moves cur"),
        ok_exchange(b"finish"),
        w2_exchange(GOAL),
        # resume: every taught goal must still exist, then one read-back
        ok_exchange(b"set cur = opgoal"),
        ok_exchange(b"set cur = g_p1"),
        w2_exchange(GOAL),
    ]
    robot = ScriptedRobot(script)
    async with robot:
        await robot.teach_goal()
        assert await robot.teach_goal("p1") == Pose(*P1)
        result = await robot.move_absolute((0.001, 0.0, -0.002), goal="p1")
        assert result.goal == "p1"
        assert result.actual.position == (460.001, 10.0, 249.998)
        await robot.move_absolute((0.0, 0.0, 0.0))  # the default goal, as before issue 20
        assert robot.taught_goals() == {DEFAULT_GOAL: Pose(*GOAL), "p1": Pose(*P1)}
        await robot.stop()
        with pytest.raises(MotionHeldError):  # a hold refuses every goal
            await robot.move_absolute((0.0, 0.0, 0.0), goal="p1")
        await robot.resume()
    robot.assert_all_used()


async def test_a_lost_named_goal_refuses_resume() -> None:
    script = [
        *CONNECT,
        ok_exchange(b"new g_p1"),
        ok_exchange(b"here g_p1"),
        w2_exchange(P1),
        (b"set cur = g_p1\r", b"set cur = g_p1\r\nerror: variable not found.\r\n" + PROMPT),
    ]
    robot = ScriptedRobot(script)
    async with robot:
        await robot.teach_goal("p1")
        await robot.stop()
        with pytest.raises(GoalLostError):
            await robot.resume()
        assert robot.status().motion_held
    robot.assert_all_used()


@pytest.mark.parametrize(
    ("offset", "rotation", "goal", "match"),
    [
        ((0.0, 0.0, 0.0), (0.0, math.nan, 0.0), DEFAULT_GOAL, "non-finite rotation"),
        ((0.0, 0.0, 0.0), (math.inf, 0.0, 0.0), DEFAULT_GOAL, "non-finite rotation"),
        ((math.nan, 0.0, 0.0), (0.0, 0.0, 0.0), DEFAULT_GOAL, "non-finite motion target"),
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), "p2", "no goal 'p2' taught"),
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), "no such", "goal name"),
    ],
)
async def test_refused_moves_write_nothing(
    offset: tuple[float, float, float],
    rotation: tuple[float, float, float],
    goal: str,
    match: str,
) -> None:
    robot = ScriptedRobot(
        [*CONNECT, ok_exchange(b"new opgoal"), ok_exchange(b"here opgoal"), w2_exchange(GOAL)]
    )
    async with robot:
        await robot.teach_goal()
        with pytest.raises(DeviceError, match=match):
            await robot.move_absolute(offset, rotation, goal=goal)  # a write fails the script
    robot.assert_all_used()


# --- the console driver against the emulator (real pty) --------------------------------------

CONSOLE = RobotSettings(command_timeout_s=1.0, move_timeout_s=2.0, reconnect_max_backoff_s=0.2)


@pytest.fixture
async def console_emulator() -> AsyncIterator[C500CEmulator]:
    async with C500CEmulator(EmulatorConfig(paced=False, noise_um=0.0, move_ms=1.0)) as emu:
        yield emu


async def test_console_goals_and_rotation_on_the_emulator(
    console_emulator: C500CEmulator,
) -> None:
    async with C500CRobot(CONSOLE, port=console_emulator.device_path) as robot:
        home = await robot.teach_goal()
        await robot.move_absolute((5.0, -2.0, 1.0))
        second = await robot.teach_goal("p1")  # taught where the arm is now
        assert second.position == pytest.approx((home.x + 5.0, home.y - 2.0, home.z + 1.0))
        result = await robot.move_absolute((0.0, 0.0, 0.0), _rotvec(0.5, 0.0, -0.25), goal="p1")
        # the emulator adds wshift's angles to the location's (emulator simplification)
        assert result.actual == pytest.approx(
            Pose(second.x, second.y, second.z, home.z_rot + 0.5, home.y_rot, home.x_rot - 0.25)
        )
        back = await robot.move_absolute((0.001, 0.0, 0.0))
        assert back.actual.position == pytest.approx((home.x + 0.001, home.y, home.z))
    commands = list(console_emulator.state.commands)
    assert "new g_p1" in commands and "set cur = g_p1" in commands
    assert "wshift cur,0.000,0.000,0.000,0.500,0.000,-0.250" in commands


# --- the fast path: framing ------------------------------------------------------------------


def test_goal_zero_frames_are_those_of_a_single_goal() -> None:
    offset = (0.0123, 0.0, 0.0, 0.0, 0.0, 0.0)
    plain = proto.encode_request(2, proto.RequestType.MOVE_GOAL, offset)
    assert proto.encode_request(2, proto.RequestType.MOVE_GOAL, offset, goal=0) == plain
    assert len(plain) == proto.MOVE_REQUEST_BYTES
    teach = proto.encode_request(3, proto.RequestType.TEACH_GOAL)
    assert len(teach) == proto.REQUEST_BYTES
    assert proto.parse_request(proto.decode_frame(teach)).goal == 0


def test_six_values_and_a_goal_index_round_trip() -> None:
    offset = (0.0123, -1.5, 2.25, 0.3, -0.2, 0.1)
    data = proto.encode_request(7, proto.RequestType.MOVE_GOAL, offset, goal=5)
    frame = proto.decode_frame(data)
    assert len(frame.body) == proto.MOVE_BODY.size + 1 and frame.body[-1] == 5
    # the six values in the WORLD row's order, in 0.1 um and 0.0001 degree
    assert proto.MOVE_BODY.unpack_from(frame.body)[:6] == (123, -15000, 22500, 3000, -2000, 1000)
    request = proto.parse_request(frame)
    assert request.offset == pytest.approx(offset)
    assert request.goal == 5
    teach = proto.parse_request(
        proto.decode_frame(proto.encode_request(8, proto.RequestType.TEACH_GOAL, goal=15))
    )
    assert teach.goal == 15


def test_goal_indices_out_of_range_or_on_other_requests_are_refused() -> None:
    with pytest.raises(ValueError, match="goal 16"):
        proto.encode_request(1, proto.RequestType.TEACH_GOAL, goal=proto.MAX_GOALS)
    with pytest.raises(ValueError, match="takes no goal"):
        proto.encode_request(1, proto.RequestType.MOVE_RELATIVE, (0.0,) * 6, goal=1)
    body = proto.MOVE_BODY.pack(0, 0, 0, 0, 0, 0, proto.MODE_STRAIGHT)
    for frame_type, extra in (
        (proto.RequestType.MOVE_GOAL, bytes([proto.MAX_GOALS])),  # index too large
        (proto.RequestType.MOVE_RELATIVE, b"\x01"),  # no goal on a relative move
        (proto.RequestType.MOVE_GOAL, b"\x01\x02"),  # one byte too many
    ):
        frame = proto.decode_frame(proto.encode_frame(1, frame_type, body + extra))
        with pytest.raises(ProtocolError):
            proto.parse_request(frame)
    with pytest.raises(ProtocolError):
        proto.parse_request(proto.decode_frame(proto.encode_frame(1, 2, b"\x01\x02")))


# --- the fast path against the emulated program (real pty) -----------------------------------

SERVER = RobotSettings(
    driver="c500c-server",
    command_timeout_s=1.0,
    move_timeout_s=30.0,
    heartbeat_s=0.25,
    server_silence_s=4.0,
)


@pytest.fixture
async def server_emulator() -> AsyncIterator[C500CServerEmulator]:
    config = server_emulator_config(paced=False, move_ms=1.0, noise_um=0.0, silence_timeout_s=4.0)
    async with C500CServerEmulator(config) as emu:
        yield emu


async def test_fast_path_goals_and_rotation(server_emulator: C500CServerEmulator) -> None:
    emulator = server_emulator
    async with C500CServerRobot(SERVER, port=emulator.device_path) as robot:
        home = await robot.teach_goal()
        await robot.move_absolute((5.0, -2.0, 1.0))
        second = await robot.teach_goal("p1")
        assert emulator.goal_at(1) == pytest.approx((*second.position, *GOAL[3:]))
        result = await robot.move_absolute((0.0, 0.0, 0.0), _rotvec(0.5, 0.0, -0.25), goal="p1")
        request = emulator.requests[-1]
        assert (request.type, request.goal) == (proto.RequestType.MOVE_GOAL, 1)
        assert request.offset == pytest.approx((0.0, 0.0, 0.0, 0.5, 0.0, -0.25))
        assert result.commanded_rotation_deg == pytest.approx((0.5, 0.0, -0.25))
        assert result.bytes_sent == proto.MOVE_REQUEST_BYTES + 1
        assert result.actual == pytest.approx(
            Pose(second.x, second.y, second.z, home.z_rot + 0.5, home.y_rot, home.x_rot - 0.25)
        )
        back = await robot.move_absolute((0.001, 0.0, 0.0))  # the default goal: goal 0
        assert emulator.requests[-1].goal == 0
        assert back.bytes_sent == proto.MOVE_REQUEST_BYTES
        assert back.actual.position == pytest.approx((home.x + 0.001, home.y, home.z))
        await robot.stop()
        with pytest.raises(MotionHeldError):
            await robot.move_absolute((0.0, 0.0, 0.0), goal="p1")
        with pytest.raises(DeviceError, match="no goal 'p2'"):
            await robot.move_absolute((0.0, 0.0, 0.0), goal="p2")
        await robot.resume()
        again = await robot.move_absolute((0.0, 0.0, 0.0), goal="p1")
        assert again.actual.position == pytest.approx(second.position)


async def test_fast_path_refuses_a_seventeenth_goal(server_emulator: C500CServerEmulator) -> None:
    async with C500CServerRobot(SERVER, port=server_emulator.device_path) as robot:
        names = [DEFAULT_GOAL, *(f"p{i}" for i in range(1, proto.MAX_GOALS))]
        for name in names:
            await robot.teach_goal(name)
        assert len(robot.taught_goals()) == proto.MAX_GOALS
        assert all(server_emulator.goal_at(i) is not None for i in range(proto.MAX_GOALS))
        with pytest.raises(DeviceError, match="16 goals at most"):
            await robot.teach_goal("p99")
        await robot.teach_goal("p3")  # teaching a known name again reuses its index
        assert server_emulator.requests[-1].goal == 3


def test_goal_locations_differ() -> None:
    # the emulated program keeps goal k in its own console location; goal 0 is `opgoal`
    names = {goal_location(i) for i in range(proto.MAX_GOALS)}
    assert len(names) == proto.MAX_GOALS and goal_location(0) == "opgoal"
    assert "cur" not in names
