"""``thermocomp calibrate cameras``: each camera's pose in the robot's world from marker positions
the robot visited; the fits are the pure :mod:`daemon.vision.camera_pose` and
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
  too few markers keep their pose. On a UR (``robot.driver = "ur-rtde"``) the PC does not
  move the robot: the cube is a pattern of offsets (±``--size``, default half
  robot.correction_limit_mm) the robot's own program applies, recorded while it dwells at its
  measured poses (all of them, or ``--station NAME``; daemon/calibration/cameras_ur.py).

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
from pathlib import Path

from config import load_settings
from config.cli import (
    EXIT_FAILURE,
    EXIT_OK,
    EXIT_USAGE,
    add_config_argument,
    positive_float,
)
from daemon.calibration.camera_observations import (
    PROG,
    ObservationError,
    read_observations,
    write_observations,
)


# numpy, OpenCV and SciPy are imported where they are used: `--help` answers at once (issue 16);
# the work is daemon/calibration/camera_fit.py (and cameras_robot.py for --robot)
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


def run_calibrate_cameras(args: argparse.Namespace) -> int:
    # lazy: NumPy, SciPy and OpenCV load when the command runs, not for --help (issue 16)
    from daemon.calibration.camera_fit import (
        fit_as_dict,
        fit_known_marker,
        fit_summary,
        fit_with_marker,
        simulate_observations,
    )
    from daemon.calibration.cameras_robot import run_with_robot
    from daemon.vision.cameras import CameraFileError, cameras_toml, load_cameras, write_cameras
    from daemon.vision.multiview import MultiviewError

    if args.per_axis < 2:
        print(f"{PROG}: --per-axis must be 2 or more", file=sys.stderr)
        return EXIT_USAGE
    if args.turn is not None and not (math.isfinite(args.turn) and 0.0 <= args.turn <= math.pi):
        print(f"{PROG}: --turn must be between 0 and pi rad", file=sys.stderr)
        return EXIT_USAGE
    if args.robot:
        if load_settings(args.config).robot.driver == "ur-rtde":
            # lazy: the UR's pattern (offsets at its program's dwells) loads only for a UR
            from daemon.calibration.cameras_ur import run_with_ur

            return run_with_ur(args)
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
