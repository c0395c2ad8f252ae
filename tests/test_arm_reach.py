"""The emulated arm reaches any pose a controller would (issue 29): a 190 degree waist swing of
a legitimate duty cycle, which a local solve from the current joints stalls on, is reached on
the same stance; a location out of reach is still refused."""

from __future__ import annotations

import math

import numpy as np
import pytest

from daemon.arm.description import ArmError, load_arm
from daemon.arm.kinematics import forward, inverse
from drivers.sim.arm_reach import branch_seeds, nearest_solution
from drivers.sim.joint_arm import JointArm, JointArmConfig, UnreachableError, location_of

A465 = load_arm("crs-a465")
#: A 190 degree waist swing that the local solve from LEFT stalls on (the shoulder, elbow and
#: wrist all change too).
LEFT = np.radians([-95.0, 16.2, 51.9, -20.9, 30.1, -35.3])
RIGHT = np.radians([95.0, 3.6, 74.8, 23.7, -21.5, -35.8])


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
