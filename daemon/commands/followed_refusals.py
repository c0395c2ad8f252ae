"""What the calibration commands cannot do on a robot that plays its own program (robot.driver
``ur-rtde``, a followed run: daemon/run/followed/), each refused in ONE line before anything
opens, saying what exists instead and where the docs say it.

- ``calibrate cameras --robot`` and ``calibrate camera`` move the robot through a pattern of
  absolute moves (tens of millimetres); a UR's PC only shifts the robot's own program, by at
  most 2 mm (controller/ur/thermocomp_offset.script MAX_OFFSET_M), so the pattern cannot be
  made.
- ``calibrate model`` identifies a model from an uncompensated run's *measured* tool errors; a
  followed run with tool cameras measures the tool at the program's dwells
  (daemon/run/followed/measure.py), but identification from a followed run is not built: a UR
  runs with the arm's preset model and its joint temperatures fused.
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
        "own program and the PC only shifts it by at most 2 mm: fit a camera file from "
        "recorded marker positions instead "
        f"(calibrate cameras --observations CSV; {UR_DOCS})"
    )


def model_refusal(settings: Settings) -> str | None:
    """The one line refusing ``calibrate model`` on a UR, or None elsewhere."""
    if not _followed(settings):
        return None
    return (
        "a UR (robot.driver ur-rtde) has no model calibration yet: a followed run measures the "
        "tool at its dwells, but no model is identified from one; it runs with the arm's preset "
        "model (arm.arm_file) and its joint temperatures as the thermal input "
        f"(model.prediction = model+ir): start it with `thermocomp run --config ...` ({UR_DOCS})"
    )
