"""`thermocomp calibrate cameras --robot` on a UR (issue 31; daemon/calibration/cameras_ur.py,
camera_run_ur.py). Real parts: the UR emulator over real TCP (real clock: the emulated
controller runs its 500 Hz cycle), the real UR driver, the bench's tool cameras rendering the
emulator's true tool. The robot plays its own program; the PC writes the pattern as offsets and
records them at the program's measured poses.

- From a camera file perturbed by ~3 mm and ~2 mrad, every camera of both stations is
  recovered (the truth as the controller's frame sees it) within tens of um and its sigmas;
  the saved observations fit again to the same cameras.
- Every frame is grabbed while the program dwells at a measured pose with the pattern's offset
  applied (read in the emulated controller at the grab, not over RTDE).
- A hold during the pattern: the pattern stops, the program's offset freezes where it was and
  no correction register is written after the hold.
- A program that does not dwell at a measured pose: the pattern stops with one message.
- A program that reports an offset it does not apply (the TCP does not follow): stopped.
- Bad usage: exit 2, one line, nothing opened.
"""

from __future__ import annotations

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

from config import CONFIG_DIR, Settings, load_settings
from daemon.arm.duty import load_duty_cycle
from daemon.calibration import cameras_ur
from daemon.calibration.camera_pattern import Shift, robot_pattern
from daemon.calibration.camera_run_ur import (
    CalibrationStopped,
    URRecording,
    record_ur_pattern,
    stations_of,
)
from daemon.commands import calibrate as calibrate_cli
from daemon.vision.cameras import load_cameras, write_cameras
from daemon.vision.multiview import CameraModel
from drivers.base import Frame
from drivers.clock import make_clock
from drivers.errors import MotionHeldError
from drivers.factory import open_devices
from drivers.sim.arm_markers import CameraRig
from drivers.sim.ur.cameras import SimURCamera
from drivers.sim.ur.controller import URController, URControllerConfig
from tests.helpers import run_in_process
from tests.loopback import loopback_host

UR5E = CONFIG_DIR / "ur5e-sim.toml"
#: The camera-calibration program: the pick-and-place program's measured poses, 12 s dwells.
CALIBRATION_PROGRAM = "ur5e-camera-calibration"
GUESS_ROTATION_RAD = 2e-3
GUESS_TRANSLATION_MM = 3.0


def lab_file(directory: Path, host: str, cameras_file: Path | None, duty: str) -> Path:
    """config/ur5e-sim.toml on ``host`` with the program ``duty``, a camera file and a data
    directory in ``directory``; a loaded machine's render within the grab timeout."""
    text = UR5E.read_text(encoding="utf-8")
    text = text.replace('host = "127.0.0.1"', f'host = "{host}"')
    text = text.replace('data_dir = "data-ur"', f'data_dir = "{directory / "data"}"')
    text = text.replace('duty_cycle = "ur5e-pick-and-place"', f'duty_cycle = "{duty}"')
    if cameras_file is not None:
        text = text.replace("[arm]\n", f'[arm]\ncameras_file = "{cameras_file}"\n')
    text = text.replace("[robot]\n", "[robot]\nur_timeout_s = 10.0\n")
    text += "\n[camera]\ngrab_timeout_s = 10.0\n"
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "lab.toml"
    path.write_text(text, encoding="utf-8")
    return path


def bench_cameras(settings: Settings) -> tuple[CameraModel, ...]:
    """The UR bench's true cameras, as its emulated controller stands them."""
    controller = URController(
        URControllerConfig(
            duty=settings.arm.duty_cycle or CALIBRATION_PROGRAM,
            seed=settings.bench.seed,
            camera_rig=CameraRig(count=settings.arm.cameras),
            markers_tool_mm=settings.arm.markers_mm,
            autoplay=False,
        )
    )
    return controller.bench.cameras


