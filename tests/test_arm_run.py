"""Arm runs (issue 20) through the daemon on exact fakes: the 6-DOF correction checks (a
correction over a limit never reaches the robot's writer), a hold during an arm step, the
recorded 6-DOF prediction/correction/measurement against an analytic truth, the summary.

The fake arm's truth is the fake predictor's own law with its rates scaled by TRUTH_FACTOR:
the tool error grows linearly in time at each pose, so an uncompensated run's drift is exactly
that law and a compensated run's residual is exactly ``1 - 1/TRUTH_FACTOR`` of it (the
correction cancels the predicted part). Synchronisation is by gates, never by sleeping.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Self

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from config import Settings
from daemon.arm.correction import CorrectionLimits, check_correction, correction_for
from daemon.arm.run import MeasuredPose, ToolMeasurement
from daemon.arm.types import Pose6
from daemon.model.compensation import UnsafeTargetError
from daemon.run.arm.setup import ArmPlan
from daemon.run.arm.work import ToolMeter
from daemon.run.devices_check import Devices
from daemon.run.states import RunParameters, RunState
from daemon.run.workers import Workers
from daemon.service import Daemon, RunParameterError
from drivers.base import DEFAULT_GOAL, GoalRobot
from drivers.clock import Clock, make_clock
from tests.fakes import FakeBench, FakeCamera, FakeIr, Gate, OpenedDevices
from tests.fakes_arm import (
    POSES,
    TRUTH_FACTOR,
    ArmTruth,
    FakeArmRobot,
    error_law,
)

WAIT_S = 30.0
STEP_S = 10.0
DURATION_S = 200.0  # 20 steps, 10 per pose


def pose6(translation_mm: Any, rotation_rad: Any) -> Pose6:
    return Pose6(np.array(translation_mm, dtype=float), np.array(rotation_rad, dtype=float))


async def until(condition: Callable[[], bool]) -> None:
    """Yield to the loop until ``condition()`` holds (bounded by WAIT_S)."""
    async with asyncio.timeout(WAIT_S):
        while not condition():  # noqa: ASYNC110 -- the conditions are plain attributes
            await asyncio.sleep(0)


def _matrix(move: Pose6) -> np.ndarray:
    # a copy: SciPy refuses Pose6's read-only arrays
    matrix: np.ndarray = Rotation.from_rotvec(np.array(move.rotation_rad)).as_matrix()
    return matrix


def displaced(pose: np.ndarray, *moves: Pose6) -> np.ndarray:
    """``pose`` moved by each Pose6 (base frame: R' = exp(r) R, t' = t + dt)."""
    result = np.array(pose, dtype=float)
    for move in moves:
        result[:3, :3] = _matrix(move) @ result[:3, :3]
        result[:3, 3] += move.translation_mm
    return result


class FakePredictor:
    """The controller's model: the error law at model time."""

    def __init__(self, rotation_factor: float = 1.0) -> None:
        self.time_s = 0.0
        self.rotation_factor = rotation_factor

    def advance_to(self, t_s: float) -> None:
        self.time_s = t_s

    def tool_error(self, pose: MeasuredPose) -> Pose6:
        error = error_law(pose.name, self.time_s)
        return Pose6(error.translation_mm, self.rotation_factor * error.rotation_rad)

    def temperatures_c(self) -> Mapping[str, float]:
        return {"link-1": 22.0 + self.time_s / 100.0}


class FakeMeter:
    """The tool's pose as the truth and the last move make it, measured exactly."""

    def __init__(self, robot: FakeArmRobot) -> None:
        self.robot = robot
        self.measurements = 0

    async def measure(
        self, expected_pose: np.ndarray, frames: int | None = None
    ) -> ToolMeasurement:
        robot = self.robot
        assert robot.goal is not None
        nominal = next(p.tool_pose for p in POSES if p.name == robot.goal)
        np.testing.assert_array_equal(expected_pose, nominal)
        self.measurements += 1
        pose = displaced(nominal, robot.correction, robot.truth.error(robot.goal))
        return ToolMeasurement(pose, 0.001, True, {"cam-0": ((1.0, 2.0),)})


