"""The C500C emulator in joint space (issue 20, drivers/sim/joint_arm.py): trapezoidal profiles
against their closed form, inverse kinematics behind world moves, `w2`'s JOINTS and PULSES rows
from the joints, rotated and halted moves, and the drivers over real ptys."""

from __future__ import annotations

import asyncio
import math
import subprocess
from collections.abc import AsyncIterator
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from config.settings import RobotSettings
from daemon.arm.kinematics import forward
from daemon.arm.loading import load_arm
from drivers.c500c import protocol as console_proto
from drivers.c500c import server_protocol as proto
from drivers.c500c.robot import C500CRobot
from drivers.c500c.server import C500CServerRobot
from drivers.errors import DeviceReportedError
from drivers.sim.arm_physics import true_arm
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.joint_arm import (
    ESTIMATED_A465_PULSES_PER_DEG,
    JointArm,
    JointArmConfig,
    location_of,
    pose_of,
    shift_location,
    trapezoid,
    wrist_singular,
)
from drivers.sim.server_emulator import C500CServerEmulator, server_emulator_config
from tests.helpers import REPO_ROOT, cli_command, run_cli

A465 = load_arm("crs-a465")
ARM = JointArmConfig(A465, speed_deg_s=60.0, acceleration_deg_s2=240.0)


# --- the profile: closed form ----------------------------------------------------------------


def test_trapezoid_reaches_the_speed_limit_on_a_long_move() -> None:
    q0, q1 = np.zeros(3), np.array([1.0, -0.5, 0.25])  # rad
    v, a = 0.5, 2.0  # rad/s, rad/s^2: the ramp covers v^2/a = 0.125 rad < 1 rad
    motion = trapezoid(q0, q1, 10.0, v, a)
    assert motion.ramp_s == pytest.approx(v / a)
    assert motion.duration_s == pytest.approx(1.0 / v + v / a)  # D/v + v/a
    mid = 10.0 + motion.duration_s / 2
    q, qd, qdd = motion.sample(mid)
    assert q == pytest.approx(q0 + (q1 - q0) / 2)  # symmetric profile
    assert qd == pytest.approx(v * (q1 - q0))  # the farthest joint at the limit, others in step
    assert qdd == pytest.approx(np.zeros(3))
    q, qd, qdd = motion.sample(10.0 + 0.1)  # accelerating: 1/2 a t^2
    assert q[0] == pytest.approx(0.5 * a * 0.01) and qd[0] == pytest.approx(a * 0.1)
    assert qdd == pytest.approx(a * (q1 - q0))
    q, qd, qdd = motion.sample(motion.end_s - 0.1)  # decelerating, mirrored
    assert q[0] == pytest.approx(1.0 - 0.5 * a * 0.01) and qdd[0] == pytest.approx(-a)
    q, qd, _ = motion.sample(motion.end_s + 1.0)
    assert q == pytest.approx(q1) and qd == pytest.approx(np.zeros(3))
    q, qd, _ = motion.sample(9.0)  # before the start: at rest where it began
    assert q == pytest.approx(q0) and qd == pytest.approx(np.zeros(3))


def test_trapezoid_is_a_triangle_on_a_short_move_and_speed_is_the_derivative() -> None:
    q0, q1 = np.array([0.2, 0.1]), np.array([0.2 + 1e-4, 0.1 - 5e-5])
    a = 4.0
    motion = trapezoid(q0, q1, 0.0, 1.0, a)
    assert motion.duration_s == pytest.approx(2.0 * math.sqrt(1e-4 / a))  # 2 sqrt(D/a)
    times = np.linspace(0.0, motion.duration_s, 401)
    positions = np.array([motion.sample(t)[0] for t in times])
    speeds = np.array([motion.sample(t)[1] for t in times])
    numeric = np.gradient(positions[:, 0], times)
    assert np.max(np.abs(numeric[2:-2] - speeds[2:-2, 0])) < 0.01 * np.max(speeds[:, 0])
    assert np.max(np.abs(speeds[:, 0])) == pytest.approx(math.sqrt(1e-4 * a), rel=1e-3)


