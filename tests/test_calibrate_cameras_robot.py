"""`thermocomp calibrate cameras --robot` (issue 20): the arm bench's robot (the C500C emulator
in joint space over a real pty, virtual clock) moves the tool through the pattern, its cameras
render the markers, and the fitted cameras are compared with the bench's truth seen from the
controller's frame; the written file then measures the tool where the controller puts it. Also
the pattern's limits, bad usage (exit 2, one line, nothing opened), a device error and a hold
in the middle of the pattern, and the pure pieces against analytic oracles."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import io
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from config import Settings, load_settings
from daemon.arm.duty import load_duty_cycle
from daemon.arm.loading import load_arm
from daemon.arm.run import MeasuredPose
from daemon.calibration import cameras_robot as calibrate_cameras_robot
from daemon.calibration.camera_pattern import Shift, check_pattern, robot_pattern, split_shift
from daemon.calibration.camera_run import (
    Recording,
    controller_frame_truth,
    find_markers,
    record_pattern,
    station_pose,
)
from daemon.commands import calibrate as calibrate_cli
from daemon.run.arm.measure import marker_views, tool_pose
from daemon.run.arm.robot import GoalRobotArm, pose_matrix
from daemon.vision.cameras import load_cameras, write_cameras
from daemon.vision.markers import render_markers
from daemon.vision.multiview import CameraModel, intrinsic_matrix, look_at, project
from drivers.base import Frame
from drivers.clock import make_clock
from drivers.errors import DeviceError, MotionHeldError
from drivers.factory import open_devices
from drivers.sim.arm_bench import ArmBench
from drivers.sim.arm_devices import bench_config
from tests.helpers import REPO_ROOT, run_in_process

ARM_SIM = REPO_ROOT / "config" / "arm-sim.toml"
#: The initial guess: each camera turned by ~2 mrad and moved by ~3 mm from the truth.
GUESS_ROTATION_RAD = 2e-3
GUESS_TRANSLATION_MM = 3.0


def lab_file(directory: Path, cameras_file: Path | None, **arm: object) -> Path:
    """config/arm-sim.toml with its camera file and a data directory in ``directory``."""
    text = ARM_SIM.read_text(encoding="utf-8").replace(
        'data_dir = "data-arm"', f'data_dir = "{directory / "data"}"'
    )
    lines = [f'cameras_file = "{cameras_file}"'] if cameras_file is not None else []
    lines += [f"{key} = {value}" for key, value in arm.items()]
    text = text.replace("[arm]\n", "[arm]\n" + "".join(f"{line}\n" for line in lines))
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "lab.toml"
    path.write_text(text, encoding="utf-8")
    return path


def bench_cameras(settings: Settings) -> tuple[CameraModel, ...]:
    """The arm bench's true cameras, as drivers/sim/arm_devices.py builds them."""
    assert settings.arm.duty_cycle is not None
    arm = load_arm(settings.arm.arm_file)
    duty = load_duty_cycle(settings.arm.duty_cycle)
    return ArmBench(bench_config(settings, arm, duty, settings.bench.seed), arm=arm).cameras


def perturbed(cameras: Sequence[CameraModel], seed: int = 5) -> list[CameraModel]:
    """Each camera's centre moved by ~GUESS_TRANSLATION_MM and its orientation turned by
    ~GUESS_ROTATION_RAD (random directions, seeded)."""
    rng = np.random.default_rng(seed)
    out = []
    for camera in cameras:
        turn = rng.normal(0.0, GUESS_ROTATION_RAD / math.sqrt(3.0), 3)
        shift = rng.normal(0.0, GUESS_TRANSLATION_MM / math.sqrt(3.0), 3)
        rotation = Rotation.from_rotvec(turn) * Rotation.from_rotvec(np.array(camera.rotation_rad))
        centre = camera.centre_mm + shift
        out.append(camera.with_pose(rotation.as_rotvec(), -rotation.as_matrix() @ centre))
    return out


@dataclass(frozen=True)
class Calibrated:
    status: int
    data: dict[str, Any]
    err: str
    guess: Path
    written: Path
    observations: Path
    lab: Path
    truth: tuple[CameraModel, ...]