class FakeArmDevices(OpenedDevices):
    def __init__(self, clock: Clock) -> None:
        self.bench = ArmTruth(clock)
        self.robot = FakeArmRobot(self.bench)
        self.camera = FakeCamera(FakeBench(clock, {}))  # the two-link camera: unused by arm runs
        self.ir = FakeIr(clock)


class ArmHarness:
    def __init__(self, settings: Settings, predictor: Callable[[], FakePredictor]) -> None:
        self.clock = make_clock(settings.bench.clock, settings.bench.time_factor)
        self.devices: FakeArmDevices | None = None
        self.meter: FakeMeter | None = None
        self.setups: list[str] = []
        self._predictor = predictor
        self.daemon = Daemon(
            settings,
            clock=self.clock,
            open_devices=self._open,
            arm_setup=self._setup,
            arm_meter=self._meter,
        )

    def _open(self, settings: Settings, clock: Clock) -> FakeArmDevices:
        self.devices = FakeArmDevices(clock)
        return self.devices

    def _setup(self, settings: Settings, parameters: RunParameters) -> ArmPlan:
        assert parameters.duty_cycle is not None
        self.setups.append(parameters.duty_cycle)
        return ArmPlan(self._predictor(), POSES, {"arm": "fake"})

    def _meter(self, settings: Settings, devices: Devices, workers: Workers) -> ToolMeter:
        assert self.devices is not None
        self.meter = FakeMeter(self.devices.robot)
        return self.meter

    @property
    def robot(self) -> FakeArmRobot:
        assert self.devices is not None
        return self.devices.robot


def arm_settings(tmp_path: Path, **arm: Any) -> Settings:
    return Settings.model_validate(
        {
            "storage": {"data_dir": str(tmp_path), "report_at_end": False},
            "scheduler": {"duration_s": DURATION_S, "step_s": STEP_S},
            "arm": {"enabled": True, "duty_cycle": "pick-and-place.toml", **arm},
        }
    )


