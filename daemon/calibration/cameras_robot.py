"""``thermocomp calibrate cameras --robot`` (issue 20): the checks before anything moves, the
pattern on the arm (:mod:`daemon.calibration.camera_run`), the fits of every camera that saw
enough markers (:mod:`daemon.commands.calibrate_cameras`: each camera alone, or with
``--fit-marker`` every camera and the markers' common offset together) and the camera file.

A camera that saw fewer than four markers (another station's camera, one whose guess is too far
off) is not fitted: it is named with the reason and keeps its pose from the initial file, so a
rig with a station per measured pose is calibrated one ``--station`` at a time into the same
file. Exit statuses as the command's: 0 at least one camera calibrated; 1 a device error
(the pattern stopped, the robot returned to the goal when the driver let it), no camera fitted
or a failed fit; 2 bad usage (no [arm], no camera file, a pattern beyond the limits, an unknown
station, cameras and camera file that do not match).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from config import Settings, load_settings
from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from daemon.calibration.camera_fit import (
    Calibrated,
    fit_as_dict,
    fit_known_marker,
    fit_summary,
    fit_with_marker,
)
from daemon.calibration.camera_observations import PROG, Observation, write_observations
from daemon.calibration.camera_pattern import (
    PatternError,
    check_pattern,
    default_size_turn,
    robot_pattern,
)
from daemon.calibration.camera_run import (
    SEARCH_HALF_PX,
    Recording,
    RobotRun,
    calibrate_with_robot,
    joints_pose,
    station_pose,
)
from daemon.vision.camera_pose import MIN_POSE_POINTS
from daemon.vision.cameras import (
    CameraFileError,
    CameraModel,
    cameras_toml,
    load_cameras,
    write_cameras,
)
from daemon.vision.multiview import MultiviewError
from drivers.errors import DeviceError

#: A camera is fitted only when the marker positions it saw spread across its view by at
#: least this fraction of its distance (RMS about their mean along the second principal axis):
#: a few millimetres' cluster 700 mm away (one marker of another station at the edge of the
#: frame, followed through the pattern) leaves the pose's depth and rotation undetermined. The
#: arm bench's 120 mm marker plate at 700 mm spreads over ~6 %.
MIN_SPREAD_OF_DISTANCE = 0.02


#: A fitted camera is kept only when its reduced chi² (residuals over the centroids' sigmas)
#: is below this: residuals five times the noise mean the read-back tool poses are not where
#: the markers were (e.g. at a wrist singularity the controller swings joints 4 and 6 for a
#: small move, and the real wrist, not exactly spherical, carries the tool elsewhere).
MAX_REDUCED_CHI2 = 25.0


def usage(message: str) -> int:
    """Bad usage, before anything opens: one line, EXIT_USAGE (A465 and UR alike)."""
    print(f"{PROG}: {message}", file=sys.stderr)
    return EXIT_USAGE


def pattern_stopped(err: DeviceError, done: int, total: int, where: str) -> int:
    """A device error stopped the pattern after ``done`` of ``total`` poses: one line saying
    ``where`` the robot (A465) or the correction (UR) is now, EXIT_FAILURE."""
    print(
        f"{PROG}: {err}; the pattern stopped after {done} of {total} poses, {where}",
        file=sys.stderr,
    )
    return EXIT_FAILURE


def fit_and_report(
    args: argparse.Namespace,
    run: RobotRun,
    rows: list[Observation],
    *,
    models: tuple[CameraModel, ...],
    guess_path: Path,
    hint: str,
    extra: dict[str, object] | None = None,
) -> int:
    """The recorded ``rows`` (``--save-observations``: written first, as fitted) fitted into
    the cameras (:func:`fit_robot_rows`, ``--fit-marker``) and reported (:func:`report`):
    EXIT_OK; a failed fit, or no camera fitted (one line ending with ``hint``): EXIT_FAILURE."""
    if args.save_observations is not None:  # the rows fitted: --observations fits them again
        write_observations(args.save_observations, rows)
    try:
        calibrated, skipped = fit_robot_rows(models, rows, args.fit_marker)
    except MultiviewError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_FAILURE
    if calibrated is None:
        print(
            f"{PROG}: no camera calibrated from {run.recording.poses} poses: "
            + "; ".join(f"{name} {why}" for name, why in skipped.items())
            + f" ({hint})",
            file=sys.stderr,
        )
        return EXIT_FAILURE
    report(
        args,
        run,
        models=models,
        calibrated=calibrated,
        skipped=skipped,
        guess_path=guess_path,
        extra=extra,
    )
    return EXIT_OK


def fit_robot_rows(
    cameras: tuple[CameraModel, ...], rows: list[Observation], fit_marker: bool
) -> tuple[Calibrated | None, dict[str, str]]:
    """The fitted cameras (those with at least MIN_POSE_POINTS markers seen; each alone, or all
    with the markers' common offset) and, by name, why each other camera was not fitted."""
    skipped: dict[str, str] = {}
    usable = []
    for camera in cameras:
        points = np.array([row.position_mm for row in rows if row.camera == camera.name])
        if points.size == 0:
            skipped[camera.name] = "saw no marker at any pose"
            continue
        if len(points) < MIN_POSE_POINTS:
            skipped[camera.name] = (
                f"saw only {len(points)} marker(s): a pose needs {MIN_POSE_POINTS}"
            )
            continue
        spread = float(
            np.sqrt(
                np.linalg.svd(points - points.mean(axis=0), compute_uv=False)[1] ** 2 / len(points)
            )
        )
        distance = float(np.linalg.norm(points.mean(axis=0) - camera.centre_mm))
        if spread < MIN_SPREAD_OF_DISTANCE * distance:
            skipped[camera.name] = (
                f"the {len(points)} marker positions it saw spread over {spread:.2f} mm (RMS "
                f"across), {100 * spread / distance:.2f} % of its distance: at least "
                f"{100 * MIN_SPREAD_OF_DISTANCE:g} % fixes a pose (a marker of another "
                "station at its edge?)"
            )
            continue
        usable.append(camera)
    if not usable:
        return None, skipped
    names = {camera.name for camera in usable}
    mine = [row for row in rows if row.camera in names]
    if fit_marker:
        joint = fit_with_marker(tuple(usable), mine, (0.0, 0.0, 0.0))
        fits, marker, marker_se = list(joint.fits), joint.marker_mm, joint.marker_se_mm
    else:
        fits, marker, marker_se = [], (0.0, 0.0, 0.0), None
        for camera in usable:
            try:
                own = [row for row in mine if row.camera == camera.name]
                one = fit_known_marker((camera,), own, (0.0, 0.0, 0.0))
            except (MultiviewError, cv2.error) as err:
                skipped[camera.name] = str(err).strip().splitlines()[-1]
                continue
            fits.extend(one.fits)
    kept = []
    for fit in fits:
        if fit.reduced_chi2 > MAX_REDUCED_CHI2:
            skipped[fit.camera.name] = (
                f"its fit leaves {fit.residual_px:.3f} px RMS, reduced chi2 "
                f"{fit.reduced_chi2:.0f} > {MAX_REDUCED_CHI2:g}: the tool was not where the "
                "read-back put it (a goal at the wrist singularity? choose one off it, e.g. "
                "--joints with the wrist bent)"
            )
        else:
            kept.append(fit)
    if not kept:
        return None, skipped
    return Calibrated(kept, marker, marker_se), skipped


@dataclass(frozen=True, eq=False)
class Guess:
    """What ``--robot`` starts from: the camera file (the initial guess) and the search
    window's half-width (px)."""

    models: tuple[CameraModel, ...]
    path: Path
    search_half_px: int


def robot_guess(args: argparse.Namespace, settings: Settings) -> Guess | str:
    """The guess of ``--robot`` (A465 and UR alike), or the one line refusing it."""
    if not settings.arm.enabled:
        return (
            "--robot needs the [arm] section with enabled = true (the arm, its markers and "
            "the cameras watching them)"
        )
    path = args.cameras or (
        Path(settings.arm.cameras_file) if settings.arm.cameras_file is not None else None
    )
    if path is None:
        return (
            "no camera file: give --cameras FILE or set arm.cameras_file (the initial guess: "
            "intrinsics known, poses approximate)"
        )
    try:
        models = load_cameras(path)
    except CameraFileError as err:
        return str(err)
    search = SEARCH_HALF_PX if args.search_px is None else args.search_px
    if search < 4:
        return "--search-px must be 4 or more"
    return Guess(models, path, search)


def run_with_robot(args: argparse.Namespace) -> int:
    settings = load_settings(args.config)
    guess = robot_guess(args, settings)
    if isinstance(guess, str):
        return usage(guess)
    models, path, search = guess.models, guess.path, guess.search_half_px
    size, turn = default_size_turn(settings)
    size = size if args.size is None else args.size
    # turns only make the markers' offset observable: without --fit-marker the tool keeps its
    # orientation (an offset then shifts every camera alike; docs/how-to/calibrate-cameras.md)
    turn = (turn if args.fit_marker else 0.0) if args.turn is None else args.turn
    if args.fit_marker and turn == 0.0:
        return usage("--fit-marker needs the tool to turn: --turn must be above 0")
    try:
        shifts = robot_pattern(size, args.per_axis, turn, args.seed)
        check_pattern(settings, shifts)
        if args.station is not None:  # refused now, before anything opens
            station_pose(settings, args.station)
        if args.joints is not None:
            joints_pose(settings, args.joints)
    except PatternError as err:
        return usage(str(err))
    recording = Recording("")
    try:
        run = asyncio.run(
            calibrate_with_robot(
                settings,
                models,
                shifts,
                station=args.station,
                joints_deg=args.joints,
                search_half_px=search,
                recording=recording,
            )
        )
    except PatternError as err:
        return usage(str(err))
    except DeviceError as err:
        back = "returned to" if recording.returned else "could NOT return to"
        where = f"the robot {back} the goal {recording.goal!r}"
        return pattern_stopped(err, recording.poses, len(shifts), where)
    return fit_and_report(
        args,
        run,
        run.recording.rows,
        models=models,
        guess_path=path,
        hint="is the goal in front of the cameras? is the camera file's guess near?",
    )


def report(
    args: argparse.Namespace,
    run: RobotRun,
    *,
    models: tuple[CameraModel, ...],
    calibrated: Calibrated,
    skipped: dict[str, str],
    guess_path: Path,
    extra: dict[str, object] | None = None,
) -> None:
    """The fitted cameras (JSON or summary lines), the camera file printed or written;
    ``extra``: more JSON keys (and one summary line each)."""
    record = run.recording
    fitted = {fit.camera.name: fit for fit in calibrated.fits}
    cameras = [fitted[m.name].camera if m.name in fitted else m for m in models]
    reference = {m.name: r for m, r in zip(models, run.reference or (), strict=False)}
    if args.json:
        data: dict[str, object] = {
            "goal": record.goal,
            "poses": record.poses,
            "moves": record.moves,
            "returned_to_goal": record.returned,
            "cameras": [fit_as_dict(f, reference.get(f.camera.name)) for f in calibrated.fits],
            "not_fitted": [{"camera": n, "reason": why} for n, why in skipped.items()],
            "markers_seen": {m.name: record.seen_poses.get(m.name, 0) for m in models},
            "markers_missed": dict(record.missed),
            "marker_mm": list(calibrated.marker_mm),
            "marker_se_mm": (
                list(calibrated.marker_se_mm) if calibrated.marker_se_mm is not None else None
            ),
        }
        if run.kinematic_error is not None:
            # the arm bench: errors above are from the truth as the controller's frame sees it
            data["bench_kinematic_error"] = {
                "translation_mm": run.kinematic_error[0],
                "rotation_mrad": run.kinematic_error[1],
            }
        print(json.dumps(data | (extra or {}), indent=2))
    else:
        missed = ", ".join(f"{n} {k}" for n, k in record.missed.items() if k)
        print(
            f"# {record.poses} poses around the goal {record.goal!r} ({record.moves} moves), "
            f"back at the goal: {'yes' if record.returned else 'NO'}; markers the guess put "
            f"on a chip but not found there: {missed or 'none'}"
        )
        for fit in calibrated.fits:
            print(fit_summary(fit, reference.get(fit.camera.name)))
        for name, why in skipped.items():
            print(f"# {name}: not fitted, {why}: its pose is kept from {guess_path}")
        if calibrated.marker_se_mm is not None:
            offset = ", ".join(
                f"{v:.4f}+-{s:.4f}"
                for v, s in zip(calibrated.marker_mm, calibrated.marker_se_mm, strict=True)
            )
            print(f"# the markers' common offset from arm.markers_mm: ({offset}) mm, tool frame")
        if run.kinematic_error is not None:
            print(
                "# arm bench: errors are from the truth's cameras in the controller's frame "
                f"(the arm's kinematic error at the goal: {run.kinematic_error[0]:.3f} mm, "
                f"{run.kinematic_error[1]:.3f} mrad)"
            )
        for key, value in (extra or {}).items():
            print(f"# {key}: {json.dumps(value)}")
        if args.write is None:
            print(cameras_toml(cameras), end="")
    if args.write is not None:
        write_cameras(args.write, cameras)
        print(f"# written to {args.write}", file=sys.stderr)
