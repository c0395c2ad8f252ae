"""Named taught goals and the rotation of an absolute move, shared by both C500C drivers
(issue 20): names, their controller variables, and the rotation vector -> the controller's
z-rot, y-rot, x-rot angles.

A duty cycle teaches several poses; each compensation step moves to "goal k + its own
correction" (thesis 6.4.4's absolute command, per goal). The default goal is today's single
`opgoal`, so a run that teaches one goal sends exactly the bytes it always did.
"""

from __future__ import annotations

import math
import re
import warnings

from drivers.base import DEFAULT_GOAL, Vector3
from drivers.errors import DeviceError

#: A goal's name: a letter, then letters, digits or underscores. Its console variable is
#: ``GOAL_VARIABLE_PREFIX + name`` (or `opgoal` for the default goal), so no name can be a
#: RAPL-3 keyword or the per-step target `cur`. ASSUMED: `ash` takes variable names of 16
#: characters (docs/reference/c500c-console.md gives no limit; the repository's RAPL-3 code uses
#: names up to 15).
GOAL_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,13}")
GOAL_VARIABLE_PREFIX = "g_"
_GIMBAL_LOCK_WARNING = "Gimbal lock detected"  # SciPy's, at y = +-90 deg
#: How many goals the fast-path program holds (controller/thermocomp_server.r3 MAX_GOALS).
MAX_SERVER_GOALS = 16


def check_goal_name(goal: str, device: str) -> str:
    if goal != DEFAULT_GOAL and not GOAL_NAME.fullmatch(goal):
        raise DeviceError(
            device,
            f"goal name {goal!r}: a letter then up to 13 letters, digits or underscores",
        )
    return goal


def goal_variable(goal: str, device: str) -> str:
    """The console location variable that holds ``goal`` (docs/reference/c500c-console.md: made with
    `new`)."""
    check_goal_name(goal, device)
    return goal if goal == DEFAULT_GOAL else GOAL_VARIABLE_PREFIX + goal


def require_finite(values: Vector3, what: str, device: str) -> None:
    """Last guard before the serial writer (issue 10): a NaN or an infinity would otherwise be
    printed into a console command as "nan" or fail deep in the framing."""
    if not all(math.isfinite(v) for v in values):
        raise DeviceError(device, f"refused a non-finite {what} {values}")


#: The farthest a move may go from its taught goal (mm), checked by every driver before any
#: byte (issue 26): an A465 reaches 711 mm (thesis 3.2.1), so a target 1 m from a goal is always
#: a wrong one. The daemon's limits (compensation.max_total_offset_mm, arm.max_translation_mm)
#: are far tighter; this is the drivers' own last guard.
MAX_MOVE_OFFSET_MM = 1000.0


def require_target(
    values: Vector3, what: str, device: str, limit_mm: float = MAX_MOVE_OFFSET_MM
) -> None:
    """A motion target's offset: finite and within ``limit_mm`` on every axis, else refused
    (DeviceError) before anything is written."""
    require_finite(values, what, device)
    if max(abs(v) for v in values) > limit_mm:
        raise DeviceError(device, f"refused a {what} {values} beyond {limit_mm:g} mm")


def rotation_zyx_deg(rotation_rad: Vector3, device: str) -> Vector3:
    """A rotation vector (rad, base frame: daemon.arm.types.Pose6) as the controller's wshift
    angles z-rot, y-rot, x-rot in degrees (Pose6.zyx_deg, the contract of issue 20). ASSUMED
    (docs/reference/c500c-console.md says only "shifts a location in world coordinates; units mm and
    degrees"): the controller turns the location by these angles in the world frame, about its own
    position."""
    require_finite(rotation_rad, "rotation", device)
    if not any(rotation_rad):
        return (0.0, 0.0, 0.0)
    # lazy: NumPy and SciPy load here, so the console's checks and `--help` load without them
    import numpy as np
    from scipy.spatial.transform import Rotation

    # SciPy here, not Pose6.zyx_deg: a device driver imports no model code (the layers,
    # tests/test_layering.py); tests/test_c500c_goals.py checks the two agree. At y = +-90 deg
    # only z -+ x is determined and any split is the same rotation: that warning only is quiet.
    rotation = Rotation.from_rotvec(np.array(rotation_rad, dtype=np.float64))
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=_GIMBAL_LOCK_WARNING, category=UserWarning)
        z, y, x = rotation.as_euler("ZYX", degrees=True)
    return (float(z), float(y), float(x))