async def run_to_end(
    harness: ArmHarness, **overrides: Any
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    daemon = harness.daemon
    parameters = RunParameters.from_settings(daemon.settings, **overrides)
    info = await daemon.start_run(parameters)
    async with asyncio.timeout(WAIT_S):
        final = await daemon.wait_run()
    assert daemon.recorder is not None
    steps = [record.as_dict() for record in daemon.recorder.steps(info["id"])]
    return final, steps


# --- the pure checks ------------------------------------------------------------------------

LIMITS = CorrectionLimits(
    max_translation_mm=1.0,
    max_rotation_deg=0.1,
    max_step_translation_mm=0.2,
    max_step_rotation_deg=0.05,
)


def test_correction_cancels_the_error_and_scales_both_parts() -> None:
    error = pose6((0.01, -0.02, 0.03), (1e-5, 0.0, -2e-5))
    correction = correction_for(error, 2.0)
    np.testing.assert_allclose(correction.translation_mm, (-0.02, 0.04, -0.06))
    np.testing.assert_allclose(correction.rotation_rad, (-2e-5, 0.0, 4e-5))
    assert check_correction(correction, Pose6.zero(), LIMITS) is correction


@pytest.mark.parametrize(
    ("correction", "previous", "limit"),
    [
        # 0.11 deg of rotation: over max_rotation_deg 0.1 (its step from 0.07 deg is fine)
        (
            pose6((0, 0, 0), (0, 0, math.radians(0.11))),
            pose6((0, 0, 0), (0, 0, math.radians(0.07))),
            "arm.max_rotation_deg",
        ),
        # a step of 0.06 deg about x: over max_step_rotation_deg 0.05
        (pose6((0, 0, 0), (math.radians(0.06), 0, 0)), Pose6.zero(), "arm.max_step_rotation_deg"),
        (
            pose6((0.9, 0.5, 0), (0, 0, 0)),
            pose6((0.8, 0.4, 0), (0, 0, 0)),
            "arm.max_translation_mm",
        ),
        (pose6((0.15, 0.15, 0), (0, 0, 0)), Pose6.zero(), "arm.max_step_translation_mm"),
    ],
)
def test_correction_over_a_limit_is_refused_naming_it(
    correction: Pose6, previous: Pose6, limit: str
) -> None:
    with pytest.raises(UnsafeTargetError, match=limit):
        check_correction(correction, previous, LIMITS)


def test_the_limits_are_inclusive_and_per_norm() -> None:
    # exactly at each limit passes; the norm, not each component, is bounded
    at_limit = pose6((0.6, 0.8, 0.0), (0.0, 0.0, math.radians(0.05)))
    previous = pose6(np.array([0.6, 0.8, 0.0]) - np.array([0.12, 0.16, 0.0]), (0.0, 0.0, 0.0))
    check_correction(at_limit, previous, LIMITS)
    with pytest.raises(UnsafeTargetError, match=r"arm\.max_translation_mm"):
        check_correction(
            pose6((0.6, 0.8, 0.01), (0, 0, 0)), pose6((0.6, 0.8, 0), (0, 0, 0)), LIMITS
        )


# --- through the daemon -----------------------------------------------------------------------


async def test_uncompensated_arm_run_records_the_truth_drift(tmp_path: Path) -> None:
    harness = ArmHarness(arm_settings(tmp_path), FakePredictor)
    async with harness.daemon:
        final, steps = await run_to_end(harness, compensation="off")
    assert final["state"] == "finished" and harness.setups == ["pick-and-place.toml"]
    robot = harness.robot
    # each measured pose taught (a move), then measured at its goal before the first step
    assert list(robot.taught) == ["opgoal", "pick", "place"]
    # each reached by one move from where the robot stood (opgoal), then measured at its goal
    start = np.eye(4)
    start[:3, 3] = (400.0, 0.0, 300.0)
    teaching = [c for goal, c in robot.written[:2]]
    assert [goal for goal, _ in robot.written[:4]] == ["opgoal", "opgoal", "pick", "place"]
    for move, pose in zip(teaching, POSES, strict=True):
        np.testing.assert_allclose(move.translation_mm, pose.tool_pose[:3, 3] - start[:3, 3])
        turned = Rotation.from_rotvec(np.array(move.rotation_rad)).as_matrix()
        np.testing.assert_allclose(turned, pose.tool_pose[:3, :3], atol=1e-12)
        assert robot.taught[pose.name].position == tuple(pose.tool_pose[:3, 3])
    assert len(steps) == DURATION_S / STEP_S
    assert harness.devices is not None and harness.devices.bench.duty_cycles == [
        "pick-and-place.toml"
    ]
    for record in steps:
        name = record["arm_pose"]
        assert name == POSES[record["step"] % 2].name
        t = record["scheduled_s"]
        truth = error_law(name, t, TRUTH_FACTOR)
        predicted = error_law(name, t)
        np.testing.assert_allclose(
            [record[f"predicted_t{a}_um"] for a in "xyz"],
            1000 * predicted.translation_mm,
            atol=1e-9,
        )
        np.testing.assert_allclose(
            [record[f"predicted_r{a}_urad"] for a in "xyz"], 1e6 * predicted.rotation_rad, atol=1e-6
        )
        assert [record[f"correction_t{a}_mm"] for a in "xyz"] == [0.0, 0.0, 0.0]
        np.testing.assert_allclose(
            [record[f"measured_t{a}_um"] for a in "xyz"], 1000 * truth.translation_mm, atol=1e-6
        )
        np.testing.assert_allclose(
            [record[f"measured_r{a}_urad"] for a in "xyz"], 1e6 * truth.rotation_rad, atol=1e-4
        )
        assert record["drift_3d_um"] == pytest.approx(1000 * truth.translation_norm_mm, abs=1e-6)
        assert record["rotation_error_urad"] == pytest.approx(
            1e6 * truth.rotation_angle_rad, abs=1e-4
        )
        assert record["flags"] == ""
    summary = final["summary"]
    last = error_law(steps[-1]["arm_pose"], steps[-1]["scheduled_s"], TRUTH_FACTOR)
    assert summary["drift_3d_max_um"] == pytest.approx(1000 * last.translation_norm_mm, rel=1e-6)
    assert summary["reduction_basis"] == "drift"
    assert set(summary["per_pose"]) == {"pick", "place"}


async def test_compensated_arm_run_leaves_the_model_error_only(tmp_path: Path) -> None:
    harness = ArmHarness(arm_settings(tmp_path), FakePredictor)
    async with harness.daemon:
        off, off_steps = await run_to_end(harness, compensation="off")
        final, steps = await run_to_end(harness, compensation="absolute", reference_run=off["id"])
    assert final["state"] == "finished"
    moves = [(goal, c) for goal, c in harness.robot.written if goal != DEFAULT_GOAL]
    for record in steps:
        t, name = record["scheduled_s"], record["arm_pose"]
        predicted = error_law(name, t)
        np.testing.assert_allclose(
            [record[f"correction_t{a}_mm"] for a in "xyz"], -predicted.translation_mm, atol=1e-12
        )
        # the residual is what the model missed: (TRUTH_FACTOR - 1) of the prediction
        residual = error_law(name, t, TRUTH_FACTOR - 1.0)
        assert record["drift_3d_um"] == pytest.approx(1000 * residual.translation_norm_mm, abs=1e-6)
        assert record["rotation_error_urad"] == pytest.approx(
            1e6 * residual.rotation_angle_rad, abs=1e-4
        )
    # every correction sent was the checked one of its step (and the references' zeros)
    sent = [c for goal, c in moves if np.any(c.as_array() != 0)]
    assert len(sent) == len(steps) - 1  # step 0 predicts a zero error
    summary = final["summary"]
    assert summary["reduction_basis"] == "reference"
    expected = 100 * (1 - (TRUTH_FACTOR - 1) / TRUTH_FACTOR)
    assert summary["reduction_3d_percent"] == pytest.approx(expected, rel=1e-6)
    assert summary["reduction_rotation_percent"] == pytest.approx(expected, rel=1e-4)
    ratio = TRUTH_FACTOR / (TRUTH_FACTOR - 1)  # same-seed uncompensated drift / residual
    assert off_steps[-1]["drift_3d_um"] == pytest.approx(ratio * steps[-1]["drift_3d_um"])


async def test_correction_over_the_rotation_limit_never_reaches_the_writer(
    tmp_path: Path,
) -> None:
    # the model's rotation is 1000 x the truth's: 0.1 deg is reached near 87 s (step 9)
    settings = arm_settings(tmp_path, max_rotation_deg=0.1, max_step_rotation_deg=1.0)
    harness = ArmHarness(settings, lambda: FakePredictor(rotation_factor=1000.0))
    async with harness.daemon:
        daemon = harness.daemon
        await daemon.start_run(RunParameters.from_settings(settings))
        async with asyncio.timeout(WAIT_S):
            state = await daemon.wait_state(RunState.PAUSED)
        assert state is RunState.PAUSED
        view = daemon.run
        assert view is not None and "arm.max_rotation_deg" in (view.reason or "")
        refused = view.last_record
        assert refused is not None and "unsafe-target" in refused["flags"]
        angle = math.hypot(*(refused[f"predicted_r{a}_urad"] for a in "xyz")) * 1e-6 * 1000
        assert math.degrees(angle) > 0.1
        # nothing over the limit was written, and the refused step's move was not written
        moves = [c for g, c in harness.robot.written if g != DEFAULT_GOAL]  # not teaching
        for correction in moves:
            assert math.degrees(correction.rotation_angle_rad) <= 0.1
        assert len(moves) == len(POSES) + refused["step"]  # references + steps before it
        await daemon.stop()


async def test_a_hold_during_an_arm_step_refuses_its_move(tmp_path: Path) -> None:
    harness = ArmHarness(arm_settings(tmp_path), FakePredictor)
    async with harness.daemon:
        daemon = harness.daemon
        await daemon.start_run(RunParameters.from_settings(daemon.settings))
        async with asyncio.timeout(WAIT_S):
            await daemon.wait_state(RunState.RUNNING)
        await until(lambda: daemon.run is not None and daemon.run.step >= 2)
        gate = Gate()
        harness.robot.move_gate = gate  # set with no await since: the next step's move
        async with asyncio.timeout(WAIT_S):
            await gate.reached.wait()  # the move is on its way to the writer
        assert daemon.run is not None
        gated_step = daemon.run.step + 1
        written = len(harness.robot.written)
        await daemon.hold_robot("operator hold")
        gate.open()
        await until(lambda: daemon.run is not None and daemon.run.step >= gated_step)
        assert len(harness.robot.written) == written  # the move was refused under the lock
        view = daemon.run
        assert view is not None and view.state is RunState.PAUSED
        assert view.last_record is not None and "robot-error" in view.last_record["flags"]
        assert harness.meter is not None
        await daemon.stop()
    assert len(harness.robot.written) == written  # and nothing moved after it either


async def test_arm_run_needs_the_arm_section(tmp_path: Path) -> None:
    settings = arm_settings(tmp_path, enabled=False)
    harness = ArmHarness(settings, FakePredictor)
    async with harness.daemon:
        parameters = RunParameters.from_settings(settings, duty_cycle="cycle.toml")
        with pytest.raises(RunParameterError, match=r"arm\.enabled"):
            await harness.daemon.start_run(parameters)
        assert harness.robot.written == []


def test_arm_run_parameters_refuse_incremental_and_procedures() -> None:
    with pytest.raises(ValueError, match="absolute"):
        RunParameters(duty_cycle="c.toml", compensation="incremental")
    with pytest.raises(ValueError, match="stationary"):
        RunParameters(duty_cycle="c.toml", procedure="moving")
    assert RunParameters().duty_cycle is None
    assert RunParameters.from_settings(Settings()).duty_cycle is None


def test_fake_robot_is_a_goal_robot() -> None:
    robot: GoalRobot = FakeArmRobot(ArmTruth(make_clock("virtual")))
    assert robot.status().motion_held is False


# --- the real controller model (daemon/arm/controller.py) ------------------------------------


def test_controller_heats_from_the_duty_cycle_and_predicts_at_each_pose() -> None:
    from daemon.arm.controller import ArmModelOptions
    from daemon.arm.controller_loading import load_controller
    from daemon.arm.kinematics import forward, tool_error

    controller = load_controller(
        "config/arms/crs-a465.toml", "a465-pick-and-place", ArmModelOptions(model_dt_s=60.0)
    )
    poses = controller.measured_poses()
    assert [pose.name for pose in poses] == [p.name for p in controller.duty.measured_poses()]
    for pose in poses:
        np.testing.assert_array_equal(pose.tool_pose, forward(controller.arm, pose.q_rad))
        assert controller.tool_error(pose).translation_norm_mm == 0.0  # cold: no error
    # the mean heat over whole cycles is the cycle's energy over its period
    period = controller.duty.period_s
    np.testing.assert_allclose(
        controller.mean_heat_w(2 * period, 5 * period), controller.heat.mean_power_w, rtol=1e-9
    )
    controller.advance_to(3600.0)
    assert controller.time_s == 3600.0
    np.testing.assert_allclose(controller.last_heat_w, controller.mean_heat_w(0.0, 3600.0))
    for pose in poses:  # the links' present states at the pose's own configuration
        expected = tool_error(controller.arm, pose.q_rad, controller.thermal.link_states())
        np.testing.assert_array_equal(controller.tool_error(pose).as_array(), expected.as_array())
        assert controller.tool_error(pose).translation_norm_mm > 0.005  # warm after an hour
    temperatures = controller.temperatures_c()
    assert set(temperatures) == set(controller.thermal.node_names)
    assert max(temperatures.values()) > 22.5
    with pytest.raises(ValueError, match="nowhere"):
        controller.measured_poses(("camera", "nowhere"))
    assert [p.name for p in controller.measured_poses(("place",))] == ["place"]


# --- what the API, the exports and the report show of an arm run ------------------------------


@pytest.mark.slow
async def test_arm_run_through_the_api_exports_and_report(tmp_path: Path) -> None:
    import csv
    import io
    import json

    import httpx

    from api.app import create_app
    from daemon.storage.reports import write_run_report
    from tests.test_api_server import CONTROL, serve

    settings = arm_settings(tmp_path)
    settings = settings.model_copy(
        update={"api": settings.api.model_copy(update={"control_token": CONTROL})}
    )
    harness = ArmHarness(settings, FakePredictor)
    app = create_app(settings, service_factory=lambda _settings: harness.daemon)
    headers = {"Authorization": f"Bearer {CONTROL}"}
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=WAIT_S, headers=headers) as client,
    ):
        refused = await client.post("/api/v1/runs", json={"duty_cycle": "/etc/passwd"})
        assert refused.status_code == 422  # a preset name, never a path
        started = await client.post(
            "/api/v1/runs", json={"duty_cycle": "a465-pick-and-place", "compensation": "off"}
        )
        assert started.status_code in (200, 201), started.text
        run_id = started.json()["id"]
        async with asyncio.timeout(WAIT_S):
            await harness.daemon.wait_run()
        info = (await client.get(f"/api/v1/runs/{run_id}")).json()
        assert info["parameters"]["duty_cycle"] == "a465-pick-and-place"
        summary = info["summary"]
        truth = error_law("place", DURATION_S - STEP_S, TRUTH_FACTOR)
        assert summary["drift_3d_max_um"] == pytest.approx(1000 * truth.translation_norm_mm)
        assert summary["rotation_error_max_urad"] == pytest.approx(
            1e6 * truth.rotation_angle_rad, rel=1e-5
        )
        steps = (await client.get(f"/api/v1/runs/{run_id}/steps?format=json")).json()["steps"]
        last = steps[-1]
        assert last["arm_pose"] == "place"
        np.testing.assert_allclose(
            [last[f"measured_t{a}_um"] for a in "xyz"], 1000 * truth.translation_mm, atol=1e-6
        )
        text = (await client.get(f"/api/v1/runs/{run_id}/steps?format=csv")).text
        rows = list(csv.DictReader(io.StringIO(text)))
        assert float(rows[-1]["drift_3d_um"]) == pytest.approx(last["drift_3d_um"])
        assert float(rows[-1]["measured_rx_urad"]) == pytest.approx(last["measured_rx_urad"])
    files = await asyncio.to_thread(write_run_report, tmp_path, run_id, tmp_path / "report")
    report = json.loads(files.summary.read_text())
    assert report["arm"]["drift_3d_max_um"] == pytest.approx(summary["drift_3d_max_um"])
    assert "arm_drift" in files.plots and files.plots["arm_drift"].stat().st_size > 0
    assert "Whole arm: 3-D drift and rotation error" in files.html.read_text()


