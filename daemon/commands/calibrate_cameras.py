"""``thermocomp calibrate cameras``: each camera's pose in the robot's world from marker positions
the robot visited (issue 20); the fits are the pure :mod:`daemon.vision.camera_pose` and
:mod:`daemon.vision.camera_rig`.

The cameras' intrinsics and distortion come from ``--cameras FILE`` (a camera file, see
docs/how-to/calibrate-cameras.md; the poses in it are not used). The observations
are either

* recorded: ``--observations CSV`` with one row per camera and tool pose, columns
  ``camera,x_mm,y_mm,z_mm,x_px,y_px``, optionally ``rx_rad,ry_rad,rz_rad`` (the tool's
  rotation vector; zero without them) and ``sigma_x_px,sigma_y_px`` (the centroid's own
  1-sigma; without them the noise is estimated from the residuals), or
* simulated: ``--simulate TRUTH`` (a camera file of the true cameras): the tool visits a cube
  of ``--per-axis``³ positions ±``--size`` mm about ``--centre``, turned at random by up to
  ``--turn`` rad about each axis (seeded); the marker at ``--true-marker`` on it is rendered
  with photon and read noise in every true camera and measured by the robust centroid;
  ``--save-observations`` keeps those rows as CSV; the output then also gives each camera's
  error from the truth, or
* measured with the arm: ``--robot`` (with ``--config``: the ``[arm]`` section, its camera
  file as the initial guess, its cameras and markers) teaches the goal (``--here``, the duty
  cycle's pose ``--station NAME`` or ``--joints J1,...`` in degrees), moves the tool through
  the cube of ``--per-axis``³ poses ±``--size`` mm about it, turned at random by up to
  ``--turn`` rad (the whole pattern within arm.calibration_max_* or the arm's correction
  limits, else nothing moves), grabs a frame from every camera at each and finds every marker
  near where the initial guess puts it (daemon/calibration/camera_run.py); cameras that saw
  too few markers keep their pose.

The marker sits at ``--marker`` (mm, tool frame; default 0,0,0: the tool point, so that x, y,
z are the marker's own positions), i.e. at ``R marker + p`` in the world. With
``--fit-marker`` that offset is only the starting guess and is fitted together with the
cameras (the tool must turn between poses). With ``--robot`` every marker of arm.markers_mm
is observed at its own position and the fitted offset is their common shift on the tool.

Exit statuses: 0 calibrated; 1 a fit failed (a camera saw the marker at fewer than four
positions, positions on one line, an offset the moves do not determine; with --robot: no camera
could be fitted) or a device failed; 2 bad usage, an unreadable camera file or CSV, a pattern
beyond the limits.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from config.cli import (
    EXIT_FAILURE,
    EXIT_OK,
    EXIT_USAGE,
    add_config_argument,
    positive_float,
)
from daemon.calibration.camera_observations import (
    Observation,
    ObservationError,
    read_observations,
    write_observations,
)

if TYPE_CHECKING:
    from daemon.vision.camera_pose import CameraPoseFit
    from daemon.vision.cameras import CameraModel

# numpy, OpenCV and SciPy are imported where they are used: `--help` answers at once (issue 16)

PROG = "thermocomp calibrate cameras"
#: The simulated marker: a spot like the bench's laser spot (bench.spot_sigma_px, 16-bit,
#: half full scale, 1 e-/count, 5 e- read noise: the [camera] defaults).
SIM_SPOT_SIGMA_PX = 3.0
SIM_PEAK_FRACTION = 0.5
SIM_READ_NOISE_COUNTS = 5.0


def register(kinds: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = kinds.add_parser(
        "cameras",
        help="fit each camera's pose (camera file) from marker positions the robot visited",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--cameras",
        type=Path,
        metavar="FILE",
        help="camera file (intrinsics; with --robot the initial guess, default arm.cameras_file)",
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--observations", type=Path, metavar="CSV", help="recorded observations")
    source.add_argument(
        "--simulate", type=Path, metavar="TRUTH", help="camera file of the true cameras"
    )
    source.add_argument(
        "--robot",
        action="store_true",
        help="move the arm through the pattern and grab the frames ([arm] of --config)",
    )
    add_config_argument(parser)
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--station",
        metavar="NAME",
        help="robot: calibrate around this pose of arm.duty_cycle (reached and taught first)",
    )
    where.add_argument(
        "--joints",
        type=_angles,
        metavar="J1,J2,...",
        help="robot: calibrate around these joint angles (deg; reached and taught first)",
    )
    where.add_argument(
        "--here",
        action="store_true",
        help="robot: calibrate around where the robot stands (the default)",
    )
    parser.add_argument(
        "--search-px",
        type=int,
        default=None,
        metavar="PX",
        help="robot: half-width of the window each marker is searched in around where the "
        "camera file puts it (default 96)",
    )
    parser.add_argument(
        "--centre",
        type=_triple,
        default=(0.0, 0.0, 400.0),
        metavar="X,Y,Z",
        help="simulation: centre of the cube of positions (mm, world; default 0,0,400)",
    )
    parser.add_argument(
        "--size",
        type=positive_float,
        default=None,
        metavar="MM",
        help="half-width of the cube (simulation: default 50; robot: half the limit)",
    )
    parser.add_argument(
        "--per-axis",
        type=int,
        default=3,
        metavar="N",
        help="simulation: positions per axis (default 3: 27 positions)",
    )
    parser.add_argument(
        "--turn",
        type=float,
        default=None,
        metavar="RAD",
        help="turn the tool at random by up to this about each axis (simulation: default 0; "
        "robot: within half the rotation limit)",
    )
    parser.add_argument(
        "--marker",
        type=_triple,
        default=(0.0, 0.0, 0.0),
        metavar="X,Y,Z",
        help="the marker's offset on the tool (mm, tool frame; default 0,0,0: the tool point)",
    )
    parser.add_argument(
        "--fit-marker",
        action="store_true",
        help="fit the marker's offset too (--marker is the guess; the tool must turn)",
    )
    parser.add_argument(
        "--true-marker",
        type=_triple,
        metavar="X,Y,Z",
        help="simulation: the marker's true offset on the tool (default --marker)",
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="simulation: noise seed; robot: turns (default 0)"
    )
    parser.add_argument(
        "--save-observations", type=Path, metavar="CSV", help="simulation, robot: write the rows"
    )
    parser.add_argument(
        "--write", type=Path, metavar="FILE", help="write the calibrated camera file here"
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(handler=run_calibrate_cameras)


def _triple(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected X,Y,Z in mm, got {text!r}") from err
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected three finite numbers X,Y,Z, got {text!r}")
    return values[0], values[1], values[2]


def _angles(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError as err:
        raise argparse.ArgumentTypeError(
            f"expected joint angles J1,J2,... in deg, got {text!r}"
        ) from err
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite joint angles, got {text!r}")
    return values


def simulate_observations(
    truth: tuple[CameraModel, ...],
    args: argparse.Namespace,
) -> list[Observation]:
    """The marker rendered at every tool pose of the cube in every true camera and measured;
    a camera that does not see it at a pose (off the chip, cut by its edge) has no row there."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from daemon.vision import CentroidError, measure_centroid
    from daemon.vision.camera_pose import grid_positions
    from daemon.vision.markers import render_marker_window

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
    import numpy as np
    from scipy.spatial.transform import Rotation

    from daemon.vision.camera_pose import fit_camera_pose

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
    import numpy as np
    from scipy.spatial.transform import Rotation

    from daemon.vision.camera_rig import fit_cameras_and_marker

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


