"""Reaching a location as a controller would (issue 29): the emulator's inverse kinematics
solves a location from the arm's current joints (drivers/sim/joint_arm.py, on their branch).
A large waist swing stalls that local solve (a least-squares step turns the shoulder and wrist
before the waist, and stops in a local minimum), or lands it on another branch (the arm
reaching over its shoulder, the wrist flipped), where a real controller's closed-form solution
keeps its stance (its configuration: shoulder, elbow and wrist flags) and simply turns the
waist. These seeds start from that stance. Pure.
"""

from __future__ import annotations

import math

import numpy as np

from daemon.arm.description import Arm, ArmError
from daemon.arm.kinematics import forward, inverse
from daemon.arm.types import FloatArray

#: A 6-joint arm's wrist: its last three joints.
WRIST_JOINTS = 3
#: A waist turn beyond this is a large swing: the local solve's solution is compared with the
#: seeds' (below it the local solve stays on its branch, and nothing else is solved).
LARGE_SWING_RAD = math.pi / 2
#: Two solutions this close (rad, every joint) are one: the local solve's is kept.
SAME_SOLUTION_RAD = 1e-3
#: A wrist bent less than this (rad) has no flip side (it is at its singularity).
WRIST_FLAT_RAD = math.radians(1.0)


def waist_turn_rad(arm: Arm, pose: FloatArray, q_now: FloatArray) -> float:
    """How far the waist turns to face ``pose``'s position from ``q_now`` (rad, in [-pi, pi])."""
    tool = forward(arm, q_now)[:3, 3]
    target = np.asarray(pose, dtype=np.float64)[:3, 3]
    turn = math.atan2(target[1], target[0]) - math.atan2(tool[1], tool[0])
    return math.atan2(math.sin(turn), math.cos(turn))


def wrist_side(arm: Arm, q: FloatArray) -> int:
    """The spherical wrist's flip side: the sign of its middle joint (0: flat, or no wrist)."""
    if arm.dof < WRIST_JOINTS + 3:
        return 0
    bend = float(q[arm.dof - 2])
    return 0 if abs(bend) < WRIST_FLAT_RAD else (1 if bend > 0.0 else -1)


def flipped_wrist(arm: Arm, q: FloatArray) -> FloatArray:
    """The same tool pose with the wrist's other solution: its first and last joints turned
    by 180 degrees (towards zero), the middle one mirrored."""
    out = q.copy()
    first = arm.dof - WRIST_JOINTS
    out[first] += -math.pi if out[first] > 0.0 else math.pi
    out[first + 1] = -out[first + 1]
    out[first + 2] += -math.pi if out[first + 2] > 0.0 else math.pi
    return out


def branch_seeds(arm: Arm, pose: FloatArray, q_now: FloatArray) -> list[FloatArray]:
    """Starting points on ``q_now``'s stance: the first joint turned by the difference between
    the target's azimuth and the tool's (and that difference +-360 degrees, within the joint's
    limits), each with the wrist as it is and flipped."""
    turn = waist_turn_rad(arm, pose, q_now)
    lower, upper = arm.lower_rad, arm.upper_rad
    seeds: list[FloatArray] = []
    for delta in (turn, turn - 2.0 * math.pi, turn + 2.0 * math.pi):
        waist = q_now[0] + delta
        if not lower[0] <= waist <= upper[0]:
            continue
        seed = q_now.copy()
        seed[0] = waist
        seeds.append(seed)
        if arm.dof >= WRIST_JOINTS + 3:
            seeds.append(flipped_wrist(arm, seed))
    return seeds


def needs_branch_search(
    arm: Arm, pose: FloatArray, q_now: FloatArray, local: FloatArray | None
) -> bool:
    """Whether the local solve's answer is not what a controller keeping its stance does: no
    solution, a waist swing past LARGE_SWING_RAD, or a flipped wrist."""
    if local is None or abs(waist_turn_rad(arm, pose, q_now)) > LARGE_SWING_RAD:
        return True
    side = wrist_side(arm, q_now)
    return side != 0 and wrist_side(arm, local) == -side


def nearest_solution(
    arm: Arm, pose: FloatArray, q_now: FloatArray, local: FloatArray | None = None
) -> FloatArray | None:
    """The solution a controller keeping its stance moves to: of the exact solutions from
    :func:`branch_seeds` and from ``local`` with its wrist flipped (``local``: the local
    solve's own, when it found one), those on ``q_now``'s wrist side first, the one nearest
    ``q_now`` (least squared joint travel), else ``local``; None when nothing converges.
    ``local`` is kept when the choice is the same solution."""
    seeds = branch_seeds(arm, pose, q_now)
    if local is not None and arm.dof >= WRIST_JOINTS + 3:
        seeds.append(flipped_wrist(arm, local))
    found: list[FloatArray] = []
    for seed in seeds:
        try:
            found.append(inverse(arm, pose, seed, restarts=0))
        except ArmError:
            continue
    side = wrist_side(arm, q_now)
    same = [q for q in found if side == 0 or wrist_side(arm, q) != -side]
    if local is not None and (side == 0 or wrist_side(arm, local) != -side):
        same.append(local)
    pool = same or found
    if not pool:
        return local
    nearest = min(pool, key=lambda q: float(np.sum(np.square(q - q_now))))
    if local is not None and float(np.max(np.abs(nearest - local))) < SAME_SOLUTION_RAD:
        return local  # the same solution: the local solve's, as before the seeds
    return nearest


__all__ = [
    "LARGE_SWING_RAD",
    "branch_seeds",
    "flipped_wrist",
    "nearest_solution",
    "needs_branch_search",
    "waist_turn_rad",
    "wrist_side",
]
