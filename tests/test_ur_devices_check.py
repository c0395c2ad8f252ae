"""`thermocomp devices check --config config/ur5e-sim.toml` through the real CLI: on the UR bench
it describes the UR over RTDE and the Dashboard Server (protocol and controller version,
robot, safety and program state, joint temperatures, the registers it set up, the offset
program) and says what it did not check (no camera); against an emulated "real" UR (bench
disabled, the emulator run by the test) each thing that would stop a run is its own failure
line, and an unreachable robot, input registers another client holds and a missing tool
camera are one line each; the calibrations a UR cannot make are refused in one line; and
`thermocomp run` prints a followed run's own figures.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
from pathlib import Path

import pytest

from daemon.vision.cameras import write_cameras
from drivers.sim.arm_markers import CameraRig
from drivers.sim.ur.controller import URControllerConfig
from drivers.sim.ur.emulator import UREmulator
from drivers.ur.registers import RegisterMap
from drivers.ur.rtde_client import RtdeClient
from tests.helpers import REPO_ROOT, cli_command, run_main
from tests.loopback import loopback_host

UR5E = str(REPO_ROOT / "config" / "ur5e-sim.toml")
CLI_TIMEOUT_S = 120.0


def on_host(host: str, **extra: str) -> dict[str, str]:
    return {"THERMOCOMP_ROBOT__HOST": host, **extra}


def as_robot(host: str, **extra: str) -> dict[str, str]:
    """The settings of a real UR at ``host``: no bench (the test runs the emulator), and no
    room thermometer (the bench's is refused off the bench; a lab's DS18B20, room.driver w1,
    is not on this machine)."""
    return on_host(host, THERMOCOMP_BENCH__ENABLED="false", THERMOCOMP_ROOM__DRIVER="none", **extra)


async def check(env: dict[str, str], *args: str) -> tuple[int, str, str]:
    """The CLI in a subprocess while this loop serves the emulator."""
    process = await asyncio.create_subprocess_exec(
        *cli_command("devices", "check", "--config", UR5E, *args),
        cwd=REPO_ROOT,
        env={**os.environ, **env},
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    async with asyncio.timeout(CLI_TIMEOUT_S):
        out, err = await process.communicate()
    assert process.returncode is not None
    return process.returncode, out.decode(), err.decode()


def failures(out: str) -> list[str]:
    return [line for line in out.splitlines() if ": FAILED: " in line]


@pytest.mark.slow
def test_the_ur_bench_is_described_and_passes() -> None:
    host = loopback_host()
    result = run_main(["devices", "check", "--config", UR5E], env=on_host(host))
    assert result.returncode == 0, result.stdout + result.stderr
    out = result.stdout
    for line in (
        "robot: connected",
        f"robot: RTDE: {host}:30004, protocol version 2 accepted, state at 125 Hz",
        "robot: controller: 5.15.0.0",
        "robot: robot mode: RUNNING",
        "robot: safety: NORMAL",
        "robot: program (RTDE): PLAYING",
        "robot: program (Dashboard): PLAYING thermocomp.urp",
        "robot: remote control: true",
        "robot: registers: input int 24-26 and double 24-29 set up by this PC (free: no other "
        "RTDE client holds them); output int 24-27, double 24-29",
    ):
        assert line in out.splitlines(), out
    temperatures = next(x for x in out.splitlines() if x.startswith("robot: joint temperatures"))
    values = [float(v) for v in temperatures.split(": ")[2].removesuffix(" degC").split()]
    assert len(values) == 6 and all(15.0 < v < 60.0 for v in values)
    assert "robot: offset program: running (instance " in out
    # the bench's tool cameras (arm.bench_cameras): the camera station's three see the tool's
    # markers while the program dwells there, else nothing; one frame each, by name
    cameras = [x for x in out.splitlines() if x.startswith("camera s")]
    assert [x.split(":")[0] for x in cameras] == [
        f"camera s{station}-arm-{k}" for station in (0, 1) for k in range(3)
    ], out
    assert all("2448x2048 px" in x for x in cameras)
    assert "cameras: none checked" not in out
    assert not failures(out) and not result.stderr.strip()

    as_json = run_main(
        ["devices", "check", "--config", UR5E, "--json"], env=on_host(loopback_host())
    )
    data = json.loads(as_json.stdout)
    facts = data["robot"]["facts"]
    assert facts["safety"] == "NORMAL" and facts["controller"] == "5.15.0.0"
    assert data["robot"]["link"] == "connected" and data["errors"] == {}


@pytest.mark.slow
async def test_what_would_stop_a_run_is_one_line_each() -> None:
    # the program's REG_BASE is 30, the PC's 24: the offset program is silent where the PC
    # reads; a protective stop halts the arm
    config = URControllerConfig(register_base=30)
    host = loopback_host()
    async with UREmulator(config, host=host) as ur:
        ur.protective_stop()
        status, out, err = await check(as_robot(host))
        assert status == 1
        assert failures(out) == [
            "robot safety: FAILED: PROTECTIVE_STOP: clear it on the pendant",
            "robot offset program: FAILED: silent in output_int_register_27: put "
            "thermocomp_offset.script in the program's Before Start with REG_BASE = 24 "
            "(controller/ur/README.md)",
        ], out
        assert len(err.strip().splitlines()) == 2  # one stderr line per failure
        assert "robot: program (RTDE): PAUSED" in out

        # the operator stopped the program; the Dashboard Server is not where the PC looks
        ur.operator_stop()
        with socket.socket() as probe:  # a port nothing listens on
            probe.bind((host, 0))
            closed = probe.getsockname()[1]
        status, out, _ = await check(as_robot(host, THERMOCOMP_ROBOT__DASHBOARD_PORT=str(closed)))
        assert status == 1
        lines = failures(out)
        assert "robot program: FAILED: STOPPED: load the production program with " in lines[1]
        assert lines[-1].startswith(f"robot Dashboard: FAILED: Dashboard Server {host}:")
        assert lines[-1].endswith(
            "a hold cannot pause the program (robot.pause_program_on_hold; port "
            "robot.dashboard_port)"
        )
        # without the pause on a hold the Dashboard is described, not a failure
        status, out, _ = await check(
            as_robot(
                host,
                THERMOCOMP_ROBOT__DASHBOARD_PORT=str(closed),
                THERMOCOMP_ROBOT__PAUSE_PROGRAM_ON_HOLD="false",
            )
        )
        assert not any(line.startswith("robot Dashboard") for line in failures(out))
        assert "robot: Dashboard: no answer: " in out


@pytest.mark.slow
async def test_unreachable_robot_taken_registers_and_a_missing_camera(tmp_path: Path) -> None:
    nobody = loopback_host()  # nothing listens there
    status, out, err = await check(as_robot(nobody))
    assert status == 1
    assert failures(out) == [
        f"robot: FAILED: RTDE {nobody}:30004: [Errno 111] Connect call failed ('{nobody}', 30004)"
    ]
    assert err.strip().splitlines() == [
        f"thermocomp devices check: robot: RTDE {nobody}:30004: [Errno 111] Connect call "
        f"failed ('{nobody}', 30004)"
    ]

    host = loopback_host()
    async with UREmulator(host=host) as ur:
        other = RtdeClient(ur.host, ur.rtde_port, 5.0)  # another PC holds our registers
        await other.connect()
        try:
            await other.setup_inputs([RegisterMap(24).sequence])
            # one camera model for the one device (a followed run measures with both)
            cameras = tmp_path / "cameras.toml"
            write_cameras(cameras, CameraRig(count=1).cameras((400.0, 0.0, 300.0)))
            status, out, _ = await check(
                as_robot(
                    host,
                    THERMOCOMP_ARM__CAMERAS_FILE=str(cameras),
                    THERMOCOMP_ARM__CAMERA_DEVICES=json.dumps(
                        [{"driver": "replay", "replay_dir": str(tmp_path / "no-frames")}]
                    ),
                )
            )
        finally:
            await other.aclose()
    assert status == 1
    lines = failures(out)
    assert len(lines) == 2, out
    assert lines[0].startswith("robot: FAILED: ") and "IN_USE" in lines[0]
    assert lines[1].startswith("tool camera 0: FAILED: ")
    assert "cameras: none checked" not in out  # the configured camera was checked


@pytest.mark.slow
def test_a_bench_whose_ports_are_taken_is_one_line() -> None:
    """The UR bench's emulator cannot open (its ports are taken by another bench): one line."""
    host = loopback_host()
    with socket.socket() as taken:
        taken.bind((host, 30004))
        taken.listen()
        result = run_main(["devices", "check", "--config", UR5E, "--json"], env=on_host(host))
    assert result.returncode == 1
    data = json.loads(result.stdout)
    assert list(data["errors"]) == ["robot"]
    assert data["errors"]["robot"].startswith("the UR emulator: ")
    assert len(result.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("args", "what", "extra"),
    [
        (["calibrate", "camera"], "has no spot camera: its tool cameras are calibrated", {}),
        (
            ["calibrate", "model", "--save", "ur"],
            "has no tool camera (arm.bench_cameras)",
            {"THERMOCOMP_ARM__BENCH_CAMERAS": "false"},
        ),
    ],
)
def test_the_calibrations_a_ur_cannot_make_are_refused_in_one_line(
    args: list[str], what: str, extra: dict[str, str], tmp_path: Path
) -> None:
    """Before anything opens: the emulator's ports are taken and no data directory is made."""
    host = loopback_host()
    with socket.socket() as taken:
        taken.bind((host, 30004))
        taken.listen()
        result = run_main(
            [*args, "--config", UR5E],
            env=on_host(host, THERMOCOMP_STORAGE__DATA_DIR=str(tmp_path / "data"), **extra),
        )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and what in lines[0], lines
    assert 'docs/how-to/universal-robots.md, "Calibration on a UR"' in lines[0]
    assert not (tmp_path / "data").exists()
    assert result.stdout == ""


