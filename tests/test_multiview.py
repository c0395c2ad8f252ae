"""3-D measurement with several cameras (issue 20): projection against a hand-written pinhole +
distortion oracle, triangulation against ground truth and Monte Carlo, orientation from markers,
camera poses from robot moves, camera files, synthetic marker frames, and the single camera of
the thesis as the special case of one camera looking along one axis."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from daemon.arm.types import Pose6
from daemon.vision import measure_centroid
from daemon.vision.calibration import camera_to_robot
from daemon.vision.camera_pose import fit_camera_pose, grid_positions
from daemon.vision.camera_rig import fit_cameras_and_marker
from daemon.vision.cameras import CameraFileError, cameras_toml, load_cameras, write_cameras
from daemon.vision.markers import (
    centroids_of_markers,
    marker_pixels,
    render_marker_window,
    render_markers,
)
from daemon.vision.multiview import (
    CameraModel,
    MultiviewError,
    Plane,
    axis_camera,
    intrinsic_matrix,
    look_at,
    measure_in_plane,
    pose_covariance_difference,
    pose_difference,
    project,
    projection_jacobian,
    rigid_pose_from_markers,
    triangulate,
    triangulate_detailed,
)
from daemon.vision.tool_pose import ToolMeasurement, measure_tool_pose

FloatArray = NDArray[np.float64]
TARGET = np.array([0.0, 0.0, 400.0])  # where the cameras look (mm, world)
SIGMA_PX = 0.05


def camera(
    name: str,
    position: tuple[float, float, float],
    *,
    distortion: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0),
    sigma: float = SIGMA_PX,
) -> CameraModel:
    rvec, tvec = look_at(position, TARGET)
    return CameraModel(
        name=name,
        matrix=intrinsic_matrix((2400.0, 2380.0), (375.5, 290.5)),
        distortion=np.array(distortion),
        rotation_rad=rvec,
        translation_mm=tvec,
        image_size_px=(752, 582),
        pixel_sigma_px=sigma,
    )


def rig(count: int, distortion: tuple[float, ...] = (0.0,) * 5) -> list[CameraModel]:
    """``count`` cameras around the target, 1 m away, at different heights."""
    positions = [
        (-800.0, -600.0, 500.0),
        (800.0, -600.0, 450.0),
        (0.0, -700.0, 1100.0),
        (600.0, 700.0, 600.0),
    ]
    return [camera(f"c{i}", p, distortion=distortion) for i, p in enumerate(positions[:count])]


# ----------------------------------------------------------------------------- projection


def pinhole_oracle(cam: CameraModel, point: FloatArray) -> FloatArray:
    """OpenCV's camera model written out (docs.opencv.org, calib3d): R X + t, divide by z,
    radial k1 k2 k3 and tangential p1 p2 distortion, then K."""
    rotation = Rotation.from_rotvec(np.array(cam.rotation_rad)).as_matrix()
    xc, yc, zc = rotation @ point + cam.translation_mm
    x, y = xc / zc, yc / zc
    k1, k2, p1, p2, k3 = cam.distortion
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    k = cam.matrix
    return np.array([k[0, 0] * xd + k[0, 1] * yd + k[0, 2], k[1, 1] * yd + k[1, 2]])


@pytest.mark.parametrize("distortion", [(0.0,) * 5, (-0.2, 0.05, 1e-3, -2e-3, 0.01)])
def test_projection_matches_the_pinhole_oracle(distortion: tuple[float, ...]) -> None:
    cam = camera("c", (-800.0, -600.0, 500.0), distortion=distortion)
    points = TARGET + np.array([[0.0, 0.0, 0.0], [30.0, -20.0, 15.0], [-40.0, 10.0, -35.0]])
    expected = np.array([pinhole_oracle(cam, p) for p in points])
    assert project(cam, points) == pytest.approx(expected, abs=1e-9)
    # the target is on the optical axis: it is imaged at the principal point
    assert project(cam, TARGET)[0] == pytest.approx([375.5, 290.5], abs=1e-9)


def test_projection_jacobian_is_the_derivative() -> None:
    cam = camera("c", (800.0, -600.0, 450.0), distortion=(-0.2, 0.05, 1e-3, -2e-3, 0.01))
    point = TARGET + np.array([12.0, -7.0, 20.0])
    _, jacobian = projection_jacobian(cam, point)
    step = 1e-4
    numeric = np.column_stack(
        [
            (project(cam, point + step * e)[0] - project(cam, point - step * e)[0]) / (2 * step)
            for e in np.eye(3)
        ]
    )
    assert jacobian[0] == pytest.approx(numeric, rel=1e-6, abs=1e-8)


def test_look_at_puts_the_target_on_the_axis_with_up_up_the_image() -> None:
    cam = camera("c", (0.0, -1000.0, 400.0))
    assert cam.centre_mm == pytest.approx([0.0, -1000.0, 400.0], abs=1e-9)
    above = project(cam, TARGET + np.array([0.0, 0.0, 10.0]))[0]
    right = project(cam, TARGET + np.array([10.0, 0.0, 0.0]))[0]
    assert above[1] < 290.5 and above[0] == pytest.approx(375.5)  # up the image: smaller rows
    assert right[0] > 375.5  # looking along +y, world +x is to the right


# -------------------------------------------------------------------------- triangulation


@pytest.mark.parametrize("count", [2, 3, 4])
def test_exact_pixels_triangulate_to_the_point(count: int) -> None:
    cameras = rig(count, distortion=(-0.15, 0.03, 5e-4, -5e-4, 0.0))
    truth = TARGET + np.array([25.0, -18.0, 31.0])
    pixels = np.vstack([project(c, truth) for c in cameras])
    point, covariance = triangulate(cameras, pixels)
    assert point == pytest.approx(truth, abs=1e-8)
    assert np.all(np.linalg.eigvalsh(covariance) > 0)


@pytest.mark.slow
def test_triangulation_covariance_matches_monte_carlo() -> None:
    """Fixed seed, 1200 noisy triangulations from three cameras: the empirical covariance
    agrees with the reported one (each variance within 12 %: its sampling error is
    sqrt(2/1200) = 4 %), and the mean squared Mahalanobis distance is 3 within 6 %."""
    cameras = rig(3)
    truth = TARGET + np.array([10.0, 5.0, -8.0])
    pixels = np.vstack([project(c, truth) for c in cameras])
    _, reported = triangulate(cameras, pixels)
    rng = np.random.default_rng(20)
    errors = np.array(
        [
            triangulate(cameras, pixels + rng.normal(0.0, SIGMA_PX, pixels.shape))[0] - truth
            for _ in range(1200)
        ]
    )
    empirical = np.cov(errors.T)
    assert np.diag(empirical) == pytest.approx(np.diag(reported), rel=0.12)
    mahalanobis = np.einsum("ni,ij,nj->n", errors, np.linalg.inv(reported), errors)
    assert float(np.mean(mahalanobis)) == pytest.approx(3.0, rel=0.06)
    assert np.all(np.abs(errors.mean(axis=0)) < 4 * np.sqrt(np.diag(reported) / len(errors)))


def test_the_observations_own_sigmas_weigh_the_fit() -> None:
    cameras = rig(2)
    pixels = np.vstack([project(c, TARGET) for c in cameras])
    _, nominal = triangulate(cameras, pixels)
    _, doubled = triangulate(cameras, pixels, [2 * SIGMA_PX, 2 * SIGMA_PX])
    assert doubled == pytest.approx(4 * nominal, rel=1e-9)
    # one poor camera: the point follows the good one
    _, uneven = triangulate(cameras, pixels, [SIGMA_PX, (10 * SIGMA_PX, 10 * SIGMA_PX)])
    assert np.trace(uneven) > np.trace(nominal)


def test_residuals_and_chi2_are_reported() -> None:
    cameras = rig(3)
    pixels = np.vstack([project(c, TARGET) for c in cameras])
    pixels[0, 0] += 0.3  # an inconsistent observation
    result = triangulate_detailed(cameras, pixels)
    assert result.dof == 3
    assert result.chi2 == pytest.approx(float(np.sum((result.residuals_px / SIGMA_PX) ** 2)))
    assert result.chi2 > 1.0


def test_degenerate_triangulations_are_refused() -> None:
    cameras = rig(2)
    pixels = np.vstack([project(c, TARGET) for c in cameras])
    with pytest.raises(MultiviewError, match="one camera sees no depth"):
        triangulate(cameras[:1], pixels[:1])
    with pytest.raises(MultiviewError, match="one finite pixel"):
        triangulate(cameras, pixels[:1])
    twin = camera("twin", (-800.0, -600.0, 500.5))  # half a millimetre beside c0
    with pytest.raises(MultiviewError, match="parallel"):
        triangulate([cameras[0], twin], np.vstack([project(cameras[0], TARGET)] * 2))
    # lines of sight that meet behind both cameras (both stand at y = -600 looking to +y)
    behind = np.array([0.0, -2500.0, 300.0])
    with pytest.raises(MultiviewError, match="behind camera"):
        triangulate(cameras, np.vstack([project(c, behind) for c in cameras]))


# ------------------------------------------------------------------------- single camera


@pytest.mark.parametrize("rotation_deg", [0.0, 3.0, -12.5])
def test_one_camera_along_one_axis_is_the_existing_single_camera(rotation_deg: float) -> None:
    """The thesis's camera (3.2.3) as a CameraModel: a spot drift in the plane it watches
    measures the same robot offset as calibration.camera_to_robot."""
    um_per_px = (10.22, 9.72)
    spot = (120.0, 350.0, -40.0)
    cam = axis_camera(um_per_px, rotation_deg, spot_mm=spot, pixel_sigma_px=0.02)
    plane = Plane(spot, (0.0, 1.0, 0.0))
    centre = np.array([375.5, 290.5])
    assert project(cam, spot)[0] == pytest.approx(centre, abs=1e-9)
    for drift_px in [(12.0, 0.0), (0.0, -7.5), (23.4, 31.2)]:
        point, covariance = measure_in_plane(cam, tuple(centre + drift_px), plane)
        drift_um = (drift_px[0] * um_per_px[0], drift_px[1] * um_per_px[1])
        expected_um = camera_to_robot(drift_um, rotation_deg)
        assert (point - spot) * 1000.0 == pytest.approx(expected_um, abs=1e-6)
        assert covariance[1] == pytest.approx([0.0, 0.0, 0.0], abs=1e-18)  # nothing along y
        # and through triangulate with one camera and the plane
        same, _ = triangulate([cam], [centre + drift_px], plane=plane)
        assert same == pytest.approx(point, abs=1e-12)
    if rotation_deg == 0.0:
        _, covariance = measure_in_plane(cam, (375.5, 290.5), plane)
        assert math.sqrt(covariance[0, 0]) * 1000 == pytest.approx(0.02 * um_per_px[0])
        assert math.sqrt(covariance[2, 2]) * 1000 == pytest.approx(0.02 * um_per_px[1])


def test_a_distorted_camera_measures_in_its_plane_exactly() -> None:
    """A wide lens (f = 900 px) with strong distortion, points far out in the image, on a
    tilted plane: the measured point reprojects onto the pixel (cv2.undistortPoints alone is
    off by ~4e-5 mm at the image's edge; the Newton steps remove it)."""
    wide = camera("c", (-800.0, -600.0, 500.0))
    wide = CameraModel(
        name="wide",
        matrix=intrinsic_matrix((900.0, 900.0), (375.5, 290.5)),
        distortion=np.array([-0.4, 0.2, 2e-3, -1e-3, 0.05]),
        rotation_rad=wide.rotation_rad,
        translation_mm=wide.translation_mm,
        image_size_px=(752, 582),
    )
    plane = Plane((0.0, 0.0, 400.0), (0.3, -0.2, 1.0))
    basis = np.linalg.svd(np.array([[0.3, -0.2, 1.0]]))[2][1:]
    for offset in [(0.0, 0.0), (150.0, -100.0), (300.0, 200.0)]:
        truth = TARGET + np.array(offset) @ basis
        point, _ = measure_in_plane(wide, tuple(project(wide, truth)[0]), plane)
        assert point == pytest.approx(truth, abs=1e-9)


def test_a_plane_along_the_ray_or_behind_is_refused() -> None:
    cam = axis_camera((10.0, 10.0), spot_mm=(0.0, 0.0, 0.0))
    with pytest.raises(MultiviewError, match="along the plane"):
        measure_in_plane(cam, (375.5, 290.5), Plane((0.0, 0.0, 0.0), (1.0, 0.0, 0.0)))
    with pytest.raises(MultiviewError, match="behind"):
        measure_in_plane(cam, (375.5, 290.5), Plane((0.0, -500.0, 0.0), (0.0, 1.0, 0.0)))


# ---------------------------------------------------------------------- orientation, pose6

MARKERS = np.array([[0.0, 0.0, 0.0], [60.0, 0.0, 0.0], [0.0, 45.0, 0.0], [20.0, 20.0, 30.0]])


def known_pose() -> FloatArray:
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("ZYX", [35.0, -20.0, 10.0], degrees=True).as_matrix()
    pose[:3, 3] = [150.0, -80.0, 420.0]
    return pose


def test_three_or_more_markers_recover_a_known_rotation() -> None:
    pose = known_pose()
    measured = MARKERS @ pose[:3, :3].T + pose[:3, 3]
    found, covariance = rigid_pose_from_markers(MARKERS, measured, np.tile(np.eye(3), (4, 1, 1)))
    assert found == pytest.approx(pose, abs=1e-10)
    assert covariance.shape == (6, 6)
    three, _ = rigid_pose_from_markers(MARKERS[:3], measured[:3], None)
    assert three == pytest.approx(pose, abs=1e-10)


@pytest.mark.slow
def test_pose_covariance_matches_monte_carlo() -> None:
    """Anisotropic marker noise (the covariances triangulation gives), 1500 draws, fixed seed:
    the reported 6x6 covariance's diagonal agrees with the spread of the fitted poses."""
    pose = known_pose()
    measured = MARKERS @ pose[:3, :3].T + pose[:3, 3]
    rng = np.random.default_rng(6)
    roots = [
        np.diag([0.01, 0.02, 0.015]) @ Rotation.random(random_state=k).as_matrix() for k in range(4)
    ]
    covariances = np.array([r @ r.T for r in roots])
    _, reported = rigid_pose_from_markers(MARKERS, measured, covariances)
    draws = []
    for _ in range(1500):
        noisy = measured + np.array([r @ rng.standard_normal(3) for r in roots])
        found, _ = rigid_pose_from_markers(MARKERS, noisy, covariances)
        draws.append(pose_difference(pose, found).as_array())
    empirical = np.cov(np.array(draws).T)
    assert np.diag(empirical) == pytest.approx(np.diag(reported), rel=0.12)


def test_collinear_or_too_few_markers_are_refused() -> None:
    line = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [25.0, 0.0, 0.0], [40.0, 0.0, 0.0]])
    with pytest.raises(MultiviewError, match="one line"):
        rigid_pose_from_markers(line, line + 1.0, None)
    with pytest.raises(MultiviewError, match="three or more"):
        rigid_pose_from_markers(MARKERS[:2], MARKERS[:2], None)
    with pytest.raises(MultiviewError, match="pair up"):
        rigid_pose_from_markers(MARKERS, MARKERS[:3], None)
    singular = np.tile(np.diag([1.0, 1.0, 0.0]), (4, 1, 1))
    with pytest.raises(MultiviewError, match="positive definite"):
        rigid_pose_from_markers(MARKERS, MARKERS, singular)


