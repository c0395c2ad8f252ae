"""The emulated arm reaches any pose a controller would (issue 29): a 190 degree waist swing of
a legitimate duty cycle, which a local solve from the current joints stalls on, is reached on
the same stance; a location out of reach is still refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from daemon.arm.description import ArmError
from daemon.arm.kinematics import forward, inverse
from daemon.arm.loading import load_arm
from drivers.sim.arm_reach import branch_seeds, nearest_solution
from drivers.sim.joint_arm import JointArm, JointArmConfig, UnreachableError, location_of

A465 = load_arm("crs-a465")
#: A 190 degree waist swing that the local solve from LEFT stalls on (the shoulder, elbow and
#: wrist all change too; the wrist stays on its side, as a controller's configuration keeps it).
LEFT = np.radians([-95.0, 13.2, 87.3, 35.9, 16.7, -6.1])
RIGHT = np.radians([95.0, 12.1, 67.2, -37.8, 30.2, 3.1])


def test_a_190_degree_waist_swing_is_reached_on_the_same_stance() -> None:
    with pytest.raises(ArmError):  # what the emulator did before: "Location out of reach"
        inverse(A465, forward(A465, RIGHT), LEFT, restarts=0)
    arm = JointArm(JointArmConfig(arm=A465, start_joints_deg=tuple(np.degrees(LEFT))))
    target = location_of(forward(A465, RIGHT))
    q = arm.solve(target, LEFT)
    reached = forward(A465, q)
    assert np.allclose(reached[:3, 3], forward(A465, RIGHT)[:3, 3], atol=1e-3)
    assert math.degrees(q[0]) == pytest.approx(95.0, abs=0.5)  # the waist turned
    assert np.allclose(q, RIGHT, atol=1e-3)  # the taught configuration, not another branch
    # and back
    back = arm.solve(location_of(forward(A465, LEFT)), q)
    assert np.allclose(back, LEFT, atol=1e-3)


def test_the_nearest_of_the_seeds_solutions_is_taken() -> None:
    seeds = branch_seeds(A465, forward(A465, RIGHT), LEFT)
    assert seeds and all(A465.lower_rad[0] <= s[0] <= A465.upper_rad[0] for s in seeds)
    q = nearest_solution(A465, forward(A465, RIGHT), LEFT)
    assert q is not None
    # another solution of the same location (the wrist flipped) is farther from LEFT
    assert float(np.sum((q - LEFT) ** 2)) <= float(np.sum((RIGHT - LEFT) ** 2)) + 1e-6


def test_a_location_out_of_reach_is_still_refused() -> None:
    arm = JointArm(JointArmConfig(arm=A465, start_joints_deg=tuple(np.degrees(LEFT))))
    far = (2000.0, 0.0, 300.0, 0.0, 0.0, 0.0)
    with pytest.raises(UnreachableError):
        arm.solve(far, LEFT)


@pytest.mark.parametrize("name", ["a465-pick-and-place", "a465-machine-tending"])
def test_every_move_of_a_duty_cycle_lands_on_its_taught_joints(name: str) -> None:
    """Pose to pose as the played bench sends them (world locations): each solved from the
    previous pose's joints lands on the taught joints, not another branch (the machine-tending
    cycle swings the waist 190 degrees back to the machine, and the local solve from the
    turn-over pose flips the wrist)."""
    from daemon.arm.duty import load_duty_cycle

    duty = load_duty_cycle(name)
    taught = [np.array(pose.q_rad) for pose in duty.poses]
    arm = JointArm(JointArmConfig(arm=A465))
    for previous, target in zip([taught[-1], *taught[:-1]], taught, strict=True):
        q = arm.solve(location_of(forward(A465, target)), previous)
        assert np.allclose(q, target, atol=1e-3), (np.degrees(previous), np.degrees(q))
