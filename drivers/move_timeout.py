"""How long one move may take before it is a stall (issue 26): its motion at the slowest speed
the robot may go at, plus a margin for settling, the controller and the wire. A stalled link
(a lost reply to `finish` on the console, to MOVE_GOAL on the fast path) is then a fault within
seconds for a compensating step, not after robot.move_timeout_s (60 s), which stays the cap
and the timeout of a move whose length is unknown (nothing known of where the robot stands).
"""

from __future__ import annotations

import math

from config.settings import RobotSettings
from drivers.base import Vector3

#: The speed assumed for a move that sends none (the fast path's frames, the console's moves
#: at the controller's current speed): 10 % of the controller's maximum.
UNKNOWN_SPEED_PERCENT = 10


def move_timeout_s(
    settings: RobotSettings,
    start: tuple[Vector3, Vector3] | None,
    target: tuple[Vector3, Vector3],
    speed_percent: int | None = None,
) -> float:
    """The timeout of a move from ``start`` to ``target`` (each: position mm, z-y-x angles deg;
    None: unknown) at ``speed_percent`` (None: unknown)."""
    if start is None:
        return settings.move_timeout_s
    distance_mm = math.dist(start[0], target[0])
    turn_deg = sum(abs(b - a) for a, b in zip(start[1], target[1], strict=True))
    if not (math.isfinite(distance_mm) and math.isfinite(turn_deg)):
        return settings.move_timeout_s
    scale = (speed_percent if speed_percent is not None else UNKNOWN_SPEED_PERCENT) / 100.0
    motion_s = distance_mm / (settings.min_speed_mm_s * scale) + turn_deg / (
        settings.min_rotation_deg_s * scale
    )
    return min(settings.move_timeout_s, settings.move_margin_s + motion_s)
