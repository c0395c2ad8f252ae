"""The tool's pose from one camera (daemon/vision/pnp.py, issue 20): perspective-n-point against
ground truth (exact poses without noise), its covariance against Monte Carlo with known pixel
noise and with rendered markers measured by the robust centroid, the depth along the line of
sight worse than across it, and the degenerate cases refused in one line."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from daemon.vision.markers import MarkerSpot, centroids_of_markers
from daemon.vision.multiview import MultiviewError, pose_difference, project
from daemon.vision.pnp import depth_sigma_mm, pose_from_views
from drivers.sim.arm_markers import CameraRig

#: The arm bench's markers (config ArmSettings.markers_mm): a 120 mm cross, two raised.
MARKERS = np.array([[60.0, 0.0, 0.0], [0.0, 60.0, 0.0], [-60.0, 0.0, 15.0], [0.0, -60.0, 30.0]])
TARGET = np.array([400.0, 100.0, 300.0])
#: One of the bench's cameras (700 mm away, 30 degrees above the tool, f = 4640 px).
CAMERA = CameraRig(count=1).cameras(TARGET)[0]


def tool_pose(
    rotvec: tuple[float, float, float], offset_mm: tuple[float, float, float]
) -> NDArray[np.float64]:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    pose[:3, 3] = TARGET + np.asarray(offset_mm)
    return pose


def world(pose: NDArray[np.float64], markers: NDArray[np.float64] = MARKERS) -> NDArray[np.float64]:
    return np.asarray(markers @ pose[:3, :3].T + pose[:3, 3])


def random_pose(rng: np.random.Generator) -> NDArray[np.float64]:
    return tool_pose(
        tuple(rng.uniform(-0.35, 0.35, 3)),  # up to 20 degrees per axis
        tuple(rng.uniform(-30.0, 30.0, 3)),
    )


def error6(true: NDArray[np.float64], fitted: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(pose_difference(true, fitted).as_array())


def test_noise_free_pixels_give_the_exact_pose() -> None:
    rng = np.random.default_rng(1)
    distorted = dataclasses.replace(
        CAMERA, name="distorted", distortion=np.array([-0.08, 0.01, 0.001, -0.0005, 0.0])
    )
    for camera in (CAMERA, distorted):
        for _ in range(5):
            true = random_pose(rng)
            pixels = project(camera, world(true))[None]
            fit = pose_from_views([camera], MARKERS, pixels)
            error = error6(true, fit.pose)
            assert np.abs(error[:3]).max() < 1e-7 and np.abs(error[3:]).max() < 1e-10, error
            assert fit.dof == 2 and fit.chi2 < 1e-12 and fit.markers == (0, 1, 2, 3)


@pytest.mark.slow
def test_covariance_matches_monte_carlo_with_known_pixel_noise() -> None:
    """Gaussian noise of known sigma on exact pixels: the RMS error of each component matches the
    predicted covariance's and the mean Mahalanobis distance² is 6 (six parameters)."""
    rng = np.random.default_rng(7)
    true = tool_pose((0.1, -0.2, 0.15), (5.0, -3.0, 2.0))
    exact = project(CAMERA, world(true))
    sigma = np.array([0.04, 0.03, 0.05, 0.02])[:, None] * np.ones((4, 2))  # per marker (px)
    trials = 400
    errors = np.empty((trials, 6))
    mahalanobis = np.empty(trials)
    predicted = None
    for k in range(trials):
        noisy = exact + rng.normal(size=exact.shape) * sigma
        fit = pose_from_views([CAMERA], MARKERS, noisy[None], sigma[None])
        errors[k] = error6(true, fit.pose)
        mahalanobis[k] = errors[k] @ np.linalg.solve(fit.covariance, errors[k])
        predicted = fit.covariance
    assert predicted is not None
    # the mean of 400 chi²(6) draws: 6 with a standard error of sqrt(12 / 400) = 0.17
    assert abs(mahalanobis.mean() - 6.0) < 0.6, mahalanobis.mean()
    ratio = np.sqrt(np.mean(errors**2, axis=0) / np.diag(predicted))
    # each component's RMS over its predicted sigma: 1 within ~4 standard errors (1/sqrt(800))
    np.testing.assert_allclose(ratio, 1.0, atol=0.15)


