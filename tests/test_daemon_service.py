"""The daemon's run cycle against small fake devices (test doubles of drivers/base.py).

With a noise-free fake robot the compensated spot must stay put (the analytic oracle of
tests/fakes.py): drift = truth deformation + robot displacement = d - scale * d / scale = 0.
"""

from __future__ import annotations

import asyncio
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from daemon.model import ThermalModel, load_network
from daemon.run.states import RunState, RunStateError
from daemon.service import RunConflictError, RunParameterError
from daemon.storage.recorder import Recorder, RecorderError
from daemon.storage.report_queue import ReportStatus
from tests.fakes import GOAL, HEAT_W, SHAPE, Harness, make_settings, params


async def test_compensated_run_keeps_the_spot_still_and_records_every_step(
    tmp_path: Path,
) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        info = await daemon.start_run(params(settings))
        final = await daemon.wait_run()
        recorder = daemon.recorder
        assert recorder is not None
        steps = recorder.steps(info["id"])
        row = recorder.run(info["id"])
    assert final["state"] == "finished"
    assert [s.step for s in steps] == list(range(60))
    assert [s.scheduled_s for s in steps] == [float(k) for k in range(60)]
    predicted = np.array([s.predicted_x_um for s in steps], dtype=float)
    offsets = np.array([s.offset_x_mm for s in steps], dtype=float)
    np.testing.assert_allclose(offsets, -predicted / 1000.0)  # thesis 6.4.1: -y(t)
    assert predicted[-1] > 30.0  # the link really grew
    residual = np.array([s.residual_um for s in steps], dtype=float)
    # noise-free frames: only quantisation and the centroid's own error remain
    assert np.max(np.abs(residual)) < 0.5
    assert all(s.flags == "" and s.error == "" for s in steps)
    assert row is not None and row.state == "finished"
    summary = row.summary
    assert summary is not None and summary["n"] == 60
    assert summary["uncompensated_max_um"] == pytest.approx(predicted.max())
    # no reference run named: relative to the prediction only, and labelled so
    assert summary["reduction_basis"] == "prediction" and summary["reduction_percent"] is None
    assert summary["reduction_vs_prediction_percent"] > 98.0
    # without the moves the spot would have drifted by the whole deformation
    assert summary["uncompensated_measured_max_um"] == pytest.approx(predicted.max(), abs=0.5)
    assert all(kind == "absolute" for kind, _ in harness.robot.commands)


async def test_a_camera_without_a_gain_flags_the_steps_it_measured_its_own(
    tmp_path: Path,
) -> None:
    """A GenICam camera gives no gain (issue 30): the centroid measures it on each frame, and
    every measured step says so (flag gain-from-frame); the run is otherwise the same."""
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    harness.camera_gain_e_per_count = None
    async with harness.daemon as daemon:
        info = await daemon.start_run(params(settings))
        await daemon.wait_run()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    assert steps and all(s.flags == "gain-from-frame" and s.error == "" for s in steps)
    assert all(s.centroid_x_px is not None for s in steps)


