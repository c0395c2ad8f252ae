"""What the calibration commands cannot do on a robot that plays its own program (robot.driver
``ur-rtde``, a followed run: daemon/run/followed/), each refused in ONE line before anything
opens, saying what exists instead and where the docs say it.

- ``calibrate camera`` calibrates the two-link bench's spot camera with a grid of absolute
  moves; a UR has no spot camera, and its PC only shifts the robot's own program, by at most
  2 mm (controller/ur/thermocomp_offset.script MAX_OFFSET_M). Its tool cameras are calibrated
  by ``calibrate cameras --robot``, which on a UR records a pattern of offsets at the
  program's dwells (daemon/calibration/cameras_ur.py).
- ``calibrate model`` identifies a model from an uncompensated run's *measured* tool errors:
  on a UR the followed run's tool cameras at the program's dwells
  (daemon/run/followed/measure.py, daemon/commands/calibrate_ur_model.py); with no tool camera
  there is nothing to identify from, unless a recorded run is given (``--calibration-run``).
"""

from __future__ import annotations

from config import Settings

#: Where the docs say what a UR does instead.
UR_DOCS = 'docs/how-to/universal-robots.md, "Calibration on a UR"'


def _followed(settings: Settings) -> bool:
    return settings.robot.driver == "ur-rtde"


def cameras_refusal(settings: Settings, option: str) -> str | None:
    """The one line refusing the spot camera's calibration on a UR (``option``: what was
    asked), or None when the robot can make it."""
    if not _followed(settings):
        return None
    return (
        f"{option} moves the robot through a pattern, but a UR (robot.driver ur-rtde) plays its "
        "own program and has no spot camera: its tool cameras are calibrated at the "
        f"program's dwells with `calibrate cameras --robot` ({UR_DOCS})"
    )


def model_refusal(settings: Settings, *, recorded: bool = False) -> str | None:
    """The one line refusing ``calibrate model`` on a UR with no tool camera to measure its
    calibration run (``recorded``: a recorded run is identified instead), or None."""
    if not _followed(settings) or recorded:
        return None
    arm = settings.arm
    cameras = arm.bench_cameras if settings.bench.enabled else bool(arm.camera_devices)
    if arm.enabled and cameras:
        return None
    where = "arm.bench_cameras" if settings.bench.enabled else "arm.camera_devices"
    return (
        "a UR (robot.driver ur-rtde) is calibrated from the tool cameras' measurements at its "
        f"program's dwells, and this configuration has no tool camera ({where}): add them, or "
        f"identify a recorded followed run with --calibration-run RUN ({UR_DOCS})"
    )