def test_a_move_is_inverse_kinematics_and_pulses_are_degrees_times_resolution() -> None:
    arm = JointArm(ARM)
    q_target = np.radians([10.0, 25.0, 70.0, 5.0, 20.0, -10.0])
    target = location_of(forward(A465, q_target))
    end_s = arm.move_to(target, 1.0, np.zeros(3))
    assert arm.joints_at(end_s) == pytest.approx(q_target, abs=1e-7)
    assert arm.location_at(end_s) == pytest.approx(target, abs=1e-6)
    assert arm.pulses(q_target) == tuple(
        round(d * ESTIMATED_A465_PULSES_PER_DEG) for d in np.degrees(q_target)
    )
    # the farthest joint (elbow, 10 deg) sets the time; 10 deg < v^2/a = 15 deg, so the
    # profile is a triangle: 2 sqrt(D/a), peak speed sqrt(D a) at half time
    assert end_s - 1.0 == pytest.approx(2.0 * math.sqrt(10.0 / 240.0))
    sample = arm.sample((1.0 + end_s) / 2)
    assert np.max(np.abs(sample.qd_rad_s)) == pytest.approx(math.radians(math.sqrt(2400.0)))


def test_wshift_turns_in_the_world_frame_about_the_location() -> None:
    location = (400.0, 50.0, 300.0, 20.0, 80.0, -30.0)
    shifted = shift_location(location, (1.0, -2.0, 0.5, 0.3, -0.2, 0.1))
    expected = Rotation.from_euler("ZYX", [0.3, -0.2, 0.1], degrees=True).as_matrix()
    expected = expected @ pose_of(location)[:3, :3]
    assert pose_of(shifted)[:3, :3] == pytest.approx(expected, abs=1e-12)
    assert shifted[:3] == pytest.approx((401.0, 48.0, 300.5))


# The duty cycle's camera station (config/duty/a465-pick-and-place.toml): the tool straight
# down (y-rot 90 deg, z-y-x gimbal lock) at the A465's wrist singularity (joint 5 = 0, joints 4
# and 6 aligned), and its place station, away from it.
CAMERA_DEG = (0.0, 35.0, 55.0, 0.0, 0.0, 0.0)
PLACE_DEG = (60.0, 50.0, 30.0, 0.0, 10.0, 30.0)


def test_the_camera_station_is_wrist_singular_and_the_place_station_is_not() -> None:
    assert wrist_singular(A465, np.radians(CAMERA_DEG))
    assert not wrist_singular(A465, np.radians(PLACE_DEG))


def test_a_small_shift_at_the_wrist_singularity_moves_the_tool_by_the_shift() -> None:
    """A thermal correction (tens of um, tens of urad, angles in the console's 0.001 degree
    steps) at the camera station: the exact solution of the shifted location swings joints 4
    and 6 by ~27 degrees in opposite senses, which moves a real arm's tool (other DH values
    than the controller's) by tens of um. Kept joint 4: every joint moves by the small step
    the shift needs, the nominal tool by the shift, and a perturbed arm's tool within 1 um of
    it (the joint step, ~1e-4 rad, times its DH error, 0.2 mm: ~0.02 um)."""
    arm = JointArm(replace(ARM, start_joints_deg=CAMERA_DEG))
    q0 = arm.joints_at(0.0)
    translation = np.array([0.020, -0.030, 0.025])  # mm
    rotation_deg = (0.002, -0.003, 0.003)  # z, y, x: ~50 urad
    shifted = shift_location(location_of(forward(A465, q0)), (*translation, *rotation_deg))
    q1 = arm.solve(shifted, q0)
    assert np.max(np.abs(np.degrees(q1 - q0))) < 0.02  # no wrist swing
    assert q1[3] == q0[3]
    nominal = forward(A465, q1)[:3, 3] - forward(A465, q0)[:3, 3]
    assert nominal == pytest.approx(translation, abs=1e-4)
    truth = true_arm(A465, np.random.default_rng(1), 0.2, 2e-4, np.ones(A465.dof))
    moved = forward(truth, q1)[:3, 3] - forward(truth, q0)[:3, 3]
    assert moved == pytest.approx(translation, abs=1e-3)
    # the orientation is met in the directions the wrist reaches; about world z (joint 1's
    # axis, which the singular wrist cannot turn about) the tool turns with joint 1 alone
    missed = Rotation.from_matrix(forward(A465, q1)[:3, :3] @ pose_of(shifted)[:3, :3].T)
    expected_z = (q1[0] - q0[0]) - math.radians(rotation_deg[0])
    assert missed.as_rotvec() == pytest.approx([0.0, 0.0, expected_z], abs=1e-7)