def test_a_followed_run_prints_its_own_figures(capsys: pytest.CaptureFixture[str]) -> None:
    """`thermocomp run` on a UR: the corrections and the bench truth's removal, not the
    two-link bench's residual rows (all empty for a followed run)."""
    from daemon.commands.run import _print_result

    summary = {
        "kind": "followed",
        "corrections_written": 262,
        "overruns": 3,
        "bench_truth": {
            "steps": 262,
            "rms_residual_um": 1.25,
            "rms_uncompensated_um": 10.0,
            "worst_residual_um": 2.5,
            "worst_uncompensated_um": 12.0,
            "removed_fraction": 0.875,
        },
    }
    _print_result({"id": 4, "state": "finished", "reason": None, "summary": summary}, False)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "run 4 finished"
    assert "  corrections written          262" in lines
    assert "  removed (RMS)                87.500 %" in lines
    assert "  3-D error RMS, uncorrected   10.000 um" in lines
    assert not any("residual" in line for line in lines)


def test_a_followed_run_prints_what_its_cameras_measured(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """With tool cameras, `thermocomp run` prints the measured residuals and the cameras
    against the truth; with none, that nothing was measured."""
    from daemon.commands.run import _print_result

    measured = {
        "cameras": 6,
        "measurements": 12,
        "rms_residual_um": 7.5,
        "worst_residual_um": 12.0,
        "rms_uncompensated_um": 30.0,
        "removed_fraction": 0.75,
        "mean_sigma_um": 6.5,
    }
    versus = {"measurements": 12, "rms_difference_um": 3.25, "worst_difference_sigmas": 1.5}
    summary = {"kind": "followed", "measured": measured, "measured_vs_truth": versus}
    _print_result({"id": 5, "state": "stopped", "reason": None, "summary": summary}, False)
    lines = capsys.readouterr().out.splitlines()
    assert "  cameras: measurements (N)    12" in lines
    assert "  cameras: 3-D residual RMS    7.500 um" in lines
    assert "  cameras: removed (RMS)       75.000 %" in lines
    assert "  cameras vs bench truth: RMS  3.250 um" in lines
    none = {"kind": "followed", "measured": {"cameras": 0, "measurements": 0}}
    _print_result({"id": 6, "state": "stopped", "reason": None, "summary": none}, False)
    out = capsys.readouterr().out
    assert "tool measured                none: no camera (model + joint temperatures)" in out