def test_a_database_without_the_arm_columns_is_read_and_exported_with_them(
    tmp_path: Path,
) -> None:
    """The 6-DOF columns are an additive change: a database of the version before them opens,
    its steps read back (the new columns empty), new arm steps are written beside them, and the
    export carries the new columns."""
    import csv
    import io
    import sqlite3

    from daemon.analysis.steps import ARM_COLUMNS
    from daemon.storage.recorder import DATABASE_NAME, STEP_COLUMNS, Recorder, StepRecord

    arm_columns = STEP_COLUMNS[STEP_COLUMNS.index("arm_pose") :]
    assert set(ARM_COLUMNS) <= set(arm_columns)
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({}, {}, None, "0.9")
        recorder.write_step(StepRecord(run_id, 0, 0.0, 0.0, 0.0, residual_um=1.5))
    with sqlite3.connect(tmp_path / DATABASE_NAME) as db:  # the schema before issue 20
        for column in arm_columns:
            db.execute(f"ALTER TABLE steps DROP COLUMN {column}")
        present = {row[1] for row in db.execute("PRAGMA table_info(steps)")}
    assert not present & set(arm_columns)
    with Recorder(tmp_path) as reopened:
        (old,) = reopened.steps(run_id)
        assert old.residual_um == 1.5 and old.drift_3d_um is None and old.arm_pose is None
        reopened.write_step(StepRecord(run_id, 1, 1.0, 1.0, 0.0, arm_pose="pick", drift_3d_um=12.5))
        rows = list(csv.DictReader(io.StringIO(reopened.export_csv(run_id))))
    assert list(rows[0]) == list(STEP_COLUMNS)
    assert rows[0]["drift_3d_um"] == "" and rows[1]["drift_3d_um"] == "12.5"
    assert rows[1]["arm_pose"] == "pick"


