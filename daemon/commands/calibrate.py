"""``thermocomp calibrate camera``: the camera's micrometres per pixel and rotation, measured with
the robot itself; the fit is the pure :mod:`daemon.vision.calibration`.

With the robot jogged to the goal (the spot near the chip's centre), the command teaches that
pose as the goal, moves the robot through a square grid of known offsets in the camera plane
(world x and z; ``--size``/``--step`` or camera.calibration_size_mm/step_mm), grabs a frame and
measures the spot at each, fits, and returns the robot to the goal whatever happened.

Safety: the whole pattern must lie within compensation.max_total_offset_mm of the goal or nothing
moves (exit 2); a move longer than compensation.max_step_change_mm is split into steps along the
straight line, which stays inside the (convex) pattern. Nothing moves beyond the declared pattern.
Exit statuses (docs/reference/cli.md): 0 calibrated; 1 a device, the spot (it left the chip) or the
fit (singular) failed; 2 bad usage, a pattern beyond the limits, or an invalid configuration.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from config import Settings, load_settings
from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, add_config_argument, positive_float
from daemon.commands import calibrate_cameras, calibrate_model  # light: heavy where they run
from daemon.commands.followed_refusals import cameras_refusal
from drivers.base import Vector3
from drivers.clock import make_clock
from drivers.deadline import bounded
from drivers.errors import DeviceError

if TYPE_CHECKING:
    from daemon.vision.calibration import CameraCalibration
    from drivers.factory import Devices

# the vision modules (OpenCV, SciPy) and the drivers are imported where they are used:
# `thermocomp calibrate --help` must answer at once (issue 16)

logger = logging.getLogger(__name__)

UM_PER_MM = 1000.0
PROG = "thermocomp calibrate camera"


class PatternError(Exception):
    """The declared pattern breaks a safety limit: nothing is moved (exit 2)."""


class SpotLostError(Exception):
    """The spot could not be measured at one of the offsets (exit 1)."""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "calibrate",
        help="calibrate with the robot: the camera, several cameras in 3-D, or the model",
        description="Calibrate with the robot itself. `calibrate camera`: with the robot at "
        "the goal (spot near the chip's centre), move it through a square grid of known "
        "offsets in the camera plane, measure the spot at each, and fit the micrometres per "
        "pixel in x and y and the camera's rotation from the robot's axes, with standard "
        "errors. The robot returns to the goal at the end. `calibrate cameras`: each camera's "
        "pose in the world (camera file) from marker positions the robot visited. "
        "`calibrate model`: an "
        "uncompensated run, identification of the network from it (saved by name), and a "
        "compensated validation run with it.",
    )
    kinds = parser.add_subparsers(dest="device", metavar="DEVICE", required=True)
    camera = kinds.add_parser(
        "camera",
        help="fit camera.um_per_px and camera.rotation_deg from robot moves",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_config_argument(camera)
    camera.add_argument(
        "--size",
        type=positive_float,
        metavar="MM",
        help="half-width of the square pattern (default camera.calibration_size_mm)",
    )
    camera.add_argument(
        "--step",
        type=positive_float,
        metavar="MM",
        help="spacing of the pattern's offsets (default camera.calibration_step_mm)",
    )
    output = camera.add_mutually_exclusive_group()
    output.add_argument(
        "--write", type=Path, metavar="FILE", help="set the [camera] keys in this TOML file"
    )
    output.add_argument(
        "--print", action="store_true", help="print the [camera] TOML (the default)"
    )
    camera.add_argument("--json", action="store_true", help="print the result as JSON")
    camera.set_defaults(handler=run_calibrate_camera)
    calibrate_cameras.register(kinds)  # `calibrate cameras`: 3-D camera poses (issue 20)
    calibrate_model.add_parser(kinds)


def split_move(start: Vector3, end: Vector3, max_step_mm: float) -> list[Vector3]:
    """Points from ``start`` (excluded) to ``end`` (included) no farther apart than
    ``max_step_mm`` along every axis, on the straight line between them."""
    longest = max(abs(e - s) for s, e in zip(start, end, strict=True))
    count = max(1, math.ceil(longest / max_step_mm - 1e-9))
    between: list[Vector3] = [
        (
            start[0] + (end[0] - start[0]) * k / count,
            start[1] + (end[1] - start[1]) * k / count,
            start[2] + (end[2] - start[2]) * k / count,
        )
        for k in range(1, count)
    ]
    return [*between, end]  # the end exactly, not as rounded arithmetic gives it


def robot_offset_mm(offset_um: tuple[float, float]) -> Vector3:
    """A pattern offset (u along world x, v along world -z: image rows grow downwards) as the
    robot's offset from the goal (mm)."""
    u, v = offset_um
    return (u / UM_PER_MM, 0.0, -v / UM_PER_MM)


