"""``thermocomp calibrate model`` on a UR (issue 31, daemon/commands/calibrate_ur_model.py):
identification from a followed run's camera measurements and joint temperatures, the arm
model a followed run then loads, and the refusals (one line each).

The calibration run is the UR bench's program recorded on an accelerated clock
(benchmarks/ur_recorded.py: the emulated controller sampled without its 500 Hz loop, the
followed run's own recording and dwell measurement code, the bench's rendered cameras): hours
of warm-up in seconds. A followed run with compensation off (the chain's calibration run) is
checked apart, through the daemon on the suite's fake offset robot: its corrections are
exactly zero."""

from __future__ import annotations

import asyncio
import json
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.ur_recorded import emulated, record_calibration_run
from config.settings import Settings, load_settings
from daemon.arm.arm_model import ArmModel, arm_model_toml, new_arm_model_path
from daemon.run.followed.setup import followed_model
from daemon.run.setup import RunParameterError
from daemon.run.states import RunParameters
from daemon.service import Daemon
from daemon.storage.recorder import DATABASE_NAME
from drivers.clock import make_clock
from tests.fakes import make_settings, params, stop_with_a_move_in_flight
from tests.helpers import REPO_ROOT, run_main
from tests.loopback import loopback_host
from tests.test_followed_kind import WAIT_S, FollowedDevices

UR5E = str(REPO_ROOT / "config" / "ur5e-sim.toml")
#: the truth's shoulder motor heats half again what the preset model says
TRUE_SHOULDER_HEAT = 1.5
#: the truth's motor losses sampled every 50 ms instead of 10 ms: 5x less CPU, the same
#: mean heat to within the motion's own jerk (the model's motion_dt_s is 50 ms too)
FAST_MOTION_STEP_S = 0.05


def ur_settings(data_dir: Path) -> Settings:
    data = load_settings(Path(UR5E)).model_dump()
    data["storage"]["data_dir"] = str(data_dir)
    return Settings.model_validate(data)


def recorded_run(data_dir: Path, hours: float, **truth: Any) -> int:
    controller = emulated(1, {"motion_step_s": FAST_MOTION_STEP_S, **truth})
    run_id, _ = record_calibration_run(
        ur_settings(data_dir), controller, data_dir, hours=hours, measure_every_s=300.0
    )
    return run_id


def calibrated(data: Path, run_id: int, save: str) -> dict[str, Any]:
    """``calibrate model`` on the recorded followed run ``run_id`` of ``data`` through the real
    CLI (saved as ``save``, no validation, ``--force``): its JSON outcome."""
    result = run_main(
        [
            "calibrate",
            "model",
            "--config",
            UR5E,
            "--save",
            save,
            "--calibration-run",
            str(run_id),
            "--no-validate",
            "--force",
            "--json",
        ],
        env={"THERMOCOMP_STORAGE__DATA_DIR": str(data)},
    )
    assert result.returncode == 0, result.stderr
    outcome: dict[str, Any] = json.loads(result.stdout)
    return outcome


@pytest.mark.slow
def test_calibrate_model_identifies_the_motor_heat_the_preset_gets_wrong(tmp_path: Path) -> None:
    """Two hours of the program on a truth whose shoulder heats x1.5: the identified factor
    moves from the preset's 1.0 toward the truth by many standard errors, and the followed
    run's model loads the saved arm model with it (and the joint sensors' offsets).
    ``--force``: the bench truth bends its links (motor housings on one side), which the
    model without arm.bending absorbs into alpha, below its physical range (saved, flagged)."""
    data = tmp_path / "data"
    heat = (1.0, TRUE_SHOULDER_HEAT, 1.0, 1.0, 1.0, 1.0)
    run_id = recorded_run(data, 2.0, heat_scales=heat)
    outcome = calibrated(data, run_id, "shoulder")
    refit = outcome["identified"]["refit"]
    shoulder = next(p for p in refit["parameters"] if p["name"] == "heat:2")
    assert shoulder["identifiable"]
    value, error = shoulder["value"], shoulder["standard_error"]
    assert value - 1.0 > 5.0 * error, shoulder  # moved off the preset, beyond its SE
    assert abs(value - TRUE_SHOULDER_HEAT) < abs(1.0 - TRUE_SHOULDER_HEAT) / 4, shoulder
    # the followed run loads it: the shoulder's heat and the joints' offsets are the model's
    settings = ur_settings(data)
    parameters = RunParameters.from_settings(settings, arm_model="shoulder")
    controller = followed_model(settings, parameters).controller
    assert controller.identified is not None
    assert controller.identified.heat_scales[1] == pytest.approx(value)
    assert set(controller.identified.ir_offsets_c) <= {f"joint{k}" for k in range(1, 7)}
    assert controller.identified.ir_offsets_c  # the joint sensors' offsets were identified
    # `thermocomp identify RUN` reads the followed run the same way (no save: the table)
    table = run_main(["identify", str(run_id)], env={"THERMOCOMP_STORAGE__DATA_DIR": str(data)})
    assert table.returncode == 0, table.stderr
    row = next(line for line in table.stdout.splitlines() if line.startswith("heat:2 "))
    assert float(row.split()[2]) == pytest.approx(value, rel=1e-3)  # printed to 4 digits


def test_a_recorded_run_with_no_camera_measurement_is_refused_in_one_line(
    tmp_path: Path,
) -> None:
    """A followed run whose cameras measured nothing (its measurement columns hold the bench
    truth, flag bench-truth, or nothing): one line, nothing saved."""
    data = tmp_path / "data"
    run_id = recorded_run(data, 0.05)
    with sqlite3.connect(data / DATABASE_NAME) as db:  # as a run with no camera records it
        db.execute("UPDATE steps SET flags = 'bench-truth' WHERE measured_tx_um IS NOT NULL")
    result = run_main(
        [
            "calibrate",
            "model",
            "--config",
            UR5E,
            "--save",
            "none",
            "--calibration-run",
            str(run_id),
            "--no-validate",
        ],
        env={"THERMOCOMP_STORAGE__DATA_DIR": str(data)},
    )
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "has 0 camera measurement(s) of the tool" in lines[0], lines
    assert not list(data.glob("**/none*.toml"))


