"""The UR5e's two shipped tasks (issue 29: a model calibrated on one task compensates the
other): both load for the UR5e preset, every pose within its joint limits and above the
table, and the second is another task, not a copy (other measured poses, tool direction,
payload, a wrist that rolls)."""

from __future__ import annotations

import math

import numpy as np

from daemon.arm import kinematics
from daemon.arm.duty import arm_inverse, load_duty_cycle
from daemon.arm.loading import load_arm

#: The UR5e's published reach (mm) from the shoulder axis.
UR5E_REACH_MM = 850.0


def test_the_ur5e_tasks_load_and_every_pose_is_reachable() -> None:
    arm = load_arm("ur5e")
    for name in ("ur5e-pick-and-place", "ur5e-machine-tending"):
        duty = load_duty_cycle(name, arm_inverse(arm))
        assert duty.arm == "ur5e"
        assert duty.measured_poses(), name
        for pose in duty.poses:
            for q, joint in zip(pose.q_rad, arm.joints, strict=True):
                assert joint.lower_rad <= q <= joint.upper_rad, (name, pose.name, joint.name)
            tool = kinematics.forward(arm, pose.q_rad)[:3, 3]
            shoulder = np.array([0.0, 0.0, arm.joints[0].d_mm])
            assert tool[2] > 50.0, (name, pose.name)  # above the table the robot stands on
            assert np.linalg.norm(tool - shoulder) < UR5E_REACH_MM, (name, pose.name)


def test_the_machine_tending_is_another_task() -> None:
    arm = load_arm("ur5e")
    pick = load_duty_cycle("ur5e-pick-and-place", arm_inverse(arm))
    tend = load_duty_cycle("ur5e-machine-tending", arm_inverse(arm))
    assert {p.name for p in tend.measured_poses()} == {"chuck", "tray"}
    assert tend.payload_kg > pick.payload_kg
    rolls = [p.q_rad[5] for p in tend.poses]
    assert max(rolls) - min(rolls) >= math.radians(170.0)  # the part turned over
    chuck = next(p for p in tend.poses if p.name == "chuck")
    axis = kinematics.forward(arm, chuck.q_rad)[:3, 2]
    assert abs(axis[2]) < 0.1  # into the chuck horizontally; the pick-and-place points down
    assert tend.period_s > pick.period_s
