"""A calibration program designed so that every parameter of the arm's model is identifiable
(issue 29), generated from the arm (its joints and their limits, its motors) and the task's
camera stations, and written as a duty cycle (daemon/arm/duty.py's format, played on the robot
like any other).

Why: on a production cycle the joints' heats follow one another (the pick-and-place cycle heats
shoulder and elbow in a fixed ratio, their factors correlate beyond 0.995; the wrist's roll
never moves), so identification can only fit their sum, and a model calibrated on one task
transfers badly to another. Here each joint's heat has a time course of its own, strong and
long enough for its links to respond:

1. each joint in turn swings back and forth over most of its range (SWING_RANGE of its limits)
   from the home pose, the others still, for a block of about BLOCK_S (15 minutes): its
   motor's heat alone (friction and acceleration);
2. gravity holds, one per joint that can hold the arm's weight alone (hold_poses: the pose of
   that joint and the one before it, over a grid, where its motor releases the most heat
   holding still with the others releasing the least; on the A465 the shoulder holding the
   arm out, and the elbow holding the forearm while the shoulder is balanced), a block each:
   one end of a link heated steadily, long enough for its rise and the temperature across it
   (what bends it: the bending share) to form;
3. a rest at the home pose (the arm upright: almost no holding torque) for two blocks: the
   links cool, which is what convection and the heat capacities are read from.

Between two rounds of swings (SWINGS) or two hold dwells (HOLD_S) the tool visits every
camera station of the task (the task's measured poses, same names: the cameras stand there),
so the tool is measured every couple of minutes through the whole program. The program
repeats (a duty cycle is periodic): its period is about 2.7 hours on the A465, so 8 hours hold
about three. A first program with 80 s of swings per joint in a 22-minute period left the
elbow's heat at 0.7 W mean (the tasks give it 4-6 W): not identifiable, and a model calibrated
on it lost 10-15 % of the drift on the machine-tending task, which works the elbow.

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
#: Back-and-forth swings between two rounds of the stations (~4 s each on the A465).
SWINGS = 20
#: Each joint's block of swings and each hold's block last about this long (s): the links'
#: time constants are tens of minutes, so a joint's heat must last that long for its links'
#: rise (and the temperature across them, which bends them) to form and be told apart from
#: the other joints' (a first program of 80 s per joint and period left the elbow's heat at
#: 0.7 W mean, a tenth of what a task gives it, and not identifiable).
BLOCK_S = 900.0
#: A hold's dwell between two rounds of the stations (s), and the rest's blocks per period.
HOLD_S = 120.0
REST_BLOCKS = 2
#: The gravity holds' search: each joint and the one before it over this grid of shares of
#: their limits (a hold is one of these poses, the others at home).
HOLD_RAISE = 0.55
HOLD_GRID = 9
#: A joint gets a hold of its own when the best pose gives it at least this share of the
#: holding heat of all joints (its heat alone, not the shoulder's with it) and this much heat.
HOLD_MIN_SHARE = 0.5
HOLD_MIN_W = 0.5
#: The moves' speed and acceleration fractions (swings at full speed: their heat is the point).
SWING_SPEED = 1.0
TRANSFER_SPEED = 0.5
#: Dwell at a station for the measurement (s).
STATION_DWELL_S = 1.0


def home_pose(arm: Arm) -> FloatArray:
    """Every joint at zero, moved inside its limits."""
    result: FloatArray = np.clip(np.zeros(arm.dof), arm.lower_rad, arm.upper_rad)
    return result


def _hold_candidates(arm: Arm) -> FloatArray:
    """Poses from home with a joint and the one after it moved over the grid (module
    constants), strictly inside the limits."""
    home = home_pose(arm)
    shares = np.linspace(-HOLD_RAISE, HOLD_RAISE, HOLD_GRID)
    candidates = [home]
    for j in range(arm.dof - 1):
        for a in shares:
            for b in shares:
                q = home.copy()
                q[j] = home[j] + (a * arm.upper_rad[j] if a > 0 else -a * arm.lower_rad[j])
                q[j + 1] = home[j + 1] + (
                    b * arm.upper_rad[j + 1] if b > 0 else -b * arm.lower_rad[j + 1]
                )
                if np.all(q > arm.lower_rad) and np.all(q < arm.upper_rad):
                    candidates.append(q)
    return np.array(candidates)


def _holding_heat(arm: Arm, q: FloatArray, payload_kg: float) -> FloatArray:
    still = np.zeros_like(q)
    return np.asarray(joint_heat_batch_w(arm, q, still, still, payload_kg=payload_kg))


def hold_poses(arm: Arm, payload_kg: float) -> list[tuple[int, FloatArray]]:
    """The gravity holds: for each joint that can hold weight alone, the pose (from
    :func:`_hold_candidates`) where its motor releases the most heat holding it still with the
    others releasing the least (its heat times its share of all); (joint, pose) pairs. A hold
    that loads one joint's motor heats its link from one end for a block: the rise and the
    temperature across the link form without the other joints' heat."""
    q = _hold_candidates(arm)
    heat = _holding_heat(arm, q, payload_kg)
    total = heat.sum(axis=1)
    holds = []
    for j in range(arm.dof):
        share = np.divide(heat[:, j], total, out=np.zeros_like(total), where=total > 0)
        best = int(np.argmax(heat[:, j] * share))
        if share[best] >= HOLD_MIN_SHARE and heat[best, j] >= HOLD_MIN_W:
            holds.append((j, q[best]))
    return holds