def test_arriving_at_the_wrist_singularity_keeps_joint_4_and_leaving_it_is_exact() -> None:
    """From the place station to the camera station's location the exact solution lands with
    joints 4 and 6 at -21.6 / +21.6 degrees (the seed's path decides): the tool's true pose
    then depends on where. Kept joint 4: the taught joints exactly. Back to the place station
    (a real reorientation) the locked wrist cannot reach it and the exact solution is used."""
    arm = JointArm(replace(ARM, start_joints_deg=PLACE_DEG))
    q_place, q_camera = np.radians(PLACE_DEG), np.radians(CAMERA_DEG)
    q = arm.solve(location_of(forward(A465, q_camera)), q_place)
    assert q == pytest.approx(q_camera, abs=1e-7)
    back = arm.solve(location_of(forward(A465, q_place)), q)
    assert back == pytest.approx(q_place, abs=1e-7)


# --- the console emulator with an arm, over a real pty ---------------------------------------

#: Reply bounds of the console link: hang bounds (2 s was exceeded by a position read at load
#: 19 with the suite on both cores), the replies' content is what is checked.
CONSOLE = RobotSettings(command_timeout_s=10.0, move_timeout_s=20.0, reconnect_max_backoff_s=0.2)


@pytest.fixture
async def arm_emulator() -> AsyncIterator[C500CEmulator]:
    config = EmulatorConfig(paced=False, noise_um=0.0, joint_arm=ARM)
    async with C500CEmulator(config) as emu:
        yield emu


async def test_console_moves_the_arm_in_joint_space(arm_emulator: C500CEmulator) -> None:
    emulator = arm_emulator
    loop = asyncio.get_running_loop()
    async with C500CRobot(CONSOLE, port=emulator.device_path) as robot:
        goal = await robot.teach_goal()
        start_q = emulator.joint_sample(loop.time()).q_rad
        assert start_q == pytest.approx(np.radians(ARM.start_joints_deg))
        assert goal.position == pytest.approx(forward(A465, start_q)[:3, 3], abs=5e-4)
        before = loop.time()
        result = await robot.move_absolute((1.0, -0.5, 0.25), (0.0, 0.0, math.radians(0.5)))
        after = emulator.joint_sample(loop.time())
        # the joints reached are those of the shifted, turned goal (IK), as the read-back says
        expected = shift_location(
            (goal.x, goal.y, goal.z, goal.z_rot, goal.y_rot, goal.x_rot),
            (1.0, -0.5, 0.25, 0.5, 0.0, 0.0),
        )
        assert location_of(forward(A465, after.q_rad)) == pytest.approx(expected, abs=2e-3)
        assert result.actual.position == pytest.approx(expected[:3], abs=5e-4)
        assert after.qd_rad_s == pytest.approx(np.zeros(6))  # finished: at rest
        # 10 ms before the motion ended the joints were still on their way, decelerating
        assert emulator.console.joint_arm is not None
        end_s = emulator.console.joint_arm.end_s()
        assert before < end_s <= loop.time()
        braking = emulator.joint_sample(end_s - 0.01)
        assert np.max(np.abs(braking.qd_rad_s)) > 0
        assert np.all(braking.qdd_rad_s2 * braking.qd_rad_s <= 0)
        table = console_proto.parse_position_table(await robot.read_position_lines())
        q_now = emulator.joint_sample(loop.time()).q_rad
        assert table.joints == pytest.approx(np.degrees(q_now), abs=5e-4)  # %+10.3f
        assert table.pulses == tuple(
            round(d * ESTIMATED_A465_PULSES_PER_DEG) for d in np.degrees(q_now)
        )
        with pytest.raises(DeviceReportedError) as caught:
            # beyond the A465's reach (~0.7 m from its shoulder) yet inside the driver's own
            # 1 m bound on an offset, so the controller is the one that refuses it
            await robot.move_absolute((950.0, 0.0, 0.0))
        assert caught.value.code == 3


