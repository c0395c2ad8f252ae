"""What the calibration commands cannot do on a robot that plays its own program (robot.driver
``ur-rtde``, a followed run: daemon/run/followed/), each refused in ONE line before anything
opens, saying what exists instead and where the docs say it.

- ``calibrate cameras --robot`` and ``calibrate camera`` move the robot through a pattern of
  absolute moves (tens of millimetres); a UR's PC only shifts the robot's own program, by at
  most 2 mm (controller/ur/thermocomp_offset.script MAX_OFFSET_M), so the pattern cannot be
  made; and a followed run measures with no camera yet.
- ``calibrate model`` identifies a model from an uncompensated run's *measured* tool errors; a
  followed run measures none (its thermal input is the joint temperatures; on the bench its
  "measurement" is the bench's truth, which a lab does not have), so there is nothing to
  identify from: a UR runs with the arm's preset model and its joint temperatures fused.
"""

from __future__ import annotations

from config import Settings

#: Where the docs say what a UR does instead.
UR_DOCS = 'docs/how-to/universal-robots.md, "Calibration on a UR"'


def _followed(settings: Settings) -> bool:
    return settings.robot.driver == "ur-rtde"


def cameras_refusal(settings: Settings, option: str) -> str | None:
    """The one line refusing a camera calibration that moves the robot (``option``: what was
    asked), or None when the robot can make it."""
    if not _followed(settings):
        return None
    return (
        f"{option} moves the robot through a pattern, but a UR (robot.driver ur-rtde) plays its "
        "own program and the PC only shifts it by at most 2 mm, and a followed run measures "
        "with no camera: fit a camera file from recorded marker positions instead "
        f"(calibrate cameras --observations CSV; {UR_DOCS})"
    )


def model_refusal(settings: Settings) -> str | None:
    """The one line refusing ``calibrate model`` on a UR, or None elsewhere."""
    if not _followed(settings):
        return None
    return (
        "a UR (robot.driver ur-rtde) has no model calibration: a followed run measures no tool "
        "error to identify from; it runs with the arm's preset model (arm.arm_file) and its "
        "joint temperatures as the thermal input (model.prediction = model+ir): start it with "
        f"`thermocomp run --config ...` ({UR_DOCS})"
    )
