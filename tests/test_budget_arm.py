"""An arm's error budget (issue 32): the 3-D measurement's predicted uncertainty against Monte
Carlo through the real measurement, and an identified model's uncertainty at the tool."""

import math

import numpy as np
import pytest

from daemon.analysis.budget_arm import (
    drift_sigma_um,
    model_uncertainty,
    perturbed_models,
    predicted_measurement,
    tool_drifts_um,
    visible_pixels,
)
from daemon.arm.arm_model import ArmModel
from daemon.arm.controller import ArmModelOptions
from daemon.arm.controller_loading import load_controller
from daemon.model.calibration import CalibratedParameter
from daemon.run.arm.setup import ARMS_DIR
from daemon.vision.tool_pose import measure_tool_pose
from drivers.sim.arm_markers import CameraRig

MARKERS = np.array([(60.0, 0, 0), (0, 60.0, 0), (-60.0, 0, 15.0), (0, -60.0, 30.0)])


def _pose(position: tuple[float, float, float]) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = position
    return pose


def test_predicted_sigma_is_the_scatter_of_real_measurements() -> None:
    rig = CameraRig(pixel_sigma_px=0.1)
    target = (500.0, 100.0, 300.0)
    cameras = rig.cameras(target)
    pose = _pose(target)
    predicted = predicted_measurement(cameras, MARKERS, pose)
    assert predicted.sigma_mm is not None and predicted.cameras_seeing == 3
    assert predicted.markers_seen == (3, 3, 3, 3)
    world = MARKERS + np.array(target)
    pixels, counts = visible_pixels(cameras, world)
    assert counts == [4, 4, 4]
    rng = np.random.default_rng(6)
    positions = []
    for _ in range(150):
        noisy = pixels + rng.normal(0, 0.1, pixels.shape)
        positions.append(measure_tool_pose(cameras, MARKERS, noisy).pose[:3, 3])
    scatter = math.sqrt(float(np.var(np.array(positions), axis=0, ddof=1).sum()))
    assert scatter == pytest.approx(predicted.sigma_mm, rel=0.2)
    # twice the pixel noise, twice the sigma (first order)
    doubled = predicted_measurement(cameras, MARKERS, pose, sigmas_px=[0.2] * 3)
    assert doubled.sigma_mm == pytest.approx(2 * predicted.sigma_mm, rel=1e-3)


def test_a_tool_out_of_sight_has_no_measurement() -> None:
    cameras = CameraRig().cameras((500.0, 100.0, 300.0))
    far = predicted_measurement(cameras, MARKERS, _pose((-3000.0, 0.0, 0.0)))
    assert far.sigma_mm is None and far.cameras_seeing == 0 and far.why_not


def test_drift_sigma_averages_both_ends() -> None:
    assert drift_sigma_um(0.005, 1, 1) == pytest.approx(5.0 * math.sqrt(2))
    assert drift_sigma_um(0.005, 4, 16) == pytest.approx(5.0 * math.sqrt(1 / 4 + 1 / 16))


def _model(parameters: tuple[CalibratedParameter, ...]) -> ArmModel:
    return ArmModel(name="test", arm="CRS A465", heat_scales=(1.0,) * 6, parameters=parameters)


def test_perturbed_models_move_each_identified_factor_by_its_error() -> None:
    model = _model(
        (
            CalibratedParameter("heat:2", 1.0, 0.1, relative_error=0.1),
            CalibratedParameter("heat", 1.0, 0.05, relative_error=0.05),
            CalibratedParameter("convection", 1.0, 0.2, relative_error=0.2),
            CalibratedParameter("alpha", 1.0, 0.02, relative_error=0.02),
            CalibratedParameter("offset", 0.3, 0.1),  # the IR observer's: left out
            CalibratedParameter("heat:3", 1.0, None, identifiable=False),
        )
    )
    variants = dict(perturbed_models(model, 6))
    assert list(variants) == ["heat:2", "heat", "convection", "alpha"]
    assert variants["heat:2"].heat_scales[1] == pytest.approx(math.exp(0.1))
    assert variants["heat:2"].heat_scales[0] == 1.0
    assert variants["heat"].heat_scales == pytest.approx((math.exp(0.05),) * 6)
    assert variants["convection"].convection_scale == pytest.approx(math.exp(0.2))
    assert variants["alpha"].alpha_scale == pytest.approx(math.exp(0.02))


def test_an_alpha_error_scales_the_drift() -> None:
    """The tool drift is linear in the expansion coefficient: alpha's relative error r moves
    every pose's drift by (e^r - 1) of itself, the oracle of the propagation."""
    options = ArmModelOptions(model_dt_s=3600.0)
    controller = load_controller(ARMS_DIR / "crs-a465.toml", "a465-pick-and-place", options)
    poses = controller.measured_poses()
    model = _model((CalibratedParameter("alpha", 1.0, 0.03, relative_error=0.03),))
    end = 3600.0
    nominal = tool_drifts_um(
        controller.arm, controller.duty, poses, end_s=end, options=options, identified=model
    )
    result = model_uncertainty(
        controller.arm, controller.duty, poses, end_s=end, options=options, identified=model
    )
    expected = np.linalg.norm(nominal, axis=1) * (math.exp(0.03) - 1)
    assert np.all(expected > 0.1)
    assert result.sigma_um == pytest.approx(tuple(expected), rel=1e-6)
    assert list(result.contributions_um) == ["alpha"]
