"""A followed run's motor heat from the motion the robot actually made (issue 31, arm.heat_from
``measured``: drivers/ur/motion.py, daemon/run/followed/heat.py), against the duty cycle's.

Through the daemon on the UR bench (the emulated controller over RTDE on a loopback address of
the test's own): the program paused by the Dashboard's ``pause`` holds the arm at rest, and the
steps of the pause record the heat of an arm at rest -- the bench truth's own heat of that rest,
to the truth's motor factors -- where the duty cycle would have heated the model with the
program's motion. The recorded heat then feeds identification
(daemon/commands/followed_identify.py) after a restart, and on a calibration run whose program
was paused for most of an hour (benchmarks/ur_recorded.py, accelerated) identification finds
the truth's heat factors where the duty cycle's heat bends them; ur-rtde's own client reads
the fields the heat comes from (tests/test_ur_rtde_clients.py).
"""

from __future__ import annotations

import asyncio
import json
import math
import shutil
import sqlite3
from contextlib import closing
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.ur_recorded import emulated, record_calibration_run
from daemon.arm.heat import JointHeatProfile
from daemon.arm.loading import load_arm
from daemon.arm.motors import joint_heat_batch_w
from daemon.arm.types import JointSample
from daemon.commands.followed_identify import load_followed_run
from daemon.run.followed.heat import MeasuredHeat, RecordedHeat, parse_heat_json
from daemon.run.states import RunState
from daemon.service import Daemon
from daemon.storage.recorder import DATABASE_NAME, Recorder
from daemon.storage.step_record import StepRecord
from drivers.ur.dashboard_client import DashboardClient
from drivers.ur.modes import RuntimeState
from drivers.ur.motion import MotionSamples
from tests.fakes import params
from tests.loopback import loopback_host
from tests.test_ur_calibrate_model import FAST_MOTION_STEP_S, calibrated
from tests.test_ur_calibrate_model import ur_settings as ur_calibration_settings
from tests.test_ur_program_pause import emulator_of, until, ur_settings

#: How long the program stays paused (s): tens of 10 Hz steps.
PAUSE_S = 2.0
#: The measured heat of the arm at rest against the truth's (times its motor factors): the
#: model's torques are the nominal arm's, the truth's its own geometry (0.2 mm, 0.2 mrad
#: errors: 0.3-0.6 % of the shoulder's and elbow's holding torque's square)
REST_RTOL = 0.01
REST_ATOL_W = 1e-3


def moving(sample: JointSample) -> bool:
    return bool(np.max(np.abs(sample.qd_rad_s)) > 0.2)


def _heat_rows(data_dir: Path, run_id: int) -> list[tuple[float, float, np.ndarray[Any, Any]]]:
    path = data_dir / DATABASE_NAME
    with closing(sqlite3.connect(path)) as db:
        texts = [
            row[0]
            for row in db.execute(
                "SELECT heat_json FROM steps WHERE run_id = ? ORDER BY step", (run_id,)
            )
        ]
    rows = [parse_heat_json(text, 6) for text in texts]
    return [row for row in rows if row is not None]


@pytest.mark.slow
async def test_a_paused_program_heats_the_model_as_the_arm_at_rest(tmp_path: Path) -> None:
    """The Dashboard's pause mid-run: the steps of the pause record the heat of the arm at
    rest (times the truth's motor factors, the truth's own heat of that rest to 1 %), and
    the duty cycle's heat over the same steps -- the reference -- is far from it; the model's
    controller advanced with the recorded heat."""
    host = loopback_host()
    settings = ur_settings(tmp_path, host)
    async with Daemon(settings) as daemon:
        emulator = emulator_of(daemon)
        controller = emulator.controller
        started = await daemon.start_run(params(settings))
        await daemon.wait_state(RunState.RUNNING)
        run_id = int(started["id"])
        writes = controller.writes[controller.registers.target[0]]
        await until(lambda: controller.writes[controller.registers.target[0]] >= writes + 10, "")
        # paused mid-move: the arm halts where no taught dwell holds it
        await until(lambda: moving(controller.player.sample(emulator.now())), "a move")
        dashboard = DashboardClient(host, emulator.dashboard_port, 5.0)
        await dashboard.pause()
        assert controller.runtime_state is RuntimeState.PAUSED
        paused_at = emulator.now()
        rest = controller.player.sample(paused_at)
        await asyncio.sleep(PAUSE_S)
        await dashboard.play()
        await asyncio.sleep(1.0)
        truth_rest_w = controller.bench.power(rest)
        scales = controller.bench.heat_scales
        final = await daemon.stop()
    summary = final["summary"]["heat"]
    # 125 packages a second over the run's ~4 s; none lost, the clock never went back
    assert summary["from"] == "measured" and summary["packages"] > 300, summary
    assert summary["gaps"] == 0 and summary["clock_resets"] == 0, summary
    rows = _heat_rows(tmp_path / "data", run_id)
    assert len(rows) > 30
    at_rest = [
        (start, end, power)
        for start, end, power in rows
        if np.allclose(power * scales, truth_rest_w, rtol=REST_RTOL, atol=REST_ATOL_W)
    ]
    # every step inside the pause (its first and last may share the motion around it)
    steps = PAUSE_S / settings.scheduler.step_s
    assert len(at_rest) >= steps - 4, (len(at_rest), steps)
    profile = JointHeatProfile.from_duty(
        load_arm(settings.arm.arm_file),
        emulator.controller.duty,
        resolution_s=settings.arm.motion_dt_s,
    )
    measured_error = duty_error = 0.0
    for start, end, power in at_rest:
        duty = profile.step_power_w(start, end)
        measured_error += float(np.abs(power * scales - truth_rest_w).sum())
        duty_error += float(np.abs(duty * scales - truth_rest_w).sum())
    # the duty cycle moves the base and wrists, which do no work at rest: watts off per step
    assert duty_error > 0.5 * len(at_rest), duty_error / len(at_rest)
    assert measured_error < 0.02 * duty_error
    # the steps outside the pause heat as the moving program (not the rest)
    assert any(power[0] > 0.1 for _, _, power in rows), "the base joint never moved"
    assert not math.isclose(sum(p.sum() for _, _, p in rows), len(rows) * truth_rest_w.sum())