def perturbed(cameras: Sequence[CameraModel], seed: int = 5) -> list[CameraModel]:
    """Each camera moved by ~3 mm and turned by ~2 mrad (a lab's starting guess)."""
    rng = np.random.default_rng(seed)
    out = []
    for camera in cameras:
        turn = rng.normal(0.0, GUESS_ROTATION_RAD / math.sqrt(3.0), 3)
        shift = rng.normal(0.0, GUESS_TRANSLATION_MM / math.sqrt(3.0), 3)
        rotation = Rotation.from_rotvec(turn) * Rotation.from_rotvec(np.array(camera.rotation_rad))
        centre = camera.centre_mm + shift
        out.append(camera.with_pose(rotation.as_rotvec(), -rotation.as_matrix() @ centre))
    return out


def run_command(argv: list[str]) -> tuple[int, str, str]:
    """The command in process (a module-scoped fixture has no capsys)."""
    import argparse

    parser = argparse.ArgumentParser(prog="thermocomp")
    calibrate_cli.register(parser.add_subparsers(dest="command", required=True))
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        args = parser.parse_args(["calibrate", "cameras", *argv])
        status = int(args.handler(args))
    return status, out.getvalue(), err.getvalue()


@dataclass(frozen=True)
class Calibrated:
    status: int
    data: dict[str, Any]
    err: str
    guess: Path
    written: Path
    observations: Path
    truth: tuple[CameraModel, ...]
    #: at each grab: the program's at-pose output, its applied offset (m) and its target (m)
    grabs: list[tuple[int, tuple[float, ...], tuple[float, ...]]]


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> Calibrated:
    """One calibration of both stations (2 x 2 x 2 offsets of +-0.25 mm) from a perturbed file,
    with every grab logged in the emulated controller."""
    directory = tmp_path_factory.mktemp("urcamcal")
    host = loopback_host()
    settings = load_settings(lab_file(directory, host, None, CALIBRATION_PROGRAM))
    truth = bench_cameras(settings)
    guess = directory / "guess.toml"
    write_cameras(guess, perturbed(truth))
    lab = lab_file(directory, host, guess, CALIBRATION_PROGRAM)
    written, observations = directory / "cameras.toml", directory / "moves.csv"
    grabs: list[tuple[int, tuple[float, ...], tuple[float, ...]]] = []
    original = SimURCamera.grab

    async def logged(camera: SimURCamera) -> Frame:
        controller = camera._controller  # the emulated controller, read at the grab
        regs = controller.registers
        target = tuple(float(controller.inputs[n]) for n in regs.target)  # type: ignore[arg-type]
        at_pose = controller.outputs[regs.at_pose]
        assert isinstance(at_pose, int)
        grabs.append((at_pose, controller.program.applied, target))
        return await original(camera)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(SimURCamera, "grab", logged)
        status, out, err = run_command(
            [
                "--robot",
                "--config",
                str(lab),
                "--per-axis",
                "2",
                "--size",
                "0.25",
                "--write",
                str(written),
                "--save-observations",
                str(observations),
                "--json",
            ]
        )
    data = json.loads(out) if status == 0 else {}
    return Calibrated(status, data, err, guess, written, observations, truth, grabs)


@pytest.mark.slow
def test_the_program_s_dwells_recover_every_camera_from_a_perturbed_file(
    calibrated: Calibrated,
) -> None:
    assert calibrated.status == 0, calibrated.err
    data = calibrated.data
    assert data["goal"] == "camera, place" and data["poses"] == 16 and data["returned_to_goal"]
    assert data["offsets"] == 8 and data["not_fitted"] == []
    guesses = {c.name: c for c in load_cameras(calibrated.guess)}
    truths = {c.name: c for c in calibrated.truth}
    fitted = {c["camera"]: c for c in data["cameras"]}
    assert sorted(fitted) == sorted(truths)
    for name, camera in fitted.items():
        assert camera["points"] >= 8 * 3, name  # at least 3 markers at each of 8 offsets
        error = np.array(camera["centre_error_mm"])  # from the truth in the controller's frame
        se = np.array(camera["centre_se_mm"])
        assert np.linalg.norm(error) < 0.1, (name, error)
        assert np.all(np.abs(error) < 4.0 * se + 0.005), (name, error, se)
        assert camera["reduced_chi2"] < 2.0, name
        assert np.linalg.norm(guesses[name].centre_mm - truths[name].centre_mm) > 1.0
    assert 0.1 < data["bench_kinematic_error"]["translation_mm"] < 3.0
    written = load_cameras(calibrated.written)
    assert [c.name for c in written] == [c.name for c in calibrated.truth]
    for camera in written:
        assert np.allclose(camera.centre_mm, fitted[camera.name]["centre_mm"], atol=1e-6)