def checked_pattern(
    settings: Settings, size_mm: float, step_mm: float
) -> list[tuple[float, float]]:
    """The pattern's offsets (um), or PatternError if it breaks the compensation limits."""
    # lazy: OpenCV loads when the command runs, not for --help (issue 16)
    from daemon.vision.calibration import CalibrationError, pattern_offsets_um

    try:
        offsets = pattern_offsets_um(size_mm * UM_PER_MM, step_mm * UM_PER_MM)
    except CalibrationError as err:
        raise PatternError(str(err)) from err
    farthest_mm = max(math.hypot(u, v) for u, v in offsets) / UM_PER_MM
    limit_mm = settings.compensation.max_total_offset_mm
    if farthest_mm > limit_mm:
        raise PatternError(
            f"the pattern reaches {farthest_mm:.3f} mm from the goal, beyond "
            f"compensation.max_total_offset_mm = {limit_mm:g} mm: choose a smaller --size"
        )
    return offsets


async def measure_pattern(
    devices: Devices, settings: Settings, offsets_um: list[tuple[float, float]]
) -> list[tuple[float, float]]:
    """Teach the goal, visit every offset and measure the spot; back to the goal at the end."""
    # lazy: OpenCV and SciPy load when the command runs, not for --help (issue 16)
    from daemon.vision import CentroidError, measure_with_camera_settings

    robot, camera = devices.robot, devices.camera
    await robot.teach_goal()
    max_step_mm = settings.compensation.max_step_change_mm
    where: Vector3 = (0.0, 0.0, 0.0)
    centroids: list[tuple[float, float]] = []
    try:
        for offset in offsets_um:
            target = robot_offset_mm(offset)
            for point in split_move(where, target, max_step_mm):
                await robot.move_absolute(point)
                where = point
            frame = await bounded(camera.grab(), "camera", "frame", settings.camera.grab_timeout_s)
            try:
                result = measure_with_camera_settings(
                    frame.image, settings.camera, camera_gain_e_per_count=frame.gain_e_per_count
                )
            except CentroidError as err:
                raise SpotLostError(
                    f"no spot at offset ({offset[0]:+.1f}, {offset[1]:+.1f}) um: {err} (the "
                    "spot left the chip? jog the goal nearer the centre or choose a smaller "
                    "--size)"
                ) from err
            if "edge" in result.flags:
                raise SpotLostError(
                    f"the spot reached the chip's edge at offset ({offset[0]:+.1f}, "
                    f"{offset[1]:+.1f}) um: jog the goal nearer the centre or use a smaller --size"
                )
            centroids.append((result.x_px, result.y_px))
            logger.info("offset %s um: spot at (%.3f, %.3f) px", offset, result.x_px, result.y_px)
    finally:
        for point in split_move(where, (0.0, 0.0, 0.0), max_step_mm):
            await robot.move_absolute(point)
    return centroids


def bench_truth(settings: Settings) -> tuple[tuple[float, float], float]:
    """The simulated camera's true calibration: pixel pitch / scale, and its rotation."""
    pitch_x, pitch_y = settings.camera.pixel_pitch_um
    scale = settings.bench.camera_scale
    return (pitch_x / scale, pitch_y / scale), settings.bench.camera_rotation_deg


