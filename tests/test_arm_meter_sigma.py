"""The meter's 1-sigma from its cameras' measured scatter (issue 29): before it, every step's
1-sigma was the camera model's nominal floor (4.70 um on the bench) whatever the cameras did."""

from __future__ import annotations

import numpy as np
import pytest

from config import Settings
from daemon.run.arm.measure import MarkerView, MultiCameraMeter, ScatterLog
from daemon.run.workers import Workers
from daemon.vision.multiview import pose_difference
from tests.test_arm_measure_frames import _JitteryMarkerCamera


def test_the_scatter_log_pools_each_cameras_markers_over_frames() -> None:
    log = ScatterLog()
    log.add([[MarkerView("a", 0, 1.0, 1.0, 0.01)], [MarkerView("a", 0, 2.0, 2.0, 0.01)]])
    assert log.floors_px() == {}  # two frames: not a scatter measurement
    rng = np.random.default_rng(3)
    frames = [
        [MarkerView("a", m, 10.0 * m + x, 5.0 + y, 0.01) for m, (x, y) in enumerate(noise)]
        for noise in rng.normal(0.0, 0.1, (40, 4, 2))
    ]
    log.add(frames)
    sigma = log.sigma_px("a")
    assert sigma is not None and sigma == pytest.approx(0.1, rel=0.1)
    assert log.sigma_px("b") is None


async def _single_frame_sigmas(jitter_px: float) -> tuple[float, float]:
    """A meter whose cameras jitter by ``jitter_px``: one 8-frame measurement of the still tool
    (a reference), then 24 single-frame ones: (mean reported 1-sigma, RMS error), um."""
    from drivers.sim.arm_markers import CameraRig

    pose = np.eye(4)
    pose[:3, 3] = (400.0, 0.0, 300.0)
    rig = CameraRig(width_px=1024, height_px=768, focal_px=2000.0)
    models = rig.cameras(pose[:3, 3])
    settings = Settings.model_validate({"camera": {"bit_depth": rig.bit_depth}})
    world = np.array(settings.arm.markers_mm) @ pose[:3, :3].T + pose[:3, 3]
    cameras = [_JitteryMarkerCamera(m, rig, world, 21 + k, jitter_px) for k, m in enumerate(models)]
    workers = Workers()
    try:
        meter = MultiCameraMeter(settings, cameras, models, workers)
        await meter.measure(pose, 8)
        sigmas, errors = [], []
        for _ in range(24):
            measured = await meter.measure(pose)
            sigmas.append(measured.sigma_mm * 1000.0)
            errors.append(pose_difference(pose, measured.pose).translation_norm_mm * 1000.0)
    finally:
        workers.shutdown()
    return float(np.mean(sigmas)), float(np.sqrt(np.mean(np.square(errors))))


@pytest.mark.slow
async def test_the_reported_sigma_follows_the_cameras_real_scatter() -> None:
    quiet_sigma, quiet_error = await _single_frame_sigmas(0.02)
    noisy_sigma, noisy_error = await _single_frame_sigmas(0.08)
    # four times the jitter: about four times the reported 1-sigma (the centroids' own noise
    # adds a little to both), where the nominal floor reported one figure for both
    assert 2.5 < noisy_sigma / quiet_sigma < 4.5, (quiet_sigma, noisy_sigma)
    # and each is what the errors really are: RMS of |error| over 24 measurements (72 degrees
    # of freedom) within [0.6, 1.5] of the reported 1-sigma
    assert 0.6 < quiet_error / quiet_sigma < 1.5, (quiet_error, quiet_sigma)
    assert 0.6 < noisy_error / noisy_sigma < 1.5, (noisy_error, noisy_sigma)