def test_pose_difference_is_a_pose6_in_the_base_frame() -> None:
    cold = known_pose()
    small = Rotation.from_rotvec([1e-4, -2e-4, 5e-5])
    warm = cold.copy()
    warm[:3, :3] = small.as_matrix() @ cold[:3, :3]
    warm[:3, 3] += [0.05, -0.02, 0.1]
    error = pose_difference(cold, warm)
    assert isinstance(error, Pose6)
    assert error.translation_mm == pytest.approx([0.05, -0.02, 0.1], abs=1e-12)
    assert error.rotation_rad == pytest.approx([1e-4, -2e-4, 5e-5], abs=1e-12)
    # the console's z-y-x angles of the same rotation (read-only arrays included)
    z, y, x = error.zyx_deg()
    assert Rotation.from_euler("ZYX", [z, y, x], degrees=True).as_rotvec() == pytest.approx(
        error.rotation_rad, abs=1e-12
    )
    cov_a, cov_b = np.diag(np.arange(1.0, 7.0)), np.diag(np.arange(6.0, 0.0, -1.0)) * 1e-3
    combined = pose_covariance_difference(cold, warm, cov_a, cov_b)
    assert np.diag(combined) == pytest.approx(np.diag(cov_a + cov_b), rel=1e-3)


# ------------------------------------------------------------- camera poses from robot moves


