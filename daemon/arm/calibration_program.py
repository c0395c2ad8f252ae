"""A calibration program designed so that every parameter of the arm's model is identifiable
(issue 29), generated from the arm (its joints and their limits, its motors) and the task's
camera stations, and written as a duty cycle (daemon/arm/duty.py's format, played on the robot
like any other).

Why: on a production cycle the joints' heats follow one another (the pick-and-place cycle heats
shoulder and elbow in a fixed ratio, their factors correlate beyond 0.995; the wrist's roll
never moves), so identification can only fit their sum, and a model calibrated on one task
transfers badly to another. Here each joint's heat has a time course of its own:

1. each joint in turn swings back and forth over most of its range (SWING_RANGE of its limits)
   from the home pose, the others still: its motor's heat alone (friction and acceleration);
2. a gravity hold: the pose, among the home pose with one joint raised and the next one folded
   back, whose motors hold the most weight at rest (on the A465 the shoulder out, the forearm
   hanging: the shoulder's heat without the elbow's);
3. a rest at the home pose (the arm upright: almost no holding torque): the links cool, which
   is what convection and the heat capacities are read from.

After each block the tool visits every camera station of the task (the task's measured poses,
same names: the cameras stand there), so the tool is measured every couple of minutes through
the whole program. The program repeats (a duty cycle is periodic): over 8 hours its period of
about 25 minutes comes back about twenty times.

Before running it on a real arm, play it once slowly: the poses are within the joint limits,
not checked against the cell's fixtures.

    .venv/bin/python -m daemon.arm.calibration_program crs-a465 a465-pick-and-place > file.toml
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence

import numpy as np

from daemon.arm.description import Arm
from daemon.arm.duty import DutyCycle, TaughtPose, arm_inverse, load_duty_cycle
from daemon.arm.loading import load_arm
from daemon.arm.motors import joint_heat_batch_w
from daemon.arm.types import FloatArray

#: A swing covers this share of the joint's range on each side of home (clear of the stops).
SWING_RANGE = 0.85
#: Back-and-forth swings of one joint in its block (~4 s each on the A465).
SWINGS = 20
#: A gravity hold's and a rest's block (s), and their blocks per period.
HOLD_S = 120.0
HOLD_BLOCKS = 3
REST_BLOCKS = 4
#: The gravity hold's candidates: one joint raised by this share of its limit, the next one
#: folded back as much.
HOLD_RAISE = 0.55
#: The moves' speed and acceleration fractions (swings at full speed: their heat is the point).
SWING_SPEED = 1.0
TRANSFER_SPEED = 0.5
#: Dwell at a station for the measurement (s).
STATION_DWELL_S = 1.0


def home_pose(arm: Arm) -> FloatArray:
    """Every joint at zero, moved inside its limits."""
    result: FloatArray = np.clip(np.zeros(arm.dof), arm.lower_rad, arm.upper_rad)
    return result


def hold_pose(arm: Arm, payload_kg: float) -> FloatArray:
    """The gravity hold: of the home pose with joint j raised (either way) and joint j+1
    folded back as much (both clear of their stops), the one whose motors release the most
    heat holding it still (the home pose when none is clear)."""
    home = home_pose(arm)
    candidates = []
    for j in range(arm.dof - 1):
        for sign in (1.0, -1.0):
            q = home.copy()
            limit = arm.upper_rad[j] if sign > 0 else -arm.lower_rad[j]
            q[j] = home[j] + sign * HOLD_RAISE * limit
            q[j + 1] = home[j + 1] - (q[j] - home[j])
            if np.all(q > arm.lower_rad) and np.all(q < arm.upper_rad):  # never at a stop
                candidates.append(q)
    if not candidates:
        return home
    q = np.array(candidates)
    still = np.zeros_like(q)
    heat = np.asarray(joint_heat_batch_w(arm, q, still, still, payload_kg=payload_kg))
    best: FloatArray = q[int(np.argmax(heat.sum(axis=1)))]
    return best


def _pose(name: str, q: FloatArray, speed: float, dwell_s: float = 0.0) -> TaughtPose:
    return TaughtPose(name, tuple(float(v) for v in q), speed, speed, dwell_s, False)


def calibration_program(
    arm: Arm,
    stations: Sequence[TaughtPose],
    max_speed_rad_s: Sequence[float],
    max_accel_rad_s2: Sequence[float],
    *,
    payload_kg: float = 0.0,
    name: str = "calibration",
) -> DutyCycle:
    """The program (module docstring) for ``arm``, measured at ``stations`` (the task's
    measured poses, kept with their names and joint angles)."""
    if not stations:
        raise ValueError("a calibration program needs the task's camera stations")
    home = home_pose(arm)
    visits = [
        TaughtPose(s.name, s.q_rad, TRANSFER_SPEED, TRANSFER_SPEED, STATION_DWELL_S, True)
        for s in stations
    ]
    poses: list[TaughtPose] = []
    for j, joint in enumerate(arm.joints):
        ends = []
        for limit in (arm.upper_rad[j], arm.lower_rad[j]):
            q = home.copy()
            q[j] = home[j] + SWING_RANGE * (limit - home[j])
            ends.append(q)
        poses.append(_pose(f"{joint.name}-home", home, TRANSFER_SPEED))
        for _ in range(SWINGS):
            poses.append(_pose(f"{joint.name}-swing-a", ends[0], SWING_SPEED))
            poses.append(_pose(f"{joint.name}-swing-b", ends[1], SWING_SPEED))
        poses += visits
    hold = hold_pose(arm, payload_kg)
    for _ in range(HOLD_BLOCKS):
        poses.append(_pose("hold", hold, TRANSFER_SPEED, HOLD_S))
        poses += visits
    for _ in range(REST_BLOCKS):
        poses.append(_pose("rest", home, TRANSFER_SPEED, HOLD_S))
        poses += visits
    return DutyCycle(
        name=name,
        poses=tuple(poses),
        max_speed_rad_s=tuple(max_speed_rad_s),
        max_accel_rad_s2=tuple(max_accel_rad_s2),
        arm=arm.name,
        description=(
            f"Calibration program of {arm.name}: each joint swings in turn, a gravity hold, a "
            "rest; the task's stations measured after each block (daemon/arm/"
            "calibration_program.py)."
        ),
        payload_kg=payload_kg,
    )


def program_for_task(arm: Arm, task: DutyCycle, arm_file: str, name: str) -> DutyCycle:
    """The program measured at ``task``'s stations with its limits and payload."""
    return calibration_program(
        arm,
        task.measured_poses(),
        task.max_speed_rad_s,
        task.max_accel_rad_s2,
        payload_kg=task.payload_kg,
        name=name,
    )


