"""Averaging frames in a tool measurement (daemon/run/arm/measure.py, arm.frames_per_measurement):
the centroids' mean and the 1-sigma it is given, and the meter's pose noise over repeated
measurements of a still tool, against the 1/sqrt(frames) that independent frames give."""

from __future__ import annotations

import math
from typing import Any, Self

import numpy as np
import pytest

from config import Settings
from daemon.run.arm.measure import MarkerView, MultiCameraMeter, mean_views
from daemon.run.arm.robot import GoalRobotArm
from daemon.run.workers import Workers
from daemon.vision.multiview import pose_difference
from tests.fakes import FakeRobot

#: The image-plane jitter of the test's frames (px): the arm bench's order (0.03 px)
JITTER_PX = 0.05


def test_mean_views_averages_each_camera_and_marker_over_its_frames() -> None:
    frames = [
        [MarkerView("a", 0, 100.0, 50.0, 0.02), MarkerView("b", 0, 10.0, 20.0, 0.02)],
        [MarkerView("a", 0, 100.2, 50.2, 0.02)],  # marker 0 not found by camera b here
    ]
    by_key = {(v.camera, v.marker): v for v in mean_views(frames)}
    a, b = by_key["a", 0], by_key["b", 0]
    assert (a.x_px, a.y_px) == pytest.approx((100.1, 50.1))
    # two frames: the reported sigma over sqrt(2) (scatter is not used below three frames)
    assert a.sigma_px == pytest.approx(0.02 / math.sqrt(2))
    assert (b.x_px, b.y_px, b.sigma_px) == (10.0, 20.0, 0.02)


def test_mean_views_takes_the_scatter_when_it_exceeds_the_reported_sigma() -> None:
    xs = [0.0, 0.3, -0.3, 0.0]  # sample variance 0.06 px^2, y the same
    frames = [[MarkerView("a", 1, x, x, 0.01)] for x in xs]
    (mean,) = mean_views(frames)
    assert mean.sigma_px == pytest.approx(math.sqrt(0.06 / 4))
    quiet = [[MarkerView("a", 1, 1e-4 * k, 0.0, 0.01)] for k in range(4)]
    assert mean_views(quiet)[0].sigma_px == pytest.approx(0.01 / 2)  # reported: larger


class _JitteryMarkerCamera:
    """The arm bench's camera (drivers/sim/arm_markers.py MarkerRenderer): photon and read
    noise plus a seeded image-plane jitter drawn anew for every frame (air, stand vibration)."""

    def __init__(self, model: Any, rig: Any, points: np.ndarray, seed: int, jitter: float) -> None:
        from drivers.sim.arm_markers import MarkerRenderer

        self.renderer = MarkerRenderer(model, rig, np.random.default_rng(seed))
        self.points, self.jitter_px = points, jitter

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def grab(self) -> Any:
        from drivers.base import Frame

        image = self.renderer.render(self.points, self.jitter_px)
        return Frame(image, self.renderer.rig.bit_depth, 0.0, 0, "camera")  # type: ignore[arg-type]


@pytest.mark.slow
async def test_averaged_frames_divide_the_pose_noise_by_sqrt_frames() -> None:
    from drivers.sim.arm_markers import CameraRig

    pose = np.eye(4)
    pose[:3, 3] = (400.0, 0.0, 300.0)
    rig = CameraRig(width_px=1024, height_px=768, focal_px=2000.0)
    models = rig.cameras(pose[:3, 3])
    repeats = 20
    spreads: dict[int, tuple[float, float, float, float]] = {}
    workers = Workers()
    try:
        for frames in (1, 9):
            settings = Settings.model_validate(
                {"camera": {"bit_depth": rig.bit_depth}, "arm": {"frames_per_measurement": frames}}
            )
            markers = np.array(settings.arm.markers_mm)
            world = markers @ pose[:3, :3].T + pose[:3, 3]
            cameras = [
                _JitteryMarkerCamera(m, rig, world, 11 + k, JITTER_PX) for k, m in enumerate(models)
            ]
            meter = MultiCameraMeter(settings, cameras, models, workers)
            errors_um, rotations, sigmas, rotation_sigmas = [], [], [], []
            for _ in range(repeats):
                measured = await meter.measure(pose)
                error = pose_difference(pose, measured.pose)
                errors_um.append(error.translation_norm_mm * 1000)
                rotations.append(error.rotation_angle_rad * 1e6)
                sigmas.append(measured.sigma_mm * 1000)
                rotation_sigmas.append(measured.rotation_sigma_rad * 1e6)
            spreads[frames] = (
                float(np.sqrt(np.mean(np.square(errors_um)))),
                float(np.sqrt(np.mean(np.square(rotations)))),
                float(np.mean(sigmas)),
                float(np.mean(rotation_sigmas)),
            )
    finally:
        workers.shutdown()
    single_um, single_urad, single_sigma, single_rotation_sigma = spreads[1]
    mean_um, mean_urad, mean_sigma, mean_rotation_sigma = spreads[9]
    # nine frames: the reported 1-sigma is a third (the frames' noise is independent)...
    assert single_sigma / mean_sigma == pytest.approx(3.0, rel=0.2), spreads
    # ... and the measured error follows it: RMS of |error| from 20 measurements (60 degrees
    # of freedom, ~10 % of scatter) within [0.6, 1.5] of the reported 1-sigma, both ways
    assert 0.6 < single_um / single_sigma < 1.5, spreads
    assert 0.6 < mean_um / mean_sigma < 1.5, spreads
    # the rotation (four markers, 120 mm) the same way, against its own reported 1-sigma
    # (the rotation block of the pose's covariance: what a step records as its noise)
    assert single_rotation_sigma / mean_rotation_sigma == pytest.approx(3.0, rel=0.2), spreads
    assert 0.6 < single_urad / single_rotation_sigma < 1.5, spreads
    assert 0.6 < mean_urad / mean_rotation_sigma < 1.5, spreads


