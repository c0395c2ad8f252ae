"""The fits of ``thermocomp calibrate cameras`` (daemon/commands/calibrate_cameras.py): each
camera's pose from marker observations, with the marker's offset on the tool given or fitted
(the pure :mod:`daemon.vision.camera_pose` and :mod:`daemon.vision.camera_rig`), the simulated
observations of ``--simulate``, and the fits as JSON rows or summary lines. The ``--robot``
mode (daemon/calibration/cameras_robot.py) fits with the same functions."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from daemon.calibration.camera_observations import Observation, ObservationError
from daemon.vision import CentroidError, measure_centroid
from daemon.vision.camera_pose import CameraPoseFit, fit_camera_pose, grid_positions
from daemon.vision.camera_rig import fit_cameras_and_marker
from daemon.vision.cameras import CameraModel
from daemon.vision.markers import render_marker_window

#: The simulated marker: a spot like the bench's laser spot (bench.spot_sigma_px, 16-bit,
#: half full scale, 1 e-/count, 5 e- read noise: the [camera] defaults).
SIM_SPOT_SIGMA_PX = 3.0
SIM_PEAK_FRACTION = 0.5
SIM_READ_NOISE_COUNTS = 5.0


def simulate_observations(
    truth: tuple[CameraModel, ...],
    args: argparse.Namespace,
) -> list[Observation]:
    """The marker rendered at every tool pose of the cube in every true camera and measured;
    a camera that does not see it at a pose (off the chip, cut by its edge) has no row there."""
    rng = np.random.default_rng(args.seed)
    marker = np.array(args.true_marker if args.true_marker is not None else args.marker)
    rows = []
    for position in grid_positions(args.centre, args.size, args.per_axis):
        turn = rng.uniform(-args.turn, args.turn, 3) if args.turn > 0 else np.zeros(3)
        point = Rotation.from_rotvec(turn).as_matrix() @ marker + position
        for camera in truth:
            rendered = render_marker_window(
                camera,
                point,
                rng=rng,
                sigma_px=SIM_SPOT_SIGMA_PX,
                peak_fraction=SIM_PEAK_FRACTION,
                read_noise_counts=SIM_READ_NOISE_COUNTS,
            )
            if rendered is None:
                continue  # off this camera's chip: it sees fewer positions (the fit says so)
            window, (column0, row0) = rendered
            try:
                result = measure_centroid(window)
            except CentroidError:
                continue
            if "edge" in result.flags:
                continue
            rows.append(
                Observation(
                    camera.name,
                    (float(position[0]), float(position[1]), float(position[2])),
                    (result.x_px + column0, result.y_px + row0),
                    (result.sigma_x_px, result.sigma_y_px),
                    (float(turn[0]), float(turn[1]), float(turn[2])),
                )
            )
    return rows


@dataclass(frozen=True, eq=False)
class Calibrated:
    fits: list[CameraPoseFit]
    marker_mm: tuple[float, float, float]
    marker_se_mm: tuple[float, float, float] | None  # None: given, not fitted


def _checked(cameras: tuple[CameraModel, ...], rows: list[Observation]) -> None:
    unknown = sorted({row.camera for row in rows} - {camera.name for camera in cameras})
    if unknown:
        raise ObservationError(f"observations of unknown camera(s): {', '.join(unknown)}")


def fit_known_marker(
    cameras: tuple[CameraModel, ...], rows: list[Observation], marker: tuple[float, float, float]
) -> Calibrated:
    """Each camera on its own: the marker's world positions follow from the tool poses."""
    _checked(cameras, rows)
    fits = []
    for camera in cameras:
        mine = [row for row in rows if row.camera == camera.name]
        turns = Rotation.from_rotvec(np.array([row.rotation_rad for row in mine]).reshape(-1, 3))
        points = turns.apply(np.array(marker)) + np.array([row.position_mm for row in mine])
        sigmas = [row.sigma_px for row in mine]
        given = None if any(s is None for s in sigmas) else [s for s in sigmas if s is not None]
        fits.append(fit_camera_pose(camera, points, [row.pixel_px for row in mine], given))
    return Calibrated(fits, marker, None)


def fit_with_marker(
    cameras: tuple[CameraModel, ...], rows: list[Observation], guess: tuple[float, float, float]
) -> Calibrated:
    """Cameras and the marker's offset together (camera_rig): rows grouped by tool pose."""
    _checked(cameras, rows)
    keys: dict[tuple[float, ...], int] = {}
    for row in rows:
        keys.setdefault((*row.position_mm, *row.rotation_rad), len(keys))
    index = {camera.name: c for c, camera in enumerate(cameras)}
    pixels = np.full((len(cameras), len(keys), 2), np.nan)
    sigmas = np.full_like(pixels, np.nan)
    for row in rows:
        where = (index[row.camera], keys[(*row.position_mm, *row.rotation_rad)])
        pixels[where] = row.pixel_px
        sigmas[where] = row.sigma_px if row.sigma_px is not None else np.nan
    poses = np.tile(np.eye(4), (len(keys), 1, 1))
    for key, k in keys.items():
        poses[k, :3, :3] = Rotation.from_rotvec(key[3:]).as_matrix()
        poses[k, :3, 3] = key[:3]
    given = bool(np.all(np.isfinite(sigmas[np.isfinite(pixels)])))  # every centroid's own
    result = fit_cameras_and_marker(
        list(cameras),
        poses,
        pixels,
        np.where(np.isfinite(sigmas), sigmas, 1.0) if given else None,
        guess,
    )
    m, se = result.marker_mm, result.marker_se_mm
    return Calibrated(
        list(result.fits),
        (float(m[0]), float(m[1]), float(m[2])),
        (float(se[0]), float(se[1]), float(se[2])),
    )


def fit_as_dict(fit: CameraPoseFit, truth: CameraModel | None) -> dict[str, object]:
    data: dict[str, object] = {
        "camera": fit.camera.name,
        "points": fit.points,
        "rotation_rad": fit.camera.rotation_rad.tolist(),
        "rotation_se_rad": fit.camera.rotation_se_rad.tolist(),
        "translation_mm": fit.camera.translation_mm.tolist(),
        "translation_se_mm": fit.camera.translation_se_mm.tolist(),
        "centre_mm": fit.centre_mm.tolist(),
        "centre_se_mm": fit.centre_se_mm.tolist(),
        "residual_px": fit.residual_px,
        "reduced_chi2": fit.reduced_chi2,
    }
    if truth is not None:
        data["centre_error_mm"] = (fit.centre_mm - truth.centre_mm).tolist()
        data["rotation_error_rad"] = (fit.camera.rotation_rad - truth.rotation_rad).tolist()
    return data


def fit_summary(fit: CameraPoseFit, truth: CameraModel | None) -> str:
    centre = ", ".join(
        f"{v:.3f}+-{s:.3f}" for v, s in zip(fit.centre_mm, fit.centre_se_mm, strict=True)
    )
    line = (
        f"# {fit.camera.name}: {fit.points} positions, residual {fit.residual_px:.4f} px RMS, "
        f"reduced chi2 {fit.reduced_chi2:.2f}; centre ({centre}) mm"
    )
    if truth is not None:
        error = fit.centre_mm - truth.centre_mm
        line += "; error from the truth (" + ", ".join(f"{v:+.4f}" for v in error) + ") mm"
    return line