def test_thermocomp_run_prints_an_arm_runs_figures(capsys: pytest.CaptureFixture[str]) -> None:
    from daemon.commands.run import _print_result

    summary = {
        "kind": "arm",  # as every arm summary says (daemon/run/arm/summary.py)
        "arm_n": 12,
        "drift_3d_max_um": 66.5,
        "drift_3d_rms_um": 56.0,
        "rotation_error_max_urad": 119.9,
        "rotation_error_rms_urad": 87.3,
        "predicted_3d_max_um": 180.1,
        "measurement_sigma_um": 4.7,
        "reduction_basis": "reference",
        "reference_run": 1,
        "reduction_3d_percent": 44.2,
        "reduction_rotation_percent": 15.1,
        "overruns": 0,
    }
    _print_result({"id": 2, "state": "finished", "reason": None, "summary": summary}, False)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "run 2 finished"
    assert "3-D drift max" in lines[2] and lines[2].endswith("66.500 um")
    assert any(
        line.strip().startswith("3-D reduction vs run 1") and "44.200 %" in line for line in lines
    )
    assert not any("residual" in line for line in lines)  # not the two-link table


# --- the tool's 3-D measurement (daemon/run/arm/measure.py)
# ----------------------------------------


class _MarkerCamera:
    """A camera that renders the markers of ``pose`` (seeded noise)."""

    def __init__(self, model: Any, points: np.ndarray, seed: int) -> None:
        self.model, self.points = model, points
        self.rng = np.random.default_rng(seed)

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def grab(self) -> Any:
        from daemon.vision.markers import render_markers
        from drivers.base import Frame

        image = render_markers(self.model, self.points, rng=self.rng, sigma_px=2.0, bit_depth=12)
        return Frame(image, 12, 0.0, 0, "camera")  # type: ignore[arg-type]