def _recorded_run(data_dir: Path, heat_rows: list[tuple[float, float, list[float]]]) -> int:
    """A followed run's steps with joint temperatures, two camera measurements and the given
    recorded heat, written by the recorder (then closed: a daemon restarted reads it)."""
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run(
            {"duty_cycle": "ur5e-pick-and-place", "time_scale": 1.0},
            {"robot": {"driver": "ur-rtde"}, "arm": {"enabled": True, "arm_file": "ur5e"}},
            {"kind": "followed"},
            "test",
            kind="followed",
        )
        for step, (start, end, power) in enumerate(heat_rows):
            record = StepRecord(
                run_id=run_id, step=step, scheduled_s=end, actual_s=end, lateness_s=0.0
            )
            record.ir_json = json.dumps({f"joint{k + 1}": {"mean_c": 22.0} for k in range(6)})
            record.heat_json = json.dumps({"from_s": start, "to_s": end, "joint_w": power})
            if step in (1, len(heat_rows) - 1):  # two measurements at the camera pose (1)
                record.arm_pose = "1"
                record.measured_tx_um = record.measured_ty_um = record.measured_tz_um = 0.0
                record.correction_tx_mm = record.correction_ty_mm = 0.0
                record.correction_tz_mm = 0.0
            recorder.write_step(record)
        recorder.finish_run(run_id, "finished", {"kind": "followed"}, None)
    return run_id


def test_the_recorded_heat_survives_a_restart_and_feeds_identification(tmp_path: Path) -> None:
    """Steps recorded with their measured heat (a pause in the middle: nothing but the
    shoulder's and elbow's holding heat for 400 s), the recorder closed and the run read back
    as `calibrate model` reads a followed run: identification's heat per 20-s step is the
    recorded one (exactly its time-weighted mean), not the duty cycle's; before the first
    recorded step the duty cycle's fills in."""
    data = tmp_path / "data"
    moving = [3.0, 9.0, 7.0, 1.0, 0.2, 0.1]
    resting = [0.0, 1.5, 6.0, 0.8, 0.0, 0.0]
    rows: list[tuple[float, float, list[float]]] = []
    t = 40.0  # the first 40 s: no record (the duty cycle's)
    while t < 1200.0:
        power = resting if 400.0 <= t < 800.0 else moving
        rows.append((t, t + 10.0, power))
        t += 10.0
    run_id = _recorded_run(data, rows)
    with Recorder(data):  # a restarted daemon opens the database again (its migration)
        pass
    run = load_followed_run(
        data,
        run_id,
        {"duty_cycle": "ur5e-pick-and-place", "time_scale": 1.0},
        {"robot": {"driver": "ur-rtde"}, "arm": {"enabled": True, "arm_file": "ur5e"}},
    )
    heat = run.data.joint_heat_w
    step = run.data.heat_step_s
    assert isinstance(run.controller.heat, RecordedHeat)
    duty = run.controller.heat.fallback
    for k in range(len(heat)):
        t0, t1 = k * step, (k + 1) * step
        if t1 <= 40.0:
            np.testing.assert_allclose(heat[k], duty.step_power_w(t0, t1))
        elif t0 >= 400.0 and t1 <= 800.0:
            np.testing.assert_allclose(heat[k], resting)
            assert np.abs(duty.step_power_w(t0, t1) - resting).sum() > 1.0
        elif t0 >= 40.0 and t1 <= 400.0:
            np.testing.assert_allclose(heat[k], moving)


def _identified_heat(data: Path, run_id: int) -> dict[str, float]:
    refit = calibrated(data, run_id, "paused")["identified"]["refit"]
    return {p["name"]: p["value"] for p in refit["parameters"] if p["name"].startswith("heat:")}