async def calibrate(settings: Settings, offsets_um: list[tuple[float, float]]) -> CameraCalibration:
    # lazy: OpenCV and the devices (the simulated bench: SciPy) load when it runs, not for --help
    from daemon.vision.calibration import fit_calibration
    from drivers.factory import open_devices

    clock = make_clock(settings.bench.clock, settings.bench.time_factor)
    async with open_devices(settings, clock) as devices:
        centroids = await measure_pattern(devices, settings, offsets_um)
    return fit_calibration(offsets_um, centroids)


_KEY = re.compile(r"^\s*([A-Za-z0-9_]+)\s*=")
_TABLE = re.compile(r"^\s*\[")


def write_camera_keys(path: Path, values: dict[str, str]) -> None:
    """Set ``values`` (key -> TOML literal) in the ``[camera]`` table of ``path``, keeping every
    other line and comment; the table is added at the end when the file has none."""
    lines = path.read_text(encoding="utf-8").splitlines() if path.exists() else []
    start = next((i for i, line in enumerate(lines) if line.strip() == "[camera]"), None)
    if start is None:
        lines += ["", "[camera]", *(f"{k} = {v}" for k, v in values.items())]
    else:
        end = next((i for i in range(start + 1, len(lines)) if _TABLE.match(lines[i])), len(lines))
        remaining = dict(values)
        for i in range(start + 1, end):
            match = _KEY.match(lines[i])
            if match and match.group(1) in remaining:
                lines[i] = f"{match.group(1)} = {remaining.pop(match.group(1))}"
        lines[end:end] = [f"{k} = {v}" for k, v in remaining.items()]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def run_calibrate_camera(args: argparse.Namespace) -> int:
    # lazy: OpenCV loads when the command runs, not for --help (issue 16)
    from daemon.vision.calibration import CalibrationError

    settings = load_settings(args.config)
    refusal = cameras_refusal(settings, "calibrate camera")
    if refusal is not None:  # a UR: one line, before anything opens
        print(f"{PROG}: {refusal}", file=sys.stderr)
        return EXIT_USAGE
    size_mm = args.size or settings.camera.calibration_size_mm
    step_mm = args.step or settings.camera.calibration_step_mm
    try:
        offsets = checked_pattern(settings, size_mm, step_mm)
    except PatternError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_USAGE
    try:
        result = asyncio.run(calibrate(settings, offsets))
    except (DeviceError, SpotLostError, CalibrationError) as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_FAILURE
    truth = bench_truth(settings) if settings.camera.driver == "sim" else None
    if args.json:
        data: dict[str, object] = {
            "um_per_px": list(result.um_per_px),
            "um_per_px_se": list(result.um_per_px_se),
            "rotation_deg": result.rotation_deg,
            "rotation_se_deg": result.rotation_se_deg,
            "skew_deg": result.skew_deg,
            "residual_px": result.residual_px,
            "points": result.points,
        }
        if truth is not None:
            data["bench_truth"] = {"um_per_px": list(truth[0]), "rotation_deg": truth[1]}
        print(json.dumps(data, indent=2))
    else:
        print(
            f"# {result.points} points, +-{size_mm:g} mm every {step_mm:g} mm; residual "
            f"{result.residual_px:.3f} px RMS; axes skew {result.skew_deg:+.4f} deg"
        )
        if truth is not None:
            (true_x, true_y), true_rotation = truth
            print(
                f"# bench truth: um_per_px = [{true_x:.5f}, {true_y:.5f}], rotation_deg = "
                f"{true_rotation:g}; errors {100 * (result.um_per_px[0] / true_x - 1):+.3f} %, "
                f"{100 * (result.um_per_px[1] / true_y - 1):+.3f} %, "
                f"{result.rotation_deg - true_rotation:+.4f} deg"
            )
        print(result.toml(), end="")
    if args.write is not None:
        write_camera_keys(
            args.write,
            {
                "um_per_px": f"[{result.um_per_px[0]:.5f}, {result.um_per_px[1]:.5f}]",
                "rotation_deg": f"{result.rotation_deg:.4f}",
            },
        )
        print(f"# written to {args.write}", file=sys.stderr)
    return EXIT_OK