def test_camera_poses_from_robot_moves_lie_within_their_standard_errors() -> None:
    """Four cameras, the marker on a 3x3x3 cube of robot positions, seeded pixel noise: each
    fitted pose is within 4 of its reported standard errors of the truth; over 150 seeds the
    standard errors match the spread of the fits (within 20 %)."""
    cameras = rig(4, distortion=(-0.1, 0.02, 0.0, 0.0, 0.0))
    positions = grid_positions(TARGET, 60.0, 3)
    rng = np.random.default_rng(18)
    for cam in cameras:
        pixels = project(cam, positions)
        start = cam.with_pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])  # the pose is not needed
        noisy = pixels + rng.normal(0.0, SIGMA_PX, pixels.shape)
        fit = fit_camera_pose(start, positions, noisy, [SIGMA_PX] * len(positions))
        truth = np.concatenate([cam.rotation_rad, cam.translation_mm])
        found = np.concatenate([fit.camera.rotation_rad, fit.camera.translation_mm])
        standard = np.concatenate([fit.camera.rotation_se_rad, fit.camera.translation_se_mm])
        assert np.all(np.abs(found - truth) < 4 * standard)
        assert np.all(np.abs(fit.centre_mm - cam.centre_mm) < 4 * fit.centre_se_mm)
        assert 0.5 < fit.reduced_chi2 < 1.6
        assert fit.residual_px == pytest.approx(SIGMA_PX, rel=0.3)
    cam = cameras[0]
    pixels = project(cam, positions)
    fits = [
        fit_camera_pose(cam, positions, pixels + rng.normal(0.0, SIGMA_PX, pixels.shape))
        for _ in range(150)
    ]
    centres = np.array([f.centre_mm for f in fits])
    typical = np.mean([f.centre_se_mm for f in fits], axis=0)
    assert np.std(centres, axis=0) == pytest.approx(typical, rel=0.2)