def duty_cycle_toml(cycle: DutyCycle, arm_file: str, header: str = "") -> str:
    """``cycle`` as a duty cycle file (joint angles in degrees, rounded to 1e-6 deg)."""

    def degrees(values: Sequence[float]) -> str:
        return json.dumps([round(math.degrees(v), 6) for v in values])

    lines = [f"# {line}" for line in header.splitlines()]
    lines += [
        f"name = {json.dumps(cycle.name)}",
        f"description = {json.dumps(cycle.description)}",
        f"arm = {json.dumps(arm_file)}",
        f"max_speed_deg_s = {degrees(cycle.max_speed_rad_s)}",
        f"max_accel_deg_s2 = {degrees(cycle.max_accel_rad_s2)}",
        f"payload_kg = {cycle.payload_kg!r}",
    ]
    for pose in cycle.poses:
        lines += [
            "",
            "[[poses]]",
            f"name = {json.dumps(pose.name)}",
            f"joints_deg = {degrees(pose.q_rad)}",
            f"speed = {pose.speed!r}",
            f"accel = {pose.accel!r}",
        ]
        if pose.dwell_s:
            lines.append(f"dwell_s = {pose.dwell_s!r}")
        if pose.measure:
            lines.append("measure = true")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("arm", help="arm preset or file (config/arms)")
    parser.add_argument("task", help="the task's duty cycle: its stations, limits and payload")
    parser.add_argument("--name", help="the program's name (default ARM-calibration)")
    args = parser.parse_args(argv)
    arm = load_arm(args.arm)
    task = load_duty_cycle(args.task, arm_inverse(arm))
    name = args.name or f"{task.arm or args.arm}-calibration"
    program = program_for_task(arm, task, args.arm, name)
    header = (
        f"Generated by `python -m daemon.arm.calibration_program {args.arm} {args.task}`: the\n"
        f"calibration program of {arm.name} (issue 29), measured at the stations of {task.name}.\n"
        f"Period {program.period_s:.0f} s, {len(program.poses)} poses."
    )
    sys.stdout.write(duty_cycle_toml(program, task.arm or args.arm, header))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