async def test_without_an_arm_the_table_is_as_before() -> None:
    async with C500CEmulator(EmulatorConfig(paced=False, noise_um=0.0)) as emulator:
        with pytest.raises(RuntimeError, match="no arm"):
            emulator.joint_sample(0.0)
        lines = await emulator.console.execute("w2")
        table = console_proto.parse_position_table(lines)
        assert table.joints == (0.0,) * 6 and table.pulses == (0,) * 6


# --- the fast path with an arm: a hold halts the joints where they are -----------------------

SERVER = RobotSettings(
    driver="c500c-server",
    command_timeout_s=2.0,
    move_timeout_s=30.0,
    heartbeat_s=0.25,
    server_silence_s=4.0,
)


async def test_fast_path_hold_stops_the_joints_mid_motion() -> None:
    slow = replace(ARM, speed_deg_s=2.0, acceleration_deg_s2=4.0)  # a move of seconds
    config = server_emulator_config(paced=False, noise_um=0.0, silence_timeout_s=4.0)
    config = replace(config, console=replace(config.console, joint_arm=slow))
    loop = asyncio.get_running_loop()
    async with (
        C500CServerEmulator(config) as emulator,
        C500CServerRobot(SERVER, port=emulator.device_path) as robot,
    ):
        goal = await robot.teach_goal()
        move = asyncio.create_task(robot.move_absolute((20.0, 0.0, 0.0)))
        await asyncio.wait_for(emulator.motion_started.wait(), 10.0)
        await robot.stop()
        with pytest.raises(DeviceReportedError) as caught:
            await move
        assert caught.value.code == proto.Status.HALTED
        halted = emulator.joint_sample(loop.time())
        assert halted.qd_rad_s == pytest.approx(np.zeros(6))
        stopped_at = location_of(forward(A465, halted.q_rad))
        # stopped on the way: neither at the start nor at the target
        assert 0.0 < stopped_at[0] - goal.x < 20.0
        assert emulator.actual_pose()[:3] == pytest.approx(stopped_at[:3], abs=1e-6)
        later = emulator.joint_sample(loop.time() + 5.0)
        assert later.q_rad == pytest.approx(halted.q_rad)  # and stays there


# --- `thermocomp emulate c500c --arm` ---------------------------------------------------------


def test_emulate_cli_serves_an_arm_in_joint_space() -> None:
    process = subprocess.Popen(
        cli_command("emulate", "c500c", "--arm", "crs-a465", "--no-pacing", "--noise-um", "0"),
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout is not None
        path = process.stdout.readline().strip()

        async def read_table() -> console_proto.PositionTable:
            async with C500CRobot(CONSOLE, port=path) as robot:
                return console_proto.parse_position_table(await robot.read_position_lines())

        table = asyncio.run(read_table())
    finally:
        process.terminate()
        process.wait(timeout=10)
        for stream in (process.stdout, process.stderr):
            if stream:
                stream.close()
    assert process.returncode == 0
    start = np.asarray(ARM.start_joints_deg)
    assert table.joints == pytest.approx(start, abs=5e-4)
    assert table.pulses == tuple(round(d * ESTIMATED_A465_PULSES_PER_DEG) for d in start)
    assert table.world == pytest.approx(location_of(forward(A465, np.radians(start))), abs=5e-4)


def test_emulate_cli_refuses_an_unknown_arm() -> None:
    result = run_cli(["emulate", "c500c", "--arm", "no-such-arm"])
    assert result.returncode == 2 and "--arm" in result.stderr