@pytest.mark.slow
def test_identification_of_a_paused_program_recovers_the_truths_heat(tmp_path: Path) -> None:
    """Two hours of the UR bench's program paused from 0.5 h to 1.25 h, its shoulder and elbow
    heating x1.4 (benchmarks/ur_recorded.py, accelerated): identified on the recorded measured
    heat, the heat factors of the joints that work (1-3) are the truth's within 8 %; on the same
    run with the heat column emptied (the duty cycle's heat, the reference) they are bent to
    explain the pause's cooling, twice as far off at least and more than 15 %."""
    truth_scales = (1.0, 1.4, 1.4, 1.0, 1.0, 1.0)
    measured, duty = tmp_path / "measured", tmp_path / "duty"
    controller = emulated(1, {"motion_step_s": FAST_MOTION_STEP_S, "heat_scales": truth_scales})
    run_id, _ = record_calibration_run(
        ur_calibration_settings(measured),
        controller,
        measured,
        hours=2.0,
        measure_every_s=300.0,
        pauses=((0.5 * 3600.0, 1.25 * 3600.0),),
    )
    shutil.copytree(measured, duty)
    with closing(sqlite3.connect(duty / DATABASE_NAME)) as db:
        assert db.execute("SELECT count(heat_json) FROM steps").fetchone()[0] > 100
        db.execute("UPDATE steps SET heat_json = NULL")
        db.commit()
    errors = {}
    for label, data in (("measured", measured), ("duty-cycle", duty)):
        heat = _identified_heat(data, run_id)
        errors[label] = max(abs(heat[f"heat:{j}"] / truth_scales[j - 1] - 1.0) for j in (1, 2, 3))
    assert errors["measured"] < 0.08, errors
    assert errors["duty-cycle"] > max(0.15, 2.0 * errors["measured"]), errors


class _Constant:
    """A fallback heat source of constant power."""

    def __init__(self, power: list[float]) -> None:
        self.power = np.array(power)

    def step_power_w(self, t0_s: float, t1_s: float) -> np.ndarray[Any, Any]:
        return self.power.copy()


def test_recorded_heat_is_the_time_weighted_record_and_the_fallback_in_its_gaps() -> None:
    record = RecordedHeat(_Constant([1.0, 0.0]), 2)
    record.hold(10.0, 20.0, [3.0, 1.0])
    record.hold(20.0, 30.0, [5.0, 2.0])
    record.hold(40.0, 50.0, [7.0, 4.0])  # a gap 30-40 s: the fallback's
    np.testing.assert_allclose(record.step_power_w(40.0, 50.0), [7.0, 4.0])  # as held
    np.testing.assert_allclose(record.step_power_w(15.0, 25.0), [4.0, 1.5])
    expected = (5 * 1.0 + 10 * 3.0 + 10 * 5.0 + 10 * 1.0 + 10 * 7.0 + 10 * 1.0) / 55.0
    assert record.step_power_w(5.0, 60.0)[0] == pytest.approx(expected)
    assert record.covered_s == 30.0
    with pytest.raises(ValueError, match="before the last one's end"):
        record.hold(45.0, 55.0, [1.0, 1.0])
    with pytest.raises(ValueError, match="finite joint powers"):
        record.hold(50.0, 60.0, [math.nan, 1.0])


def test_measured_heat_of_the_played_cycle_is_the_duty_cycles_heat() -> None:
    """The packages of the taught cycle played without pauses (125 Hz, as the UR bench's
    driver receives them) give the duty cycle's own heat per joint over whole cycles (the
    same motor model); a gap in the packages holds the heat of the package after it; a
    controller clock that goes back restarts the integration."""
    controller = emulated(1, {})
    arm, duty = controller.arm, controller.duty
    heat = MeasuredHeat(arm, duty.payload_kg)
    times = np.arange(0.0, 3 * duty.period_s + 1e-9, 1 / 125)
    q, qd, qdd = duty.state(times)
    heat.add(MotionSamples(times, q, qd, qdd))
    mean = heat.take_mean_w()
    assert mean is not None
    profile = JointHeatProfile.from_duty(arm, duty, resolution_s=0.005)
    np.testing.assert_allclose(mean, profile.mean_power_w, rtol=2e-3, atol=1e-6)
    # 30 s without packages, then the arm at rest: the gap is the rest's heat
    rest_t = np.array([times[-1] + 30.0, times[-1] + 30.5])
    rest = np.repeat(q[-1:], 2, axis=0)
    still = np.zeros_like(rest)
    heat.add(MotionSamples(rest_t, rest, still, still))
    rest_w = heat.take_mean_w()
    assert rest_w is not None and heat.gaps == 1
    expected = joint_heat_batch_w(arm, rest[:1], still[:1], still[:1], payload_kg=duty.payload_kg)
    np.testing.assert_allclose(rest_w, expected[0], rtol=1e-9, atol=1e-12)
    heat.add(MotionSamples(np.array([1.0]), rest[:1], still[:1], still[:1]))
    assert heat.clock_resets == 1