class _CountingCamera(_JitteryMarkerCamera):
    grabs = 0

    async def grab(self) -> Any:
        self.grabs += 1
        return await super().grab()


async def test_a_measurement_may_ask_for_more_frames_than_a_step() -> None:
    """arm.reference_frames: the pose's zero is measured once and its error is in every later
    drift of the pose, so it may be averaged over more frames than a step's measurement."""
    from drivers.sim.arm_markers import CameraRig

    pose = np.eye(4)
    pose[:3, 3] = (400.0, 0.0, 300.0)
    rig = CameraRig(width_px=1024, height_px=768, focal_px=2000.0)
    models = rig.cameras(pose[:3, 3])
    settings = Settings.model_validate(
        {"camera": {"bit_depth": rig.bit_depth}, "arm": {"frames_per_measurement": 2}}
    )
    world = np.array(settings.arm.markers_mm) @ pose[:3, :3].T + pose[:3, 3]
    cameras = [_CountingCamera(m, rig, world, 40 + k, JITTER_PX) for k, m in enumerate(models)]
    workers = Workers()
    try:
        meter = MultiCameraMeter(settings, cameras, models, workers)
        await meter.measure(pose)
        assert [c.grabs for c in cameras] == [2] * len(cameras)
        await meter.measure(pose, 5)
        assert [c.grabs for c in cameras] == [7] * len(cameras)
    finally:
        workers.shutdown()


async def taught_robot(poses: Any) -> FakeRobot:
    """The suite's fake robot (it passes the Robot contract) with each pose taught as a goal."""
    robot = FakeRobot()
    for pose in poses:
        await robot.teach_goal(pose.name)
    return robot


async def test_the_references_are_measured_with_arm_reference_frames() -> None:
    from daemon.run.arm.prepare import ArmServices, measure_references
    from daemon.run.events import ErrorLog, EventBus
    from tests.fakes_arm import POSES

    asked: list[tuple[str, int | None]] = []

    robot = await taught_robot(POSES)

    class Meter:
        async def measure(self, expected_pose: Any, frames: int | None = None) -> Any:
            from daemon.arm.run import ToolMeasurement

            asked.append((robot.goal, frames))
            return ToolMeasurement(np.asarray(expected_pose), 0.001, True, {})

    work: Any = type(
        "Work", (), {"poses": POSES, "reference": {}, "missing_references": {}, "run_id": 1}
    )()
    services = ArmServices(GoalRobotArm(robot), Meter(), pipeline=None)  # type: ignore[arg-type]
    await measure_references(work, services, ErrorLog(EventBus()), 32)
    assert asked == [(pose.name, 32) for pose in POSES]
    assert set(work.reference) == {pose.name for pose in POSES}
    assert work.reference_source == "each taught goal before the first correction"


async def test_a_missing_reference_is_said_never_a_silent_zero(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A pose whose reference cannot be measured (its markers, or a camera timing out on a
    busy machine) takes its first step's measurement as its zero: the pose and why are kept,
    that step is flagged, and the run's summary prints a line for it."""
    from daemon.arm.run import MeasurementError, ToolMeasurement
    from daemon.commands.run import _print_result
    from daemon.run.arm.prepare import ArmServices, measure_references
    from daemon.run.arm.record import record_measurement
    from daemon.run.arm.step import REFERENCE_MISSING
    from daemon.run.events import ErrorLog, EventBus
    from daemon.storage.recorder import StepRecord
    from daemon.storage.step_record import STEP_FLAGS
    from tests.fakes_arm import POSES

    robot = await taught_robot(POSES)

    class Meter:
        async def measure(self, expected_pose: Any, frames: int | None = None) -> Any:
            if robot.goal == POSES[1].name:
                raise MeasurementError("2 markers seen, 3 needed")
            return ToolMeasurement(np.asarray(expected_pose), 0.001, True, {})

    work: Any = type(
        "Work", (), {"poses": POSES, "reference": {}, "missing_references": {}, "run_id": 1}
    )()
    services = ArmServices(GoalRobotArm(robot), Meter(), pipeline=None)  # type: ignore[arg-type]
    await measure_references(work, services, ErrorLog(EventBus()))
    assert set(work.reference) == {POSES[0].name}
    assert work.missing_references == {POSES[1].name: "markers: 2 markers seen, 3 needed"}
    assert work.reference_source == "taught goals before the first correction, else first steps"

    measured = ToolMeasurement(np.asarray(POSES[1].tool_pose), 0.001, True, {})
    record = StepRecord(run_id=1, step=0, scheduled_s=0.0, actual_s=0.0, lateness_s=0.0)
    assert record_measurement(work, POSES[1], measured, record)  # the zero: flagged
    assert not record_measurement(work, POSES[1], measured, record)  # a drift from it
    assert not record_measurement(work, POSES[0], measured, record)  # had its reference
    assert REFERENCE_MISSING in STEP_FLAGS

    summary = {"drift_3d_max_um": 1.0, "reference": {"missing": work.missing_references}}
    _print_result({"id": 3, "state": "finished", "reason": None, "summary": summary}, False)
    lines = [line for line in capsys.readouterr().out.splitlines() if "NO REFERENCE" in line]
    assert lines == [
        f"  NO REFERENCE at {POSES[1].name:<12} its first step is its zero "
        "(markers: 2 markers seen, 3 needed)"
    ]