async def test_without_compensation_the_spot_drifts_with_the_deformation(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        info = await daemon.start_run(params(settings, compensation="off", duration_s=30.0))
        await daemon.wait_run()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    assert harness.robot.commands == []  # stationary and off: nothing is moved
    drift = np.array([s.drift_x_um for s in steps], dtype=float)
    truth = np.array([s.predicted_x_um for s in steps], dtype=float)
    np.testing.assert_allclose(drift, truth, atol=0.5)


async def test_incremental_mode_sends_the_differences_of_the_offsets(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        info = await daemon.start_run(
            params(settings, compensation="incremental", duration_s=10, deformation_scale=10.0)
        )
        await daemon.wait_run()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    sent = np.array([delta for _, delta in harness.robot.commands])
    offsets = np.array([[s.offset_x_mm, s.offset_y_mm, s.offset_z_mm] for s in steps])
    np.testing.assert_allclose(np.cumsum(sent, axis=0), offsets, atol=1e-12)


async def test_unsafe_target_never_reaches_the_robot_and_pauses_the_run(tmp_path: Path) -> None:
    # a 1 um step limit: the deformation grows ~0.6 um/s, so with scale 10 step 1 is refused
    settings = make_settings(tmp_path, compensation={"max_step_change_mm": 0.001})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        info = await daemon.start_run(params(settings, deformation_scale=10.0))
        assert await daemon.wait_state(RunState.PAUSED) is RunState.PAUSED
        snapshot = daemon.snapshot()
        assert "max_step_change_mm" in snapshot["run"]["reason"]
        commands = list(harness.robot.commands)
        final = await daemon.stop()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    assert len(commands) == 1  # step 0 (zero offset) only
    assert steps[-1].flags == "unsafe-target" and "max_step_change_mm" in steps[-1].error
    assert steps[-1].pose_x_mm is None
    assert final["state"] == "stopped" and final["reason"] == "stopped by request"


async def test_device_fault_parks_the_run_until_an_explicit_resume(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        harness.robot.fail_moves = {5}
        info = await daemon.start_run(params(settings, duration_s=20.0))
        await daemon.wait_state(RunState.FAULT)
        moves_at_fault = len(harness.robot.commands)
        await asyncio.sleep(0.01)  # the loop stays parked: no motion on its own
        assert len(harness.robot.commands) == moves_at_fault
        assert daemon.snapshot()["state"] == "fault"
        assert "no answer to move 5" in daemon.snapshot()["run"]["reason"]
        reads_before = harness.robot.pose_reads
        await daemon.resume()
        assert harness.robot.resumes == 1 and harness.robot.pose_reads == reads_before + 1
        final = await daemon.wait_run()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
        errors = daemon.snapshot()["errors"]
    assert final["state"] == "finished"
    faulted = [s for s in steps if "robot-error" in s.flags]
    assert len(faulted) == 1 and faulted[0].step == 5
    assert errors[0]["kind"] == "timeout" and errors[0]["device"] == "robot"
    # after the resume each target is still absolute: offset = -predicted, pose follows it
    after = [s for s in steps if s.step > 5]
    assert after and all(
        s.pose_x_mm == pytest.approx(GOAL.x + (s.offset_x_mm or 0.0)) for s in after
    )
    assert [s.step for s in steps] == list(range(len(steps)))


async def test_one_run_at_a_time(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        await daemon.start_run(params(settings))
        with pytest.raises(RunConflictError, match="one run at a time"):
            await daemon.start_run(params(settings))
        await daemon.stop()
        second = await daemon.start_run(params(settings, duration_s=3.0))
        assert (await daemon.wait_run())["id"] == second["id"]


async def test_pause_resume_stop_and_events(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, bench={"clock": "real"})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        with daemon.subscribe(maxsize=1000) as events:
            await daemon.start_run(params(settings, duration_s=600.0))
            await daemon.wait_state(RunState.RUNNING)
            with pytest.raises(RunStateError):
                await daemon.resume()
            await daemon.pause()
            await daemon.resume()
            final = await daemon.stop()
            kinds: list[tuple[str, Any]] = []
            while (event := events.get_nowait()) is not None:
                kinds.append((event.kind, event.data.get("state")))
    states = [state for kind, state in kinds if kind == "state"]
    assert states == ["starting", "running", "paused", "running", "stopping", "stopped"]
    assert final["state"] == "stopped" and final["reason"] == "stopped by request"
    with pytest.raises(RunStateError):
        await daemon.pause()


async def test_a_slow_subscriber_loses_the_oldest_events(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        with daemon.subscribe(maxsize=4, kinds=frozenset({"step"})) as slow:
            await daemon.start_run(params(settings, duration_s=10.0))
            await daemon.wait_run()
            assert slow.dropped == 6
            steps = [(await slow.get()).data["step"] for _ in range(4)]
    assert steps == [6, 7, 8, 9]


async def test_inadmissible_scale_is_refused_before_anything_moves(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        with pytest.raises(RunParameterError, match="largest admissible scale"):
            await daemon.start_run(params(settings, deformation_scale=500.0, duration_s=3600.0))
        assert harness.robot.commands == [] and daemon.run is None


async def test_stale_frames_are_flagged_and_not_used(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, camera={"max_age_s": 0.5})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        assert harness.devices is not None
        harness.devices.camera.age_s = 1.0
        info = await daemon.start_run(params(settings, duration_s=3.0))
        await daemon.wait_run()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    assert all(s.flags == "stale-frame" and s.residual_um is None for s in steps)
    assert all(s.centroid_x_px is not None for s in steps)


async def test_crashed_run_is_interrupted_on_the_next_start(tmp_path: Path) -> None:
    settings = make_settings(tmp_path)
    with Recorder(tmp_path) as recorder:
        left = recorder.create_run({}, {}, None, "0", state="running")
    harness = Harness(settings)
    async with harness.daemon as daemon:
        assert daemon.recorder is not None
        row = daemon.recorder.run(left)
        assert row is not None and row.state == "interrupted"


async def test_shutdown_mid_run_stops_it_and_holds_the_robot(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, bench={"clock": "real"})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        info = await daemon.start_run(params(settings, duration_s=600.0))
        await daemon.wait_state(RunState.RUNNING)
    assert harness.robot.held
    with Recorder(tmp_path) as recorder:
        row = recorder.run(info["id"])
    assert row is not None and row.state == "stopped" and row.reason == "daemon shut down"


async def test_a_nan_prediction_never_reaches_the_robot(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    real = ThermalModel.deformation_um

    def poisoned(model: ThermalModel) -> np.ndarray:
        return np.array([math.nan, 0.0, 0.0]) if model.time_s >= 3.0 else real(model)

    monkeypatch.setattr(ThermalModel, "deformation_um", poisoned)
    async with harness.daemon as daemon:
        await daemon.start_run(params(settings))
        await daemon.wait_state(RunState.PAUSED)
        reason = daemon.snapshot()["run"]["reason"]
        await daemon.stop()
    assert "not finite" in reason
    assert len(harness.robot.commands) == 3  # steps 0, 1, 2; the fake robot asserts finiteness


async def test_an_unwritable_recording_stops_the_run_and_holds_the_robot(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        recorder = daemon.recorder
        assert recorder is not None
        write_step = recorder.write_step

        def failing(record: Any) -> None:
            if record.step >= 4:
                raise RecorderError("database or disk is full")
            write_step(record)

        monkeypatch.setattr(recorder, "write_step", failing)
        info = await daemon.start_run(params(settings))
        final = await daemon.wait_run()
        errors = daemon.snapshot()["errors"]
        steps = recorder.steps(info["id"])
    assert final["state"] == "aborted" and "disk is full" in final["reason"]
    assert harness.robot.held
    assert errors[-1]["device"] == "storage"
    assert [s.step for s in steps] == [0, 1, 2, 3]


async def test_overruns_skip_to_the_next_deadline_without_a_burst(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, bench={"clock": "real"})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        harness.robot.slow_moves = {3, 8}
        info = await daemon.start_run(params(settings, step_s=0.02, duration_s=2.0))
        final = await daemon.wait_run()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    summary = final["summary"]
    assert summary["overruns"] >= 2 and summary["skipped_deadlines"] >= 2 * 3
    slots = [round(s.scheduled_s / 0.02) for s in steps]
    assert slots == sorted(set(slots))  # every step has its own deadline: no burst
    for slow in (3, 8):  # the step after a slow one starts at a later deadline, not at once
        assert slots[slow + 1] - slots[slow] >= 4  # 70 ms = 3.5 periods: 3 deadlines lost
    assert [s.step for s in steps] == list(range(len(steps)))


async def test_every_nth_frame_is_archived_beside_the_database(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, storage={"archive_every": 2})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        with daemon.subscribe(kinds=frozenset({"frame"})) as frames:
            info = await daemon.start_run(params(settings, duration_s=5.0))
            await daemon.wait_run()
            live = [(await frames.get()).data for _ in range(5)]
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    # every frame is also published live, with the centroid measured in it
    assert [f["step"] for f in live] == [0, 1, 2, 3, 4]
    assert all(f["image"].shape == SHAPE for f in live)
    assert live[3]["centroid_x_px"] == steps[3].centroid_x_px
    archived = [s.step for s in steps if s.frame_path is not None]
    assert archived == [0, 2, 4]
    assert all((tmp_path / str(s.frame_path)).is_file() for s in steps if s.frame_path)


async def test_stop_abandons_a_step_stuck_on_a_device_after_the_grace_period(
    tmp_path: Path,
) -> None:
    settings = make_settings(tmp_path, scheduler={"stop_grace_s": 0.1})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        harness.robot.hung_moves = {2}
        info = await daemon.start_run(params(settings))
        await harness.robot.hanging.wait()
        final = await daemon.stop()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    assert final["state"] == "stopped" and "abandoned" in final["reason"]
    assert harness.robot.held
    assert [s.step for s in steps] == [0, 1]  # the abandoned step left nothing half-written


async def test_model_runs_ahead_by_the_latency_and_switches_heaters_exactly(
    tmp_path: Path,
) -> None:
    settings = make_settings(tmp_path, compensation={"latency_s": 0.25})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        info = await daemon.start_run(params(settings, duration_s=15.0, heater_off_s=10.6))
        await daemon.wait_run()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    # the oracle: one exact model, heaters on until 10.6 s, then off
    reference = ThermalModel(load_network("thesis-two-link"), "exact", 0.05, 22.0)
    expected = {}
    for step in range(15):
        t = step + 0.25
        if reference.time_s < 10.6 <= t:
            reference.set_heat(HEAT_W)
            reference.advance_to(10.6)
            reference.set_heat({})
        elif t <= 10.6:
            reference.set_heat(HEAT_W)
        reference.advance_to(t)
        expected[step] = reference.deformation_um_scalar()
    assert [s.model_time_s for s in steps] == [k + 0.25 for k in range(15)]
    for s in steps:
        assert s.predicted_x_um == pytest.approx(expected[s.step], rel=1e-9, abs=1e-12)


async def test_the_drift_reference_is_taken_before_the_first_move(tmp_path: Path) -> None:
    # step 0's move lands 3 um off: that is step 0's error, not an offset of every later step
    settings = make_settings(tmp_path)
    harness = Harness(settings)
    async with harness.daemon as daemon:
        harness.robot.position_errors_um = {0: 3.0}
        info = await daemon.start_run(params(settings, duration_s=5.0))
        final = await daemon.wait_run()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    assert final["summary"]["reference"]["source"] == "goal before the first move"
    residual = [s.residual_um for s in steps]
    assert residual[0] == pytest.approx(3.0, abs=0.3)
    assert all(abs(r or 0.0) < 0.3 for r in residual[1:])


@pytest.mark.slow
async def test_the_report_is_written_at_the_end_of_a_run(tmp_path: Path) -> None:
    settings = make_settings(tmp_path, storage={"report_at_end": True})
    harness = Harness(settings)
    async with harness.daemon as daemon:
        info = await daemon.start_run(params(settings, duration_s=5.0))
        await daemon.wait_run()
        # written after the run ended, by the daemon's report queue (never by a reader)
        assert await daemon.reports.wait(info["id"]) is ReportStatus.WRITTEN
        report = daemon.reports.html_path(info["id"])
    assert report.is_file() and report.is_relative_to(tmp_path)