def run_command(argv: list[str]) -> tuple[int, str, str]:
    """The command in process (stdout and stderr captured: a module-scoped fixture has no
    capsys)."""
    parser = argparse.ArgumentParser(prog="thermocomp")
    calibrate_cli.register(parser.add_subparsers(dest="command", required=True))
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        args = parser.parse_args(["calibrate", "cameras", *argv])
        status = int(args.handler(args))
    return status, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> Calibrated:
    """One calibration at the duty cycle's "place" station from a perturbed camera file."""
    directory = tmp_path_factory.mktemp("camcal")
    truth = bench_cameras(load_settings(ARM_SIM))
    guess = directory / "guess.toml"
    write_cameras(guess, perturbed(truth))
    lab = lab_file(directory, guess)
    written, observations = directory / "cameras.toml", directory / "moves.csv"
    status, out, err = run_command(
        [
            "--robot",
            "--config",
            str(lab),
            "--station",
            "place",
            "--write",
            str(written),
            "--save-observations",
            str(observations),
            "--json",
        ]
    )
    data = json.loads(out) if status == 0 else {}
    return Calibrated(status, data, err, guess, written, observations, lab, truth)


@pytest.mark.slow
def test_the_robot_recovers_the_station_cameras_from_a_perturbed_file(
    calibrated: Calibrated,
) -> None:
    assert calibrated.status == 0, calibrated.err
    data = calibrated.data
    assert data["goal"] == "place" and data["poses"] == 27 and data["returned_to_goal"]
    fitted = {c["camera"]: c for c in data["cameras"]}
    assert sorted(fitted) == ["s1-arm-0", "s1-arm-1", "s1-arm-2"]  # the place station's
    guesses = {c.name: c for c in load_cameras(calibrated.guess)}
    truths = {c.name: c for c in calibrated.truth}
    kinematic = data["bench_kinematic_error"]
    for name, camera in fitted.items():
        assert camera["points"] == 27 * 4  # every marker at every pose
        error = np.array(camera["centre_error_mm"])  # from the truth in the controller's frame
        se = np.array(camera["centre_se_mm"])
        assert np.linalg.norm(error) < 0.06, (name, error)  # a few tens of um
        assert np.all(np.abs(error) < 4.0 * se + 0.005), (name, error, se)
        assert camera["reduced_chi2"] < 2.0
        # the guess was millimetres off; the raw truth differs by the arm's kinematic error
        assert np.linalg.norm(guesses[name].centre_mm - truths[name].centre_mm) > 1.0
    assert 0.1 < kinematic["translation_mm"] < 3.0
    # the other station's cameras saw nothing: named, kept from the guess
    assert sorted(n["camera"] for n in data["not_fitted"]) == ["s0-arm-0", "s0-arm-1", "s0-arm-2"]
    assert all(n["reason"] == "saw no marker at any pose" for n in data["not_fitted"])
    written = load_cameras(calibrated.written)
    assert [c.name for c in written] == [c.name for c in calibrated.truth]  # the devices' order
    for camera in written:
        if camera.name in fitted:
            assert np.allclose(camera.centre_mm, fitted[camera.name]["centre_mm"], atol=1e-6)
        else:
            assert np.allclose(camera.centre_mm, guesses[camera.name].centre_mm, atol=1e-6)