@pytest.mark.parametrize(
    ("args", "env", "what"),
    [
        (
            ["--config", UR5E, "--calibration-cycle", "ur5e-pick-and-place"],
            {},
            "--calibration-cycle is the A465's",
        ),
        (["--config", UR5E, "--scale", "20"], {}, "--scale is the two-link bench's"),
        (
            ["--calibration-run", "1"],
            {},
            "--calibration-run is a UR's (robot.driver ur-rtde)",
        ),
    ],
)
def test_options_a_ur_chain_cannot_use_are_refused_in_one_line(
    args: list[str], env: dict[str, str], what: str, tmp_path: Path
) -> None:
    result = run_main(
        ["calibrate", "model", "--save", "x", *args],
        env={"THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path / "data"), **env},
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and what in lines[0], lines
    assert not (tmp_path / "data").exists()


async def test_an_uncompensated_followed_run_writes_zero_corrections(tmp_path: Path) -> None:
    """compensation off (the calibration run): the program gets a zero correction every step
    (its heartbeat) while the model, fed joints warmer than the room, predicts an error."""
    settings = make_settings(
        tmp_path,
        scheduler={"step_s": 0.2, "duration_s": 600.0},
        model={"prediction": "model+ir"},
        arm={"enabled": True, "arm_file": "ur5e", "duty_cycle": "ur5e-pick-and-place"},
    )
    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    devices = FollowedDevices(clock)
    robot = devices.robot
    async with Daemon(settings, clock=clock, open_devices=lambda _s, _c: devices) as daemon:
        info = await daemon.start_run(params(settings, compensation="off", time_scale=600.0))
        async with asyncio.timeout(WAIT_S):
            while len(robot.commands) < 5:  # noqa: ASYNC110 -- the fake has no event
                await asyncio.sleep(0.01)
        # the stop comes while a step's correction is on its way to the robot (as it did
        # once under load): the stop's hold is first, so that correction is refused
        await stop_with_a_move_in_flight(daemon, robot, WAIT_S)
    assert not np.any(robot.correction.translation_mm)
    assert not np.any(robot.correction.rotation_rad)
    with sqlite3.connect(tmp_path / DATABASE_NAME) as db:
        rows = db.execute(
            "SELECT correction_tx_mm, correction_ty_mm, correction_tz_mm, predicted_tx_um, "
            "predicted_ty_um, predicted_tz_um, flags FROM steps WHERE run_id = ? ORDER BY step",
            (info["id"],),
        ).fetchall()
    # every step sent a zero correction but the one in flight at the stop: refused by the
    # stop's hold, it is recorded without a correction, flagged robot-error
    *commanded, refused = rows
    assert len(commanded) >= 5 and all(row[:3] == (0.0, 0.0, 0.0) for row in commanded)
    assert refused[:3] == (None, None, None) and "robot-error" in refused[6].split(","), refused
    assert max(abs(v) for row in rows for v in row[3:6]) > 0.1  # um: the model did predict


@pytest.mark.slow
def test_the_chain_runs_a_followed_calibration_run_on_the_ur_bench(tmp_path: Path) -> None:
    """The whole step 1 on the real-clock UR bench (emulator over loopback, rendered cameras):
    an uncompensated followed run of the program measured at its dwells, identified and saved.
    Seconds of warm-up identify only the joint sensors' offsets: the model is saved with its
    loud warning, every other factor the preset's."""
    data = tmp_path / "data"
    result = run_main(
        [
            "calibrate",
            "model",
            "--config",
            UR5E,
            "--save",
            "short",
            "--duration",
            "12",
            "--no-validate",
            "--json",
        ],
        env={
            "THERMOCOMP_STORAGE__DATA_DIR": str(data),
            "THERMOCOMP_ROBOT__HOST": loopback_host(),
        },
    )
    assert result.returncode == 0, result.stderr
    outcome = json.loads(result.stdout)
    calibration = outcome["calibration_run"]
    assert calibration["state"] == "finished" and calibration["measurements"] >= 1
    model = outcome["identified"]["arm_model"]
    assert "heat:2" in model["not_identified"]
    assert (data / "arm-models" / "short.toml").read_text().count("NOT FULLY CALIBRATED") == 1
    with sqlite3.connect(data / DATABASE_NAME) as db:
        corrections = db.execute(
            "SELECT DISTINCT correction_tx_mm, correction_ty_mm, correction_tz_mm FROM steps"
        ).fetchall()
    assert corrections == [(0.0, 0.0, 0.0)]  # compensation off: zero written every step


def test_a_followed_run_refuses_an_arm_model_of_another_arm_in_one_line(tmp_path: Path) -> None:
    """An A465's arm model given to a UR's followed run: refused before the run, one line."""
    settings = ur_settings(tmp_path)
    path = new_arm_model_path("a465-cell", tmp_path)
    path.parent.mkdir(parents=True)
    path.write_text(arm_model_toml(ArmModel("a465-cell", "crs-a465", (1.0,) * 6)), "utf-8")
    with pytest.raises(RunParameterError) as refused:
        followed_model(settings, RunParameters.from_settings(settings, arm_model="a465-cell"))
    assert "identified on arm 'crs-a465', this run's arm is 'UR5e'" in str(refused.value)
    assert "\n" not in str(refused.value)
