"""Reaching a location a controller would reach (issue 29): the emulator's inverse kinematics
solves a location from the arm's current joints (drivers/sim/joint_arm.py, on their branch);
a large waist swing stalls that local solve (a least-squares step turns the shoulder and
wrist before the waist, and stops in a local minimum), where a real controller's closed-form
solution of the same stance simply turns the waist. These seeds start from that stance. Pure.
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


def branch_seeds(
    arm: Arm, pose: FloatArray, q_now: FloatArray, wrist_joints: int = WRIST_JOINTS
) -> list[FloatArray]:
    """Starting points near ``q_now``'s configuration for a location that a local solve from
    ``q_now`` does not reach: a large waist swing (the least squares turn the other joints
    before the waist and stall). The first joint turned by the difference between the target's
    azimuth and the tool's (and that difference +-360 degrees, within the joint's limits: the
    same stance facing the target), each with the wrist as it is and flipped (joints 4 and 6
    by 180 degrees, joint 5 mirrored: a spherical wrist's other solution)."""
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
        if arm.dof >= wrist_joints + 3:
            flipped = seed.copy()
            first = arm.dof - wrist_joints
            flipped[first] += math.pi if flipped[first] < 0.0 else -math.pi
            flipped[first + 1] = -flipped[first + 1]
            flipped[first + 2] += math.pi if flipped[first + 2] < 0.0 else -math.pi
            seeds.append(flipped)
    return seeds


def waist_turn_rad(arm: Arm, pose: FloatArray, q_now: FloatArray) -> float:
    """How far the waist turns to face ``pose``'s position from ``q_now`` (rad, in [-pi, pi])."""
    tool = forward(arm, q_now)[:3, 3]
    target = np.asarray(pose, dtype=np.float64)[:3, 3]
    turn = math.atan2(target[1], target[0]) - math.atan2(tool[1], tool[0])
    return math.atan2(math.sin(turn), math.cos(turn))


def nearest_solution(
    arm: Arm, pose: FloatArray, q_now: FloatArray, local: FloatArray | None = None
) -> FloatArray | None:
    """Of the exact solutions from :func:`branch_seeds` (each kept on its seed's branch: the
    current stance facing the target), the one nearest ``q_now`` (least squared joint travel):
    the configuration a controller keeping its stance moves to. None of them: ``local`` (the
    local solve's solution, when it found one; over a large swing it may be another branch,
    the arm reaching over its shoulder, which is why the seeds come first), else None."""
    found: list[FloatArray] = []
    for seed in branch_seeds(arm, pose, q_now):
        try:
            found.append(inverse(arm, pose, seed, restarts=0))
        except ArmError:
            continue
    if not found:
        return local
    nearest = min(found, key=lambda q: float(np.sum(np.square(q - q_now))))
    if local is not None and float(np.max(np.abs(nearest - local))) < SAME_SOLUTION_RAD:
        return local  # the same solution: the local solve's, as before the seeds
    return nearest


__all__ = ["LARGE_SWING_RAD", "branch_seeds", "nearest_solution", "waist_turn_rad"]