def hold_pose(arm: Arm, payload_kg: float) -> FloatArray:
    """The hold whose motors release the most heat in all (the home pose when none)."""
    holds = hold_poses(arm, payload_kg)
    if not holds:
        return home_pose(arm)
    heats = [float(_holding_heat(arm, q[None, :], payload_kg).sum()) for _, q in holds]
    return holds[int(np.argmax(heats))][1]


def _pose(name: str, q: FloatArray, speed: float, dwell_s: float = 0.0) -> TaughtPose:
    return TaughtPose(name, tuple(float(v) for v in q), speed, speed, dwell_s, False)


def _swing_seconds(
    ends: list[FloatArray], max_speed_rad_s: Sequence[float], max_accel_rad_s2: Sequence[float]
) -> float:
    """One back-and-forth swing's duration between ``ends`` (s)."""
    swing = DutyCycle(
        name="swing",
        poses=(_pose("a", ends[0], SWING_SPEED), _pose("b", ends[1], SWING_SPEED)),
        max_speed_rad_s=tuple(max_speed_rad_s),
        max_accel_rad_s2=tuple(max_accel_rad_s2),
    )
    return float(swing.period_s)


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
        swing_s = _swing_seconds(ends, max_speed_rad_s, max_accel_rad_s2)
        rounds = max(1, round(BLOCK_S / (SWINGS * swing_s)))
        for _ in range(rounds):
            poses.append(_pose(f"{joint.name}-home", home, TRANSFER_SPEED))
            for _ in range(SWINGS):
                poses.append(_pose(f"{joint.name}-swing-a", ends[0], SWING_SPEED))
                poses.append(_pose(f"{joint.name}-swing-b", ends[1], SWING_SPEED))
            poses += visits
    for j, hold in hold_poses(arm, payload_kg):
        for _ in range(max(1, round(BLOCK_S / HOLD_S))):
            poses.append(_pose(f"{arm.joints[j].name}-hold", hold, TRANSFER_SPEED, HOLD_S))
            poses += visits
    for _ in range(REST_BLOCKS * max(1, round(BLOCK_S / HOLD_S))):
        poses.append(_pose("rest", home, TRANSFER_SPEED, HOLD_S))
        poses += visits
    return DutyCycle(
        name=name,
        poses=tuple(poses),
        max_speed_rad_s=tuple(max_speed_rad_s),
        max_accel_rad_s2=tuple(max_accel_rad_s2),
        arm=arm.name,
        description=(
            f"Calibration program of {arm.name}: each joint swings for a block in turn, each "
            "joint that can holds the arm's weight alone for a block, a rest; the task's "
            "stations measured every couple of minutes (daemon/arm/calibration_program.py)."
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
    """``cycle`` as a duty cycle file (joint angles in degrees, rounded to 1e-6 deg). The poses
    are one inline table per line (``poses = [{...}, ...]``, the same TOML document as
    ``[[poses]]`` blocks): a calibration program visits its poses thousands of times and the
    format has no repeat, so one line per visit rather than six keeps the file a sixth as
    long; its bytes are the visits'."""

    def degrees(values: Sequence[float]) -> str:
        return json.dumps([round(math.degrees(v), 6) for v in values])

    def inline(pose: TaughtPose) -> str:
        keys = [
            f"name = {json.dumps(pose.name)}",
            f"joints_deg = {degrees(pose.q_rad)}",
        ]
        # the format's defaults left out (duty.py: speed and accel 1, no dwell, not measured)
        if pose.speed != 1.0:
            keys.append(f"speed = {pose.speed!r}")
        if pose.accel != 1.0:
            keys.append(f"accel = {pose.accel!r}")
        if pose.dwell_s:
            keys.append(f"dwell_s = {pose.dwell_s!r}")
        if pose.measure:
            keys.append("measure = true")
        return "  { " + ", ".join(keys) + " },"

    lines = [f"# {line}" for line in header.splitlines()]
    lines += [
        f"name = {json.dumps(cycle.name)}",
        f"description = {json.dumps(cycle.description)}",
        f"arm = {json.dumps(arm_file)}",
        f"max_speed_deg_s = {degrees(cycle.max_speed_rad_s)}",
        f"max_accel_deg_s2 = {degrees(cycle.max_accel_rad_s2)}",
        f"payload_kg = {cycle.payload_kg!r}",
        "",
        "poses = [",
        *(inline(pose) for pose in cycle.poses),
        "]",
    ]
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
        f"Generated by `python -m daemon.arm.calibration_program {args.arm} {args.task}"
        f"{f' --name {args.name}' if args.name else ''}`: the\n"
        f"calibration program of {arm.name} (issue 29), measured at the stations of {task.name}.\n"
        f"Period {program.period_s:.0f} s, {len(program.poses)} poses."
    )
    sys.stdout.write(duty_cycle_toml(program, task.arm or args.arm, header))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