async def test_the_meter_measures_a_known_displacement_of_the_tool() -> None:
    from daemon.arm.run import MeasurementError
    from daemon.run.arm.measure import MultiCameraMeter
    from daemon.vision.multiview import pose_difference
    from drivers.sim.arm_markers import CameraRig

    settings = Settings.model_validate({"camera": {"bit_depth": 12}})
    nominal = POSES[0].tool_pose
    shift = pose6((0.080, -0.050, 0.030), (2e-4, -1e-4, 3e-4))  # 100 um, 0.02 deg
    true_pose = displaced(nominal, shift)
    markers = np.array(settings.arm.markers_mm)
    world = markers @ true_pose[:3, :3].T + true_pose[:3, 3]
    models = CameraRig(width_px=1024, height_px=768, focal_px=2000.0).cameras(nominal[:3, 3])
    workers = Workers()
    try:
        meter = MultiCameraMeter(
            settings,
            [_MarkerCamera(m, world, k) for k, m in enumerate(models)],
            models,
            workers,
        )
        measured = await meter.measure(nominal)
        assert measured.oriented and len(measured.centroids_px) == len(models)
        error = pose_difference(true_pose, measured.pose)
        # within its own uncertainty (1.5 um off at a 10.9 um 1-sigma here; the shift is 100 um)
        assert error.translation_norm_mm * 1000 < 3 * measured.sigma_mm * 1000
        assert measured.sigma_mm * 1000 < 20.0
        assert error.rotation_angle_rad < 1e-4  # 37 urad here; the shift turns by 374 urad
        found = pose_difference(nominal, measured.pose)
        np.testing.assert_allclose(found.translation_mm, shift.translation_mm, atol=0.01)
        # one camera triangulates nothing, but sees the four markers: the pose by PnP
        # (daemon/vision/pnp.py), its depth along the camera's line of sight poorer
        alone = MultiCameraMeter(
            settings, [_MarkerCamera(models[0], world, 9)], models[:1], workers
        )
        single = await alone.measure(nominal)
        assert single.oriented and list(single.centroids_px) == [models[0].name]
        error = pose_difference(true_pose, single.pose)
        assert error.translation_norm_mm < 3 * single.sigma_mm
        assert single.sigma_mm > 2 * measured.sigma_mm  # depth from one camera: poorer
        assert error.rotation_angle_rad < 3e-4
        found = pose_difference(nominal, single.pose)
        np.testing.assert_allclose(found.translation_mm, shift.translation_mm, atol=0.05)
        # a camera that sees no marker measures nothing
        elsewhere = markers @ true_pose[:3, :3].T + true_pose[:3, 3] + [0.0, 0.0, 5000.0]
        blind = MultiCameraMeter(
            settings, [_MarkerCamera(models[0], elsewhere, 9)], models[:1], workers
        )
        with pytest.raises(MeasurementError, match="no pose from the views: 0 marker"):
            await blind.measure(nominal)
    finally:
        workers.shutdown()