@pytest.mark.slow
def test_the_saved_observations_give_the_same_fit(
    calibrated: Calibrated, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert calibrated.status == 0, calibrated.err
    station = tmp_path / "station.toml"
    write_cameras(station, [c for c in load_cameras(calibrated.guess) if c.name.startswith("s1")])
    status, out, err = run_in_process(
        calibrate_cli.register,
        [
            "calibrate",
            "cameras",
            "--cameras",
            str(station),
            "--observations",
            str(calibrated.observations),
            "--json",
        ],
        capsys,
    )
    assert status == 0, err
    again = {c["camera"]: c["centre_mm"] for c in json.loads(out)["cameras"]}
    for camera in calibrated.data["cameras"]:
        assert np.allclose(again[camera["camera"]], camera["centre_mm"], atol=1e-4)


@pytest.mark.slow
async def test_the_written_file_measures_the_tool_where_the_controller_puts_it(
    calibrated: Calibrated,
) -> None:
    """An arm run's measurement (daemon/run/arm/measure.py) at the station with the written file
    and with the guess: the tool's position from the calibrated cameras is the controller's
    read-back within tens of um (the cameras are in its frame), the guess's is millimetres off."""
    assert calibrated.status == 0, calibrated.err
    settings = load_settings(calibrated.lab)
    markers = np.array(settings.arm.markers_mm)
    files = {"written": load_cameras(calibrated.written), "guess": load_cameras(calibrated.guess)}
    async with open_devices(settings, make_clock("virtual")) as devices:
        await GoalRobotArm(devices.robot).teach_pose(  # type: ignore[arg-type]
            MeasuredPose(*station_pose(settings, "place"))
        )
        believed = pose_matrix(await devices.robot.actual_pose())
        frames = await asyncio.gather(*(camera.grab() for camera in devices.cameras))
    errors = {}
    for label, models in files.items():
        views = marker_views(models, frames, markers @ believed[:3, :3].T + believed[:3, 3])
        measured = tool_pose(models, views, markers, believed)
        assert measured.oriented
        errors[label] = float(np.linalg.norm(measured.pose[:3, 3] - believed[:3, 3]))
    assert errors["written"] < 0.05, errors
    assert errors["guess"] > 0.5, errors


@pytest.mark.slow
def test_a_station_at_the_wrist_singularity_is_refused_and_nothing_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The preset's camera station points the tool down with joint 5 at 0: the controller
    swings joints 4 and 6 for every small move and the true (non-spherical) wrist carries the
    markers elsewhere than the read-back says: the fits are refused, each camera named."""
    guess = tmp_path / "guess.toml"
    write_cameras(guess, perturbed(bench_cameras(load_settings(ARM_SIM))))
    written = tmp_path / "cameras.toml"
    status, out, err = run_in_process(
        calibrate_cli.register,
        [
            "calibrate",
            "cameras",
            "--robot",
            "--config",
            str(lab_file(tmp_path, guess)),
            "--station",
            "camera",
            "--per-axis",
            "2",
            "--write",
            str(written),
        ],
        capsys,
    )
    assert status == 1 and out == "" and not written.exists()
    line = err.strip().splitlines()[-1]
    assert line.startswith("thermocomp calibrate cameras: no camera calibrated from 8 poses")
    assert "s1-arm-0 saw no marker at any pose" in line
    for name in ("s0-arm-0", "s0-arm-1", "s0-arm-2"):
        assert f"{name} its fit leaves" in line


@pytest.mark.slow
def test_the_camera_stations_cameras_from_a_goal_off_the_wrist_singularity(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The same station with the wrist bent by 10 degrees (joint 5): the tool's markers are
    still in its cameras' views, the joints move smoothly, the cameras are recovered."""
    truth = bench_cameras(load_settings(ARM_SIM))
    guess = tmp_path / "guess.toml"
    write_cameras(guess, perturbed(truth, seed=6))
    status, out, err = run_in_process(
        calibrate_cli.register,
        [
            "calibrate",
            "cameras",
            "--robot",
            "--config",
            str(lab_file(tmp_path, None)),
            "--cameras",
            str(guess),
            "--joints",
            "0,35,55,0,10,0",
            "--per-axis",
            "2",
            "--json",
        ],
        capsys,
    )
    assert status == 0, err
    data = json.loads(out)
    assert data["goal"] == "camcal" and data["poses"] == 8 and data["returned_to_goal"]
    fitted = {c["camera"]: c for c in data["cameras"]}
    assert sorted(fitted) == ["s0-arm-0", "s0-arm-1", "s0-arm-2"]
    for name, camera in fitted.items():
        error = np.array(camera["centre_error_mm"])
        assert np.linalg.norm(error) < 0.1, (name, error)  # 8 poses: a few tens of um
        assert np.all(np.abs(error) < 4.0 * np.array(camera["centre_se_mm"]) + 0.005)
        assert camera["reduced_chi2"] < 2.0


# --- bad usage: exit 2, one line, nothing opened ---------------------------------------------


@pytest.fixture
def no_devices(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*_: object, **__: object) -> None:
        raise AssertionError("the devices were opened")

    monkeypatch.setattr(calibrate_cameras_robot, "calibrate_with_robot", refuse)


@pytest.mark.usefixtures("no_devices")
@pytest.mark.parametrize(
    ("extra", "arm", "message"),
    [
        (
            ["--size", "1.5"],
            {},
            "the pattern reaches 2.598 mm from the goal, beyond arm.max_translation_mm = 2 mm",
        ),
        (
            ["--size", "3", "--here"],
            {"calibration_max_translation_mm": 4.0},
            "beyond arm.calibration_max_translation_mm = 4 mm",
        ),
        (["--fit-marker", "--turn", "0.01"], {}, "the pattern turns the tool by"),
        (["--fit-marker", "--turn", "0"], {}, "--fit-marker needs the tool to turn"),
        (["--station", "nowhere"], {}, "--station 'nowhere': not a pose of the duty cycle"),
        (["--per-axis", "1"], {}, "--per-axis must be 2 or more"),
        (["--joints", "0,35,55"], {}, "--joints: 3 angles for the 6 joints of"),
        (["--joints", "0,35,55,0,10,400"], {}, "--joints: joint 6 at 400 deg is beyond"),
    ],
)
def test_bad_patterns_are_refused_before_anything_opens(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    arm: dict[str, object],
    message: str,
) -> None:
    guess = tmp_path / "guess.toml"
    write_cameras(guess, [camera()])
    lab = lab_file(tmp_path, guess, **arm)
    status, out, err = run_in_process(
        calibrate_cli.register,
        ["calibrate", "cameras", "--robot", "--config", str(lab), *extra],
        capsys,
    )
    assert (status, out) == (2, "")
    assert err.count("\n") == 1 and message in err, err


@pytest.mark.usefixtures("no_devices")
def test_no_arm_and_no_camera_file_are_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plain = tmp_path / "plain.toml"
    plain.write_text('[bench]\nclock = "virtual"\n', encoding="utf-8")
    cases = [
        (["--config", str(plain)], "--robot needs the [arm] section with enabled = true"),
        (["--config", str(lab_file(tmp_path / "a", None))], "no camera file: give --cameras FILE"),
        (
            ["--config", str(lab_file(tmp_path / "b", tmp_path / "missing.toml"))],
            "missing.toml",
        ),
        (["--station", "place"], "--station goes with --robot"),
    ]
    for argv, message in cases:
        robot = ["--robot"] if "--station" not in argv else ["--observations", "x.csv"]
        status, out, err = run_in_process(
            calibrate_cli.register, ["calibrate", "cameras", *robot, *argv], capsys
        )
        assert (status, out) == (2, ""), (argv, err)
        assert err.count("\n") == 1 and message in err, (argv, err)


# --- device error and hold in the middle of the pattern -----------------------------------------


class DarkCamera:
    """A camera of small dark frames that fails (or holds the robot) at its ``at``-th grab."""

    def __init__(self, at: int | None = None, hold: Any = None) -> None:
        self.grabs = 0
        self.at = at
        self.hold = hold

    async def __aenter__(self) -> DarkCamera:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def grab(self) -> Frame:
        self.grabs += 1
        if self.at is not None and self.grabs == self.at:
            if self.hold is None:
                raise DeviceError("camera", "cable pulled")
            self.hold()  # an operator's hold arrives while the frame is taken
        return Frame(np.zeros((32, 32), dtype=np.uint16), 12, 0.0, self.grabs)


def camera() -> CameraModel:
    rvec, tvec = look_at((0.0, -700.0, 400.0), (0.0, 0.0, 400.0))
    return CameraModel(
        name="c0",
        matrix=intrinsic_matrix((4640.0, 4640.0), (1223.5, 1023.5)),
        distortion=np.zeros(5),
        rotation_rad=rvec,
        translation_mm=tvec,
        image_size_px=(2448, 2048),
        pixel_sigma_px=0.05,
    )


async def test_a_device_error_stops_the_pattern_and_returns_to_the_goal() -> None:
    settings = load_settings(ARM_SIM)
    shifts = robot_pattern(0.8, 2, 0.0, 0)
    async with open_devices(settings, make_clock("virtual")) as devices:
        robot: Any = devices.robot
        goal = await robot.teach_goal()
        record = Recording("opgoal")
        with pytest.raises(DeviceError, match="cable pulled"):
            await record_pattern(
                robot,
                [DarkCamera(at=3)],
                [camera()],
                np.zeros((1, 3)),
                shifts,
                goal="opgoal",
                max_step_mm=0.5,
                max_step_rad=1e-3,
                grab_timeout_s=1.0,
                recording=record,
            )
        back = await robot.actual_pose()
    assert record.poses == 2 and record.returned
    assert math.dist(back.position, goal.position) < 0.01  # at the goal (repeatability)


async def test_no_move_after_a_hold_reaches_the_controller() -> None:
    settings = load_settings(ARM_SIM)
    shifts = robot_pattern(0.8, 2, 0.0, 0)
    async with open_devices(settings, make_clock("virtual")) as devices:
        robot: Any = devices.robot
        emulator = devices.emulator
        assert emulator is not None
        await robot.teach_goal()
        sent_at_hold: list[int] = []

        def hold() -> None:
            robot.stop().close()  # the hold is set when stop() is called (drivers/c500c/robot.py)
            sent_at_hold.append(len(emulator.state.motion_commands()))

        record = Recording("opgoal")
        with pytest.raises(MotionHeldError):
            await record_pattern(
                robot,
                [DarkCamera(at=2, hold=hold)],
                [camera()],
                np.zeros((1, 3)),
                shifts,
                goal="opgoal",
                max_step_mm=0.5,
                max_step_rad=1e-3,
                grab_timeout_s=1.0,
                recording=record,
            )
        sent = len(emulator.state.motion_commands())
    assert sent_at_hold and sent == sent_at_hold[0]  # not one motion after the hold
    assert record.poses == 2 and not record.returned  # the return was refused too


# --- pure pieces ------------------------------------------------------------------------------


def test_the_pattern_is_a_cube_within_the_limits_and_its_moves_are_split() -> None:
    settings = Settings.model_validate({"arm": {"enabled": True}})
    shifts = robot_pattern(1.0, 3, 0.001, 7)
    assert len(shifts) == 27
    check_pattern(settings, shifts)  # 1.73 mm and 0.1 deg at most, within 2 mm and 0.2 deg
    corners = [s.translation_mm for s in shifts if all(abs(v) == 1.0 for v in s.translation_mm)]
    assert len(corners) == 8
    assert all(max(abs(v) for v in s.rotation_rad) <= 0.001 for s in shifts)
    start = Shift((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    steps = split_shift(start, shifts[0], 0.3, 2e-4)
    assert steps[-1] == shifts[0]
    for a, b in zip([start, *steps], steps, strict=False):
        assert (
            max(abs(x - y) for x, y in zip(a.translation_mm, b.translation_mm, strict=True))
            <= 0.3 + 1e-12
        )
        turn = Rotation.from_rotvec(b.rotation_rad) * Rotation.from_rotvec(a.rotation_rad).inv()
        assert turn.magnitude() <= 2e-4 * (1 + 1e-4)


def test_markers_are_found_where_the_guess_is_tens_of_pixels_off() -> None:
    truth = camera()
    rvec, tvec = look_at((0.0, -700.0, 400.0), (4.0, 0.0, 403.0))  # 3-4 mm aside
    guess = truth.with_pose(rvec, tvec)
    points = np.array([[0.0, 0.0, 400.0], [60.0, 0.0, 400.0], [0.0, 0.0, 2000.0]])
    pixels = project(truth, points[:2])
    assert np.max(np.abs(project(guess, points[:2]) - pixels)) > 10.0  # the guess is off
    image = render_markers(
        truth, points[:2], rng=np.random.default_rng(1), sigma_px=2.0, bit_depth=12
    )
    frame = Frame(np.asarray(image), 12, 0.0, 0)
    found = find_markers([guess], [frame], points)
    assert [f.marker for f in found] == [0, 1]  # the third is behind... far off the chip
    for f in found:
        assert math.dist((f.x_px, f.y_px), pixels[f.marker]) < 0.05
        assert min(f.sigma_px) >= truth.pixel_sigma_px


def test_the_truth_in_the_controllers_frame_projects_what_the_truth_sees() -> None:
    truth = camera()
    believed = np.eye(4)
    believed[:3, 3] = (10.0, -5.0, 400.0)
    error = np.eye(4)
    error[:3, :3] = Rotation.from_rotvec([2e-3, -1e-3, 5e-4]).as_matrix()
    error[:3, 3] = (0.4, -0.2, 0.3)
    true_tool = error @ believed
    (seen,), (moved_mm, turned_mrad) = controller_frame_truth([truth], true_tool, believed)
    points = np.array([[0.0, 0.0, 400.0], [30.0, 20.0, 420.0], [-40.0, 10.0, 380.0]])
    truly = points @ error[:3, :3].T + error[:3, 3]
    assert np.allclose(project(seen, points), project(truth, truly), atol=1e-9)
    assert math.isclose(moved_mm, math.sqrt(0.4**2 + 0.2**2 + 0.3**2))
    assert math.isclose(turned_mrad, 1000 * math.sqrt(4e-6 + 1e-6 + 0.25e-6), rel_tol=1e-9)