def run_calibrate_cameras(args: argparse.Namespace) -> int:
    from daemon.vision.cameras import CameraFileError, cameras_toml, load_cameras, write_cameras
    from daemon.vision.multiview import MultiviewError

    if args.per_axis < 2:
        print(f"{PROG}: --per-axis must be 2 or more", file=sys.stderr)
        return EXIT_USAGE
    if args.turn is not None and not (math.isfinite(args.turn) and 0.0 <= args.turn <= math.pi):
        print(f"{PROG}: --turn must be between 0 and pi rad", file=sys.stderr)
        return EXIT_USAGE
    if args.robot:
        from daemon.calibration.cameras_robot import run_with_robot

        return run_with_robot(args)
    robot_only = [
        option
        for option, value in (
            ("--station", args.station),
            ("--joints", args.joints),
            ("--here", args.here),
            ("--search-px", args.search_px),
            ("--config", args.config),
        )
        if value
    ]
    if robot_only:
        print(f"{PROG}: {robot_only[0]} goes with --robot", file=sys.stderr)
        return EXIT_USAGE
    if args.cameras is None:
        print(f"{PROG}: --cameras FILE is needed (the cameras' intrinsics)", file=sys.stderr)
        return EXIT_USAGE
    args.size = 50.0 if args.size is None else args.size
    args.turn = 0.0 if args.turn is None else args.turn
    try:
        cameras = load_cameras(args.cameras)
        truth = load_cameras(args.simulate) if args.simulate is not None else None
        rows = read_observations(args.observations) if args.observations is not None else None
    except (CameraFileError, ObservationError) as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_USAGE
    try:
        if truth is not None:
            missing = sorted({c.name for c in cameras} - {c.name for c in truth})
            if missing:
                print(
                    f"{PROG}: {args.simulate}: no camera(s) {', '.join(missing)}", file=sys.stderr
                )
                return EXIT_USAGE
            shown = tuple(c for c in truth if c.name in {m.name for m in cameras})
            rows = simulate_observations(shown, args)
            if args.save_observations is not None:
                write_observations(args.save_observations, rows)
        assert rows is not None
        fit = fit_with_marker if args.fit_marker else fit_known_marker
        calibrated = fit(cameras, rows, args.marker)
    except ObservationError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_USAGE
    except MultiviewError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_FAILURE
    fits = calibrated.fits
    truths = {c.name: c for c in truth} if truth is not None else {}
    marker_line = (
        "# marker offset on the tool: ("
        + ", ".join(
            f"{v:.4f}" + (f"+-{s:.4f}" if calibrated.marker_se_mm is not None else "")
            for v, s in zip(
                calibrated.marker_mm, calibrated.marker_se_mm or (0.0,) * 3, strict=True
            )
        )
        + ") mm"
        + ("" if calibrated.marker_se_mm is not None else " (given)")
    )
    if args.json:
        data = {
            "cameras": [fit_as_dict(f, truths.get(f.camera.name)) for f in fits],
            "marker_mm": list(calibrated.marker_mm),
            "marker_se_mm": (
                list(calibrated.marker_se_mm) if calibrated.marker_se_mm is not None else None
            ),
        }
        print(json.dumps(data, indent=2))
    else:
        for one in fits:
            print(fit_summary(one, truths.get(one.camera.name)))
        print(marker_line)
        if args.write is None:
            print(cameras_toml([f.camera for f in fits]), end="")
    if args.write is not None:
        write_cameras(args.write, [f.camera for f in fits])
        print(f"# written to {args.write}", file=sys.stderr)
    return EXIT_OK


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