def test_pose_calibration_refuses_too_few_or_collinear_positions() -> None:
    cam = rig(1)[0]
    line = TARGET + np.outer(np.linspace(-50.0, 50.0, 6), [1.0, 0.0, 0.0])
    with pytest.raises(MultiviewError, match="one line"):
        fit_camera_pose(cam, line, project(cam, line))
    few = grid_positions(TARGET, 50.0, 2)[:3]
    with pytest.raises(MultiviewError, match="at least 4"):
        fit_camera_pose(cam, few, project(cam, few))


# ------------------------------------------------------------------------------ camera files


def test_camera_files_round_trip(tmp_path: Path) -> None:
    cameras = rig(3, distortion=(-0.1, 0.02, 1e-3, 0.0, 0.0))
    path = tmp_path / "cameras.toml"
    write_cameras(path, cameras)
    loaded = load_cameras(path)
    assert [c.name for c in loaded] == ["c0", "c1", "c2"]
    for original, again in zip(cameras, loaded, strict=True):
        assert again.matrix == pytest.approx(original.matrix)
        assert again.distortion == pytest.approx(original.distortion)
        assert project(again, TARGET + 20.0) == pytest.approx(
            project(original, TARGET + 20.0), abs=1e-6
        )
    assert cameras_toml(loaded) == cameras_toml(cameras)