@pytest.mark.slow
def test_every_frame_is_grabbed_at_a_dwell_with_the_offset_applied(
    calibrated: Calibrated,
) -> None:
    assert calibrated.status == 0, calibrated.err
    assert len(calibrated.grabs) >= 16 * 6
    measured = {
        k + 1 for k, p in enumerate(load_duty_cycle(CALIBRATION_PROGRAM).poses) if p.measure
    }
    offsets = {tuple(round(v, 6) for v in s.translation_mm) for s in robot_pattern(0.25, 2, 0.0, 0)}
    seen = set()
    for at_pose, applied, target in calibrated.grabs:
        assert at_pose in measured
        assert np.allclose(applied, target, atol=1e-9)  # reached, not on its way
        seen.add(tuple(round(1000.0 * v, 6) for v in applied[:3]))
    assert offsets <= seen


@pytest.mark.slow
def test_the_saved_observations_fit_again_to_the_same_cameras(
    calibrated: Calibrated, capsys: pytest.CaptureFixture[str]
) -> None:
    assert calibrated.status == 0, calibrated.err
    status, out, err = run_in_process(
        calibrate_cli.register,
        [
            "calibrate",
            "cameras",
            "--cameras",
            str(calibrated.guess),
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


# --- the pattern on the bench without cameras: holds, a program that does not dwell ---------


def _settings(tmp_path: Path, host: str, duty: str) -> Settings:
    settings = load_settings(lab_file(tmp_path, host, None, duty))
    return settings.model_copy(
        update={"arm": settings.arm.model_copy(update={"bench_cameras": False})}
    )


@pytest.mark.slow
async def test_a_hold_stops_the_pattern_and_freezes_the_offset(tmp_path: Path) -> None:
    settings = _settings(tmp_path, loopback_host(), CALIBRATION_PROGRAM)
    stations = stations_of(load_duty_cycle(CALIBRATION_PROGRAM), "camera")
    shifts = robot_pattern(0.4, 3, 0.0, 0)
    recording = URRecording("")
    async with open_devices(settings, make_clock("real")) as devices:
        assert devices.ur_emulator is not None
        controller = devices.ur_emulator.controller
        robot: Any = devices.robot

        async def hold_after_two() -> tuple[int, tuple[float, ...]]:
            # the recording is the pattern's own (no event to wait on): polled
            while recording.poses < 2:  # noqa: ASYNC110
                await asyncio.sleep(0.005)
            await robot.stop()
            regs = controller.registers
            return sum(controller.writes[n] for n in regs.target), controller.program.applied

        holder = asyncio.create_task(hold_after_two())
        with pytest.raises(MotionHeldError, match="held"):
            await record_ur_pattern(
                robot,
                (),
                (),
                np.zeros((0, 3)),
                shifts,
                stations=stations,
                wait_s=60.0,
                grab_timeout_s=5.0,
                recording=recording,
            )
        writes, applied = await holder
        assert 2 <= recording.poses < len(shifts)
        assert not recording.returned  # the return was refused before its bytes, too
        await asyncio.sleep(1.0)  # the program plays on: its offset stays where the hold froze it
        regs = controller.registers
        assert sum(controller.writes[n] for n in regs.target) == writes
        assert controller.program.applied == applied


@pytest.mark.slow
async def test_a_program_that_does_not_dwell_stops_the_pattern(tmp_path: Path) -> None:
    settings = _settings(tmp_path, loopback_host(), "ur5e-pick-and-place")
    stations = stations_of(load_duty_cycle("ur5e-pick-and-place"), None)
    async with open_devices(settings, make_clock("real")) as devices:
        assert devices.ur_emulator is not None
        controller = devices.ur_emulator.controller
        controller.pause(controller.time_s)  # the operator paused it (on its way: not at a pose)
        recording = URRecording("")
        with pytest.raises(CalibrationStopped, match="was not at a measured pose") as caught:
            await record_ur_pattern(
                devices.robot,  # type: ignore[arg-type]
                (),
                (),
                np.zeros((0, 3)),
                robot_pattern(0.25, 2, 0.0, 0),
                stations=stations,
                wait_s=1.0,
                grab_timeout_s=5.0,
                recording=recording,
            )
        assert "\n" not in str(caught.value)
        assert recording.poses == 0


# --- a program that reports an offset it does not apply -------------------------------------


@pytest.mark.slow
async def test_a_tcp_that_does_not_follow_the_offset_stops_the_pattern(tmp_path: Path) -> None:
    """The emulated controller's actual TCP pose made to ignore the offset its program reports
    applied (the joints of the taught path alone): the pattern stops at its second offset."""
    from daemon.arm import kinematics

    settings = _settings(tmp_path, loopback_host(), CALIBRATION_PROGRAM)
    stations = stations_of(load_duty_cycle(CALIBRATION_PROGRAM), "camera")
    async with open_devices(settings, make_clock("real")) as devices:
        assert devices.ur_emulator is not None
        controller = devices.ur_emulator.controller

        def tcp_of_the_path(t_s: float) -> tuple[float, ...]:
            _, _, nominal = controller.joint_state(t_s)
            pose = kinematics.forward(controller.arm, nominal)
            rotvec = Rotation.from_matrix(pose[:3, :3]).as_rotvec()
            return (*(float(v) / 1000.0 for v in pose[:3, 3]), *(float(v) for v in rotvec))

        controller.tcp_pose = tcp_of_the_path  # type: ignore[method-assign]
        recording = URRecording("")
        with pytest.raises(CalibrationStopped, match="does not shift the tool"):
            await record_ur_pattern(
                devices.robot,  # type: ignore[arg-type]
                (),
                (),
                np.zeros((0, 3)),
                robot_pattern(0.25, 2, 0.0, 0),
                stations=stations,
                wait_s=60.0,
                grab_timeout_s=5.0,
                recording=recording,
            )
        assert recording.poses == 1 and recording.returned


# --- bad usage: exit 2, one line, nothing opened ---------------------------------------------


@pytest.fixture
def no_devices(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*_: object, **__: object) -> None:
        raise AssertionError("the devices were opened")

    monkeypatch.setattr(cameras_ur, "calibrate_with_ur", refuse)


@pytest.mark.usefixtures("no_devices")
@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (
            ["--size", "0.9"],
            "shifts the program's path by up to 1.559 mm, beyond robot.correction_limit_mm = 1 mm",
        ),
        (["--turn", "0.001"], "beyond robot.correction_limit_rad = 0.001 rad"),
        (["--here"], "--here: the PC does not move a UR"),
        (["--joints", "0,-90,90,0,90,0"], "--joints: the PC does not move a UR"),
        (["--fit-marker", "--turn", "0.0005"], "--fit-marker: a UR's offset program turns"),
        (["--station", "pick"], "--station 'pick': not a measured pose of the program"),
    ],
)
def test_bad_usage_is_refused_before_anything_opens(
    extra: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    guess = tmp_path / "guess.toml"
    write_cameras(guess, bench_cameras(load_settings(UR5E)))
    lab = lab_file(tmp_path, loopback_host(), guess, "ur5e-pick-and-place")
    status, out, err = run_in_process(
        calibrate_cli.register,
        ["calibrate", "cameras", "--robot", "--config", str(lab), *extra],
        capsys,
    )
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines
    assert out == ""
    assert not (tmp_path / "data").exists()


def test_the_default_pattern_is_half_the_correction_limit() -> None:
    settings = load_settings(UR5E)
    shifts = robot_pattern(cameras_ur.default_size(settings), 3, 0.0, 0)
    cameras_ur.check_ur_pattern(settings, shifts)  # within the limit
    farthest = max(math.dist((0.0, 0.0, 0.0), s.translation_mm) for s in shifts)
    assert farthest == pytest.approx(0.5 * math.sqrt(3.0) * settings.robot.correction_limit_mm)
    assert all(s.rotation_rad == (0.0, 0.0, 0.0) for s in shifts)
    assert isinstance(shifts[0], Shift)


# --- the followed run loads the written camera file -----------------------------------------


async def test_a_followed_run_measures_with_arm_cameras_file(tmp_path: Path) -> None:
    """arm.cameras_file (what `calibrate cameras --robot --write` wrote) is the followed run's
    camera models, on the bench too (else the bench's own); a file that does not match the
    cameras is one RunParameterError."""
    from types import SimpleNamespace

    from daemon.run.followed.build import _measurement
    from daemon.run.setup import RunParameterError

    truth = bench_cameras(load_settings(UR5E))
    written = tmp_path / "cameras.toml"
    write_cameras(written, perturbed(truth))
    workers = SimpleNamespace(step=asyncio.to_thread)
    devices = SimpleNamespace(cameras=tuple(object() for _ in truth), camera_models=truth)

    async def models_of(cameras_file: Path | None) -> tuple[CameraModel, ...]:
        settings = load_settings(
            lab_file(tmp_path, loopback_host(), cameras_file, CALIBRATION_PROGRAM)
        )
        builder = SimpleNamespace(settings=settings, workers=workers)
        robot = SimpleNamespace(robot_state=lambda: None)
        measurement = await _measurement(builder, devices, robot, None)  # type: ignore[arg-type]
        assert measurement is not None
        return measurement.meter._models  # type: ignore[attr-defined,no-any-return]

    loaded = await models_of(written)
    expected = load_cameras(written)
    assert [m.name for m in loaded] == [m.name for m in expected]
    assert all(np.allclose(a.centre_mm, b.centre_mm) for a, b in zip(loaded, expected, strict=True))
    assert await models_of(None) == truth
    write_cameras(written, list(truth[:3]))
    with pytest.raises(RunParameterError, match="6 tool cameras but 3 camera models"):
        await models_of(written)


@pytest.mark.slow
async def test_a_followed_run_with_the_written_file_measures_what_the_truth_does(
    calibrated: Calibrated, tmp_path: Path
) -> None:
    """The whole path: the written file as arm.cameras_file, a followed run of the production
    program; after each pose's zero the truth's arm is made 15 degC warmer than the model
    knows, and the residuals the calibrated cameras measure are the truth's within their
    sigmas (as tests/test_ur_followed_cameras.py checks with the bench's true cameras)."""
    from daemon.run.states import RunState
    from daemon.service import Daemon
    from drivers.sim.ur.emulator import UREmulator
    from tests.fakes import params
    from tests.test_ur_followed_cameras import (
        FLOOR_UM,
        SIGMAS,
        WARMER_C,
        flag_counts,
        measured,
        steps_of,
        until,
        ur_settings,
    )

    assert calibrated.status == 0, calibrated.err
    settings = ur_settings(tmp_path, loopback_host(), cameras_file=str(calibrated.written))
    async with Daemon(settings) as daemon:
        emulator = getattr(daemon.devices, "ur_emulator", None)
        assert isinstance(emulator, UREmulator)
        info = await daemon.start_run(params(settings))
        run_id = int(info["id"])
        await daemon.wait_state(RunState.RUNNING)

        def zeros() -> int:
            steps = steps_of(daemon, run_id)
            return len({s["arm_pose"] for s in steps if "first-step-reference" in s["flags"]})

        await until(
            lambda: zeros() == 2,
            "each measured pose's zero",
            lambda: flag_counts(daemon, run_id),
        )
        thermal = emulator.controller.bench.thermal
        thermal.set_temperatures(thermal.temperatures_c + WARMER_C)
        await until(
            lambda: len(measured(steps_of(daemon, run_id))) >= 6,
            "measurements",
            lambda: flag_counts(daemon, run_id),
        )
        final = await daemon.stop()
    # the run's own comparison of each measurement with the truth at its frames (a
    # measurement whose frames outlasted the dwell on a loaded machine is discarded, not
    # compared: daemon/run/followed/measure.py)
    summary = final["summary"]
    assert summary["measured"]["rms_residual_um"] > 50.0  # the warming, far beyond the noise
    versus = summary["measured_vs_truth"]
    assert versus["measurements"] >= 2
    assert versus["rms_difference_um"] < SIGMAS * summary["measured"]["mean_sigma_um"] + FLOOR_UM
    assert versus["within_3_sigma_fraction"] >= 0.5