@pytest.mark.slow
def test_depth_along_the_line_of_sight_is_much_poorer_than_across_it() -> None:
    rng = np.random.default_rng(3)
    true = tool_pose((0.05, 0.1, -0.1), (0.0, 0.0, 0.0))
    exact = project(CAMERA, world(true))
    fit = pose_from_views([CAMERA], MARKERS, exact[None])
    along, across = depth_sigma_mm(CAMERA, fit)
    # the depth of a 120 mm marker cross 700 mm away: about distance / spread worse
    assert along > 4.0 * across, (along, across)
    # the translation covariance's widest axis is the line of sight
    _, vectors = np.linalg.eigh(fit.covariance[:3, :3])
    sight = (true[:3, 3] - CAMERA.centre_mm) / np.linalg.norm(true[:3, 3] - CAMERA.centre_mm)
    assert abs(float(vectors[:, -1] @ sight)) > 0.95
    # ... and the Monte Carlo depth error says the same
    depths = []
    for _ in range(300):
        noisy = exact + rng.normal(0.0, CAMERA.pixel_sigma_px, exact.shape)
        moved = pose_from_views([CAMERA], MARKERS, noisy[None]).pose[:3, 3] - true[:3, 3]
        depths.append(float(moved @ sight))
    assert math.sqrt(np.mean(np.square(depths))) == pytest.approx(along, rel=0.15)


def test_rendered_markers_measured_by_the_centroid_match_the_predicted_covariance() -> None:
    """Markers rendered with the sensor's noise (daemon/vision/markers.py) at known poses, each
    measured by the robust centroid with its own sigma: Mahalanobis² ~ 6 per pose on average."""
    rng = np.random.default_rng(11)
    spot = MarkerSpot(
        sigma_px=2.0, peak_fraction=0.6, bit_depth=12, gain_e_per_count=2.5, read_noise_e=6.0
    )
    poses = 80
    mahalanobis = np.empty(poses)
    squared = np.zeros(2)
    predicted = np.zeros(2)
    for k in range(poses):
        true = random_pose(rng)
        pixels, sigmas = centroids_of_markers([CAMERA], world(true), rng, spot)
        fit = pose_from_views([CAMERA], MARKERS, pixels, sigmas)
        error = error6(true, fit.pose)
        mahalanobis[k] = error @ np.linalg.solve(fit.covariance, error)
        squared += [error[:3] @ error[:3], error[3:] @ error[3:]]
        predicted += [np.trace(fit.covariance[:3, :3]), np.trace(fit.covariance[3:, 3:])]
    # mean of 80 chi²(6): 6 +- 0.39 (one standard error); the centroid's sigma is its own estimate
    assert 6.0 - 1.5 < mahalanobis.mean() < 6.0 + 1.5, mahalanobis.mean()
    np.testing.assert_allclose(np.sqrt(squared / predicted), 1.0, atol=0.2)


def test_markers_split_between_two_cameras_still_give_the_pose() -> None:
    """No marker in two cameras (no triangulation): the views together fix the pose."""
    rig = CameraRig(count=2, spread_rad=math.radians(90.0)).cameras(TARGET)
    true = tool_pose((0.1, 0.0, 0.2), (3.0, 1.0, -2.0))
    pixels = np.stack([project(camera, world(true)) for camera in rig])
    pixels[0, 2:] = np.nan
    pixels[1, :2] = np.nan
    fit = pose_from_views(rig, MARKERS, pixels, expected_pose=tool_pose((0.1, 0.0, 0.2), (0, 0, 0)))
    assert np.abs(error6(true, fit.pose)).max() < 1e-7
    assert sorted(fit.observations) == [(0, 0), (0, 1), (1, 2), (1, 3)]


def test_three_markers_need_the_expected_pose() -> None:
    true = tool_pose((0.2, -0.1, 0.05), (2.0, 2.0, 2.0))
    pixels = project(CAMERA, world(true))[None].copy()
    pixels[0, 3] = np.nan
    with pytest.raises(MultiviewError, match="give the expected pose or show a fourth marker"):
        pose_from_views([CAMERA], MARKERS, pixels)
    near = tool_pose((0.2, -0.1, 0.05), (2.3, 1.8, 2.1))  # the taught pose, 0.4 mm off
    fit = pose_from_views([CAMERA], MARKERS, pixels, expected_pose=near)
    assert np.abs(error6(true, fit.pose)).max() < 1e-7 and fit.dof == 0


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("two markers", r"^2 marker\(s\) seen: a pose from the cameras' views needs 3"),
        ("in a line", r"^the seen markers lie on one line"),
        ("shape", r"^expected pixels of shape \(1 cameras, 4 markers, 2\)"),
    ],
)
def test_degenerate_views_are_refused_in_one_line(case: str, message: str) -> None:
    true = tool_pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    markers = MARKERS
    pixels = project(CAMERA, world(true))[None].copy()
    if case == "two markers":
        pixels[0, 2:] = np.nan
    elif case == "in a line":
        markers = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0], [60.0, 0.0, 0.0], [90.0, 0.0, 0.0]])
        pixels = project(CAMERA, world(true, markers))[None]
    else:
        pixels = pixels[0]
    with pytest.raises(MultiviewError, match=message) as caught:
        pose_from_views([CAMERA], markers, pixels, expected_pose=true)
    assert "\n" not in str(caught.value)
