"""``thermocomp calibrate cameras``: each camera's pose in the robot's world from marker positions
the robot visited (issue 20); the fit is the pure :mod:`daemon.vision.camera_pose`.

The cameras' intrinsics and distortion come from ``--cameras FILE`` (a camera file, see
README "Measuring in 3-D with several cameras"; the poses in it are not used). The observations
are either

* recorded: ``--observations CSV`` with one row per camera and position, columns
  ``camera,x_mm,y_mm,z_mm,x_px,y_px`` and optionally ``sigma_x_px,sigma_y_px`` (the centroid's
  own 1-sigma; without them the noise is estimated from the residuals), or
* simulated: ``--simulate TRUTH`` (a camera file of the true cameras): the marker visits a cube
  of ``--per-axis``³ positions ±``--size`` mm about ``--centre``, is rendered with photon and
  read noise in every true camera and measured by the robust centroid; ``--save-observations``
  keeps those rows as CSV; the output then also gives each camera's error from the truth.

Driving the arm through the daemon to record the observations is not part of this command yet:
record them with the arm (marker positions = commanded tool poses x the marker's tool offset)
and pass the CSV.

Exit statuses: 0 calibrated; 1 a fit failed (too few or collinear positions, a marker off a
camera's chip); 2 bad usage, an unreadable camera file or CSV.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, positive_float

if TYPE_CHECKING:
    from daemon.vision.camera_pose import CameraPoseFit
    from daemon.vision.cameras import CameraModel

# numpy, OpenCV and SciPy are imported where they are used: `--help` answers at once (issue 16)

PROG = "thermocomp calibrate cameras"
CSV_COLUMNS = ("camera", "x_mm", "y_mm", "z_mm", "x_px", "y_px")
SIGMA_COLUMNS = ("sigma_x_px", "sigma_y_px")
#: The simulated marker: a spot like the bench's laser spot (bench.spot_sigma_px, 16-bit,
#: half full scale, 1 e-/count, 5 e- read noise: the [camera] defaults).
SIM_SPOT_SIGMA_PX = 3.0
SIM_PEAK_FRACTION = 0.5
SIM_READ_NOISE_COUNTS = 5.0


class ObservationError(Exception):
    """The observations cannot be read or used (exit 2) ."""


@dataclass(frozen=True, slots=True)
class Observation:
    camera: str
    point_mm: tuple[float, float, float]
    pixel_px: tuple[float, float]
    sigma_px: tuple[float, float] | None


def register(kinds: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = kinds.add_parser(
        "cameras",
        help="fit each camera's pose (camera file) from marker positions the robot visited",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--cameras", type=Path, required=True, metavar="FILE", help="camera file (intrinsics)"
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--observations", type=Path, metavar="CSV", help="recorded observations")
    source.add_argument(
        "--simulate", type=Path, metavar="TRUTH", help="camera file of the true cameras"
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
        default=50.0,
        metavar="MM",
        help="simulation: half-width of the cube (default 50)",
    )
    parser.add_argument(
        "--per-axis",
        type=int,
        default=3,
        metavar="N",
        help="simulation: positions per axis (default 3: 27 positions)",
    )
    parser.add_argument("--seed", type=int, default=0, help="simulation: noise seed (default 0)")
    parser.add_argument(
        "--save-observations", type=Path, metavar="CSV", help="simulation: write the rows here"
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


def read_observations(path: Path) -> list[Observation]:
    """The CSV's rows (module docstring); ObservationError names the file and the row."""
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            missing = [c for c in CSV_COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                raise ObservationError(f"{path}: missing column(s) {', '.join(missing)}")
            with_sigma = all(c in (reader.fieldnames or []) for c in SIGMA_COLUMNS)
            rows = []
            for number, row in enumerate(reader, start=2):
                try:
                    values = [float(row[c]) for c in CSV_COLUMNS[1:]]
                    sigma = (
                        (float(row["sigma_x_px"]), float(row["sigma_y_px"])) if with_sigma else None
                    )
                except (TypeError, ValueError) as err:
                    raise ObservationError(f"{path}: line {number}: not a number ({err})") from err
                rows.append(
                    Observation(
                        row["camera"],
                        (values[0], values[1], values[2]),
                        (values[3], values[4]),
                        sigma,
                    )
                )
    except OSError as err:
        raise ObservationError(f"{path}: cannot read: {err.strerror}") from err
    if not rows:
        raise ObservationError(f"{path}: no observations")
    return rows


def write_observations(path: Path, rows: list[Observation]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow([*CSV_COLUMNS, *SIGMA_COLUMNS])
        for row in rows:
            sigma = row.sigma_px or ("", "")
            writer.writerow([row.camera, *row.point_mm, *row.pixel_px, *sigma])


def simulate_observations(
    truth: tuple[CameraModel, ...],
    centre_mm: tuple[float, float, float],
    size_mm: float,
    per_axis: int,
    seed: int,
) -> list[Observation]:
    """The marker rendered at every cube position in every true camera and measured."""
    import numpy as np

    from daemon.vision import CentroidError, measure_centroid
    from daemon.vision.camera_pose import grid_positions
    from daemon.vision.markers import render_marker_window
    from daemon.vision.multiview import MultiviewError

    rng = np.random.default_rng(seed)
    rows = []
    for point in grid_positions(centre_mm, size_mm, per_axis):
        for camera in truth:
            rendered = render_marker_window(
                camera,
                point,
                rng=rng,
                sigma_px=SIM_SPOT_SIGMA_PX,
                peak_fraction=SIM_PEAK_FRACTION,
                read_noise_counts=SIM_READ_NOISE_COUNTS,
            )
            where = f"({point[0]:g}, {point[1]:g}, {point[2]:g}) mm"
            if rendered is None:
                raise MultiviewError(f"camera {camera.name} does not see the marker at {where}")
            window, (column0, row0) = rendered
            try:
                result = measure_centroid(window)
            except CentroidError as err:
                raise MultiviewError(f"camera {camera.name}, marker at {where}: {err}") from err
            rows.append(
                Observation(
                    camera.name,
                    (float(point[0]), float(point[1]), float(point[2])),
                    (result.x_px + column0, result.y_px + row0),
                    (result.sigma_x_px, result.sigma_y_px),
                )
            )
    return rows


def fit_all(cameras: tuple[CameraModel, ...], rows: list[Observation]) -> list[CameraPoseFit]:
    from daemon.vision.camera_pose import fit_camera_pose

    names = {camera.name for camera in cameras}
    unknown = sorted({row.camera for row in rows} - names)
    if unknown:
        raise ObservationError(f"observations of unknown camera(s): {', '.join(unknown)}")
    fits = []
    for camera in cameras:
        mine = [row for row in rows if row.camera == camera.name]
        sigmas = [row.sigma_px for row in mine]
        given = None if any(s is None for s in sigmas) else [s for s in sigmas if s is not None]
        fits.append(
            fit_camera_pose(
                camera, [row.point_mm for row in mine], [row.pixel_px for row in mine], given
            )
        )
    return fits


def run_calibrate_cameras(args: argparse.Namespace) -> int:
    from daemon.vision.cameras import CameraFileError, cameras_toml, load_cameras, write_cameras
    from daemon.vision.multiview import MultiviewError

    if args.per_axis < 2:
        print(f"{PROG}: --per-axis must be 2 or more", file=sys.stderr)
        return EXIT_USAGE
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
            rows = simulate_observations(shown, args.centre, args.size, args.per_axis, args.seed)
            if args.save_observations is not None:
                write_observations(args.save_observations, rows)
        assert rows is not None
        fits = fit_all(cameras, rows)
    except ObservationError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_USAGE
    except MultiviewError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_FAILURE
    calibrated = tuple(fit.camera for fit in fits)
    truths = {c.name: c for c in truth} if truth is not None else {}
    if args.json:
        print(json.dumps([_as_dict(fit, truths.get(fit.camera.name)) for fit in fits], indent=2))
    else:
        for fit in fits:
            print(_summary(fit, truths.get(fit.camera.name)))
        if args.write is None:
            print(cameras_toml(calibrated), end="")
    if args.write is not None:
        write_cameras(args.write, calibrated)
        print(f"# written to {args.write}", file=sys.stderr)
    return EXIT_OK


def _as_dict(fit: CameraPoseFit, truth: CameraModel | None) -> dict[str, object]:
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


def _summary(fit: CameraPoseFit, truth: CameraModel | None) -> str:
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