def test_a_look_at_pose_in_a_file(tmp_path: Path) -> None:
    path = tmp_path / "cameras.toml"
    path.write_text(
        '[[cameras]]\nname = "side"\nwidth_px = 640\nheight_px = 480\nfocal_px = [1000, 1000]\n'
        "principal_px = [319.5, 239.5]\nposition_mm = [0, -900, 400]\nlook_at_mm = [0, 0, 400]\n"
    )
    (side,) = load_cameras(path)
    assert side.centre_mm == pytest.approx([0.0, -900.0, 400.0])
    assert project(side, TARGET)[0] == pytest.approx([319.5, 239.5])
    assert side.pixel_sigma_px == 0.05


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("focal_px = [1000, 1000]\nprincipal_px = [1, 1]\n", "camera 'a': .*pose"),
        (
            "focal_px = [1000, 1000]\nprincipal_px = [1, 1]\ndistortion = [0.1, 0.2, 0.3]\n"
            "rotation_rad = [0, 0, 0]\ntranslation_mm = [0, 0, 500]\n",
            "camera 'a': distortion",
        ),
        (
            "principal_px = [1, 1]\nrotation_rad = [0, 0, 0]\ntranslation_mm = [0, 0, 500]\n",
            "camera 'a': focal_px: Field required",
        ),
        (
            "focal_px = [1000, 1000]\nprincipal_px = [1, 1]\nrotation_rad = [0, 0, 0]\n"
            "translation_mm = [0, 0, 500]\nfocus = 3\n",
            "camera 'a': focus",
        ),
    ],
)
def test_a_bad_camera_file_is_one_line_naming_file_camera_and_field(
    tmp_path: Path, body: str, message: str
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(f'[[cameras]]\nname = "a"\nwidth_px = 640\nheight_px = 480\n{body}')
    with pytest.raises(CameraFileError, match=message) as caught:
        load_cameras(path)
    assert str(caught.value).startswith(str(path))
    assert "\n" not in str(caught.value)
    with pytest.raises(CameraFileError, match="no such file"):
        load_cameras(tmp_path / "missing.toml")


def test_two_cameras_with_one_name_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "twins.toml"
    write_cameras(path, rig(2))
    path.write_text(path.read_text().replace('"c1"', '"c0"'))
    with pytest.raises(CameraFileError, match="camera 'c0': name: used by two"):
        load_cameras(path)


# --------------------------------------------------------------------- synthetic marker frames


def test_rendered_markers_are_measured_where_they_project() -> None:
    """A marker rendered with noise in each camera: the centroid finds its projection within
    a few of its own reported sigmas, and triangulating the centroids gives the marker."""
    cameras = rig(3)
    truth = TARGET + np.array([8.0, -3.0, 12.0])
    rng = np.random.default_rng(3)
    pixels, sigmas = [], []
    for cam in cameras:
        rendered = render_marker_window(cam, truth, rng=rng, read_noise_counts=5.0)
        assert rendered is not None
        window, (c0, r0) = rendered
        result = measure_centroid(window)
        expected = project(cam, truth)[0]
        found = np.array([result.x_px + c0, result.y_px + r0])
        assert np.all(
            np.abs(found - expected) < 5 * np.array([result.sigma_x_px, result.sigma_y_px])
        )
        pixels.append(found)
        sigmas.append((result.sigma_x_px, result.sigma_y_px))
    point, covariance = triangulate(cameras, pixels, sigmas)
    assert np.all(np.abs(point - truth) < 5 * np.sqrt(np.diag(covariance)))


def test_whole_frames_hold_every_visible_marker() -> None:
    cam = rig(1)[0]
    points = np.array(
        [TARGET, TARGET + np.array([30.0, 0.0, 0.0]), TARGET + np.array([5000.0, 0.0, 0.0])]
    )
    pixels, visible = marker_pixels(cam, points)
    assert visible.tolist() == [True, True, False]
    frame = render_markers(cam, points, rng=None)
    assert frame.shape == (582, 752)
    for x, y in pixels[:2]:
        assert frame[round(y), round(x)] > 0.45 * 65535
    assert int(frame.astype(np.int64).sum()) == pytest.approx(
        2 * 0.5 * 65535 * 2 * math.pi * 9.0, rel=1e-3
    )  # two unit-amplitude Gaussians of sigma 3 px, nothing of the third
    assert render_marker_window(cam, points[2]) is None


# ------------------------------------------------------------------ tool pose from centroids


def test_the_tool_pose_from_rendered_markers_in_four_cameras() -> None:
    """Four markers on the tool rendered in four cameras and centroided: the measured pose is
    within 5 of its reported sigmas of the truth in each of its six components, and a 20 um /
    50 urad move of the tool is measured as such by the difference of two measurements."""
    cameras = rig(4)
    pose = known_pose()
    pose[:3, 3] = TARGET + np.array([5.0, -10.0, 8.0])
    rng = np.random.default_rng(11)

    def measure(at: FloatArray) -> ToolMeasurement:
        pixels, sigmas = centroids_of_markers(cameras, MARKERS @ at[:3, :3].T + at[:3, 3], rng)
        return measure_tool_pose(cameras, MARKERS, pixels, sigmas)

    first = measure(pose)
    assert first.views == (4, 4, 4, 4)
    error = pose_difference(pose, first.pose).as_array()
    assert np.all(np.abs(error) < 5 * np.sqrt(np.diag(first.covariance)))
    moved = pose.copy()
    moved[:3, :3] = Rotation.from_rotvec([0.0, 5e-5, 0.0]).as_matrix() @ pose[:3, :3]
    moved[:3, 3] += [0.02, 0.0, 0.0]
    second = measure(moved)
    drift = pose_difference(first.pose, second.pose).as_array()
    spread = np.sqrt(np.diag(first.covariance + second.covariance))
    assert np.all(np.abs(drift - [0.02, 0.0, 0.0, 0.0, 5e-5, 0.0]) < 5 * spread)


def test_markers_seen_by_fewer_than_two_cameras_are_left_out() -> None:
    cameras = rig(3)
    pose = known_pose()
    pose[:3, 3] = TARGET
    points = MARKERS @ pose[:3, :3].T + pose[:3, 3]
    pixels = np.array([project(c, points) for c in cameras])
    blind = pixels.copy()
    blind[1:, 3] = np.nan  # marker 3 only in camera 0
    measured = measure_tool_pose(cameras, MARKERS, blind)
    assert measured.views == (3, 3, 3, 1)
    assert np.all(np.isnan(measured.points_mm[3]))
    assert measured.pose == pytest.approx(pose, abs=1e-8)
    blind[1:, 2] = np.nan  # two markers triangulated: the pose from the views (PnP)
    from_views = measure_tool_pose(cameras, MARKERS, blind)
    assert from_views.views == (3, 3, 1, 1)
    assert from_views.pose == pytest.approx(pose, abs=1e-8)
    blind[:, 1:] = np.nan  # one marker: no pose at all
    with pytest.raises(MultiviewError, match=r"^1 marker\(s\) seen by two or more cameras and no"):
        measure_tool_pose(cameras, MARKERS, blind)
    with pytest.raises(MultiviewError, match="shape"):
        measure_tool_pose(cameras, MARKERS, pixels[:, :3])


# ------------------------------------------------- camera poses and the marker's tool offset


def tool_poses(count: int, rng: np.random.Generator, turn_rad: float) -> FloatArray:
    poses = np.tile(np.eye(4), (count, 1, 1))
    for pose, position in zip(poses, grid_positions(TARGET, 50.0, 3)[:count], strict=True):
        pose[:3, :3] = Rotation.from_rotvec(rng.uniform(-turn_rad, turn_rad, 3)).as_matrix()
        pose[:3, 3] = position
    return poses


def test_camera_poses_and_an_unknown_marker_offset_from_tool_poses() -> None:
    """27 tool poses turned up to ±0.3 rad, the marker 80 mm out on the tool, three cameras,
    seeded noise, the offset guessed as zero: the offset and every camera centre are found
    within 4 of their standard errors."""
    cameras = rig(3)
    rng = np.random.default_rng(9)
    poses = tool_poses(27, rng, 0.3)
    marker = np.array([15.0, -10.0, 80.0])
    points = poses[:, :3, :3] @ marker + poses[:, :3, 3]
    pixels = np.array([project(c, points) for c in cameras])
    noisy = pixels + rng.normal(0.0, SIGMA_PX, pixels.shape)
    noisy[2, :3] = np.nan  # the third camera misses three poses
    sigmas = np.full_like(noisy, SIGMA_PX)
    result = fit_cameras_and_marker(cameras, poses, noisy, sigmas)
    assert np.all(np.abs(result.marker_mm - marker) < 4 * result.marker_se_mm)
    assert np.all(result.marker_se_mm < 0.05)
    for fit, cam in zip(result.fits, cameras, strict=True):
        assert np.all(np.abs(fit.centre_mm - cam.centre_mm) < 4 * fit.centre_se_mm)
    assert [fit.points for fit in result.fits] == [27, 27, 24]
    assert 0.6 < result.reduced_chi2 < 1.5


def test_an_offset_the_tool_never_turns_about_is_refused() -> None:
    cameras = rig(2)
    poses = tool_poses(27, np.random.default_rng(1), 0.0)
    points = poses[:, :3, 3] + [0.0, 0.0, 80.0]
    pixels = np.array([project(c, points) for c in cameras])
    with pytest.raises(MultiviewError, match="never turns"):
        fit_cameras_and_marker(cameras, poses, pixels)


def test_the_thesis_layout_of_one_camera_per_axis_triangulates() -> None:
    """Thesis 7.2.2 proposes one camera per axis, mounted orthogonally: three cameras looking
    along world x, y and z at the work point. Each axis is then seen by the two cameras across
    it, at the same scale, so the covariance is diagonal and isotropic at the work point."""
    cameras = []
    for name, position, up in [
        ("along-x", (-1000.0, 0.0, 400.0), (0.0, 0.0, 1.0)),
        ("along-y", (0.0, -1000.0, 400.0), (0.0, 0.0, 1.0)),
        ("along-z", (0.0, 0.0, 1400.0), (0.0, 1.0, 0.0)),  # up along z is its optical axis
    ]:
        rvec, tvec = look_at(position, TARGET, up)
        cameras.append(
            CameraModel(
                name=name,
                matrix=intrinsic_matrix((2400.0, 2400.0), (375.5, 290.5)),
                distortion=np.zeros(5),
                rotation_rad=rvec,
                translation_mm=tvec,
                image_size_px=(752, 582),
                pixel_sigma_px=SIGMA_PX,
            )
        )
    truth = TARGET + np.array([3.0, -2.0, 1.5])
    pixels = np.vstack([project(c, truth) for c in cameras])
    point, _ = triangulate(cameras, pixels)
    assert point == pytest.approx(truth, abs=1e-9)
    _, at_centre = triangulate(cameras, np.vstack([project(c, TARGET) for c in cameras]))
    variance = (SIGMA_PX * 1000.0 / 2400.0) ** 2 / 2  # two views per axis, 1 m away
    assert at_centre == pytest.approx(np.diag([variance] * 3), rel=1e-6, abs=1e-15)
