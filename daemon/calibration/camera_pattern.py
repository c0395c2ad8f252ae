"""The pattern of ``thermocomp calibrate cameras --robot`` (issue 20): the tool poses around the
taught goal, declared whole and checked against the limits before anything moves
(``PatternError``: nothing moves), and each move split within the arm's step limits
(daemon/calibration/camera_run.py moves the robot through it)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from config import Settings
from daemon.vision.camera_pose import grid_positions
from daemon.vision.multiview import MultiviewError
from drivers.base import Vector3


class PatternError(Exception):
    """The declared pattern breaks a limit or cannot be made: nothing moves (exit 2)."""


@dataclass(frozen=True, slots=True)
class Shift:
    """One pose of the pattern: the goal shifted by ``translation_mm`` and turned by the
    rotation vector ``rotation_rad`` (base frame), as GoalRobot.move_absolute takes them."""

    translation_mm: Vector3
    rotation_rad: Vector3


ZERO_SHIFT = Shift((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


def calibration_limits(settings: Settings) -> tuple[float, float, str, str]:
    """The pattern's limits (mm, deg) and the settings they come from: arm.calibration_max_*
    when set, else the arm's correction limits (arm.max_translation_mm, arm.max_rotation_deg)."""
    arm = settings.arm
    if arm.calibration_max_translation_mm is not None:
        t_mm, t_name = arm.calibration_max_translation_mm, "arm.calibration_max_translation_mm"
    else:
        t_mm, t_name = arm.max_translation_mm, "arm.max_translation_mm"
    if arm.calibration_max_rotation_deg is not None:
        r_deg, r_name = arm.calibration_max_rotation_deg, "arm.calibration_max_rotation_deg"
    else:
        r_deg, r_name = arm.max_rotation_deg, "arm.max_rotation_deg"
    return t_mm, r_deg, t_name, r_name


def default_size_turn(settings: Settings) -> tuple[float, float]:
    """Defaults of ``--size`` (mm) and ``--turn`` (rad): half the limits (a cube's corner at
    0.87 of the translation limit; random turns of at most 0.87 of the rotation limit)."""
    t_mm, r_deg, _, _ = calibration_limits(settings)
    return 0.5 * t_mm, 0.5 * math.radians(r_deg) / math.sqrt(3.0)


def robot_pattern(size_mm: float, per_axis: int, turn_rad: float, seed: int) -> list[Shift]:
    """The cube of ``per_axis``³ translations ±``size_mm`` about the goal (a serpentine:
    camera_pose.grid_positions), each turned at random by up to ``turn_rad`` about every axis
    (seeded): the turns make the markers' common offset observable (``--fit-marker``)."""
    try:
        positions = grid_positions((0.0, 0.0, 0.0), size_mm, per_axis)
    except MultiviewError as err:
        raise PatternError(str(err)) from err
    rng = np.random.default_rng(seed)
    shifts = []
    for position in positions:
        turn = rng.uniform(-turn_rad, turn_rad, 3) if turn_rad > 0 else np.zeros(3)
        shifts.append(
            Shift(
                (float(position[0]), float(position[1]), float(position[2])),
                (float(turn[0]), float(turn[1]), float(turn[2])),
            )
        )
    return shifts


def check_pattern(settings: Settings, shifts: Sequence[Shift]) -> None:
    """PatternError (one line) unless every pose of the pattern lies within the limits."""
    t_mm, r_deg, t_name, r_name = calibration_limits(settings)
    farthest = max(math.dist((0.0, 0.0, 0.0), s.translation_mm) for s in shifts)
    if farthest > t_mm:
        raise PatternError(
            f"the pattern reaches {farthest:.3f} mm from the goal, beyond {t_name} = {t_mm:g} mm: "
            "choose a smaller --size (or set arm.calibration_max_translation_mm)"
        )
    widest = max(math.degrees(math.dist((0.0, 0.0, 0.0), s.rotation_rad)) for s in shifts)
    if widest > r_deg:
        raise PatternError(
            f"the pattern turns the tool by {widest:.4f} deg, beyond {r_name} = {r_deg:g} deg: "
            "choose a smaller --turn (or set arm.calibration_max_rotation_deg)"
        )


def split_shift(start: Shift, end: Shift, max_step_mm: float, max_step_rad: float) -> list[Shift]:
    """Shifts from ``start`` (excluded) to ``end`` (included), each changing the translation by
    at most ``max_step_mm`` along every axis and the rotation by about ``max_step_rad`` at most
    (rotation vectors interpolated linearly: for the pattern's fraction-of-a-degree turns the
    angle between two is their difference's norm to a part in 10^5, and every intermediate
    stays within the ball of the ends', i.e. within the pattern's rotation limit)."""
    t0, t1 = np.array(start.translation_mm), np.array(end.translation_mm)
    r0, r1 = np.array(start.rotation_rad), np.array(end.rotation_rad)
    turn = float((Rotation.from_rotvec(r1) * Rotation.from_rotvec(r0).inv()).magnitude())
    count = max(
        1,
        math.ceil(float(np.max(np.abs(t1 - t0))) / max_step_mm - 1e-9),
        math.ceil(turn / max_step_rad - 1e-9),
    )
    steps = []
    for k in range(1, count):
        t = t0 + (t1 - t0) * k / count
        r = r0 + (r1 - r0) * k / count
        steps.append(
            Shift((float(t[0]), float(t[1]), float(t[2])), (float(r[0]), float(r[1]), float(r[2])))
        )
    return [*steps, end]  # the end exactly
