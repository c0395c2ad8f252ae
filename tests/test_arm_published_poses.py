"""Forward kinematics against published reference poses (issue 20 tests): joint angles -> tool
pose pairs that another project publishes in its own tests and documentation, reproduced by
daemon/arm/kinematics.py ``forward`` on an arm built here from the published DH table through
our own loader (``arm_from_mapping``: the DH TOML's fields). The expected values are the
source's, never computed by our code.

Source: compas_fab (ETH Zurich Gramazio Kohler Research, MIT licence),
github.com/compas-dev/compas_fab:

- ``tests/backends/kinematics/test_analytical_kinematics_planner.py``: the UR5 at its zero
  configuration is ``Frame(Point(0.81725, 0.19145, -0.00549), xaxis (0, 1, 0), yaxis (1, 0,
  0))`` (``test_forward_kinematics``), and the frame ``(0.381, 0.093, 0.382)``, xaxis
  ``(0.371, -0.292, -0.882)``, yaxis ``(0.113, 0.956, -0.269)`` has the solution
  ``q = (0.022, 4.827, 1.508, 1.126, 1.876, 3.163)`` (``test_inverse_kinematics``);
- ``docs/examples/03_backends_ros/files/03_forward_kinematics_urdf.py``: the UR5 (its URDF,
  through ROS) at ``q = (-2.238, -1.153, -2.174, 0.185, 0.667, 0.0)`` has its tool at
  ``Point(0.300, 0.100, 0.500)``.

The arm: the UR5 (not e) of Universal Robots' DH article, the numbers compas_fab's
``UR5_PARAMS`` cite (src/compas_fab/backends/kinematics/solvers/offset_wrist_kinematics.py,
"taken from universal-robots.com/articles/ur/application-installation/dh-parameters-for-
calculations-of-kinematics-and-dynamics"): d1 = 0.089159, a2 = -0.425, a3 = -0.39225,
d4 = 0.10915, d5 = 0.09465, d6 = 0.0823 m; alpha = pi/2, 0, 0, pi/2, -pi/2, 0.

The frames: compas_fab's analytical kinematics is ur_kinematics' ``ur_kin.cpp`` (its
``forward_kinematics_offset_wrist`` says so), whose frame is ROS's: the world is ``base_link``,
Universal Robots' Base frame turned 180 degrees about z (ur_description's
``base_link-base_fixed_joint``, rpy (0, 0, pi), as in config/arms/ur5e.urdf), and the tool is
``ee_link``: ur_description (ROS 1, ``ur5.urdf.xacro``) puts ``tool0`` at rpy (-pi/2, 0, 0)
and ``ee_link`` at rpy (0, 0, pi/2) from ``wrist_3_link``, so ``ee_link`` is ``tool0`` (the
DH flange, tests/test_arm_kinematics.py checks it against the URDF) turned by
Rx(pi/2) Rz(pi/2): its x axis along the flange's normal. The position does not depend on it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from daemon.arm.description import Arm
from daemon.arm.kinematics import forward, jacobian
from daemon.arm.loading import arm_from_mapping

M_TO_MM = 1000.0

#: Universal Robots' published standard DH of the UR5 (m, rad), as compas_fab's UR5_PARAMS.
UR5_DH = {
    "d1": 0.089159,
    "a2": -0.42500,
    "a3": -0.39225,
    "d4": 0.10915,
    "d5": 0.09465,
    "d6": 0.0823,
}


def ur5_in_ros_frames(**dh_m: float) -> Arm:
    """The UR5 from its published DH (``dh_m`` replaces values, m), seen as compas_fab
    (ur_kinematics) sees it: world = ``base_link`` (Base turned by pi about z), tool =
    ``ee_link`` (module docstring)."""
    dh = {key: value * M_TO_MM for key, value in {**UR5_DH, **dh_m}.items()}
    rows: list[dict[str, Any]] = [
        {"name": "shoulder_pan", "link": "shoulder", "d_mm": dh["d1"], "alpha_deg": 90.0},
        {"name": "shoulder_lift", "link": "upper_arm", "a_mm": dh["a2"]},
        {"name": "elbow", "link": "forearm", "a_mm": dh["a3"]},
        {"name": "wrist_1", "link": "wrist_1", "d_mm": dh["d4"], "alpha_deg": 90.0},
        {"name": "wrist_2", "link": "wrist_2", "d_mm": dh["d5"], "alpha_deg": -90.0},
        {"name": "wrist_3", "link": "wrist_3", "d_mm": dh["d6"]},
    ]
    for row in rows:  # the UR's joints turn +-360 deg (compas_fab's solutions lie in 0..2 pi)
        row.update({"lower_deg": -360.0, "upper_deg": 360.0})
    # ee_link from tool0 (tool0 = wrist_3 Rx(-pi/2), ee_link = wrist_3 Rz(pi/2)): Rx(pi/2) Rz(pi/2),
    # as URDF rpy (fixed-axis roll, pitch, yaw: Rz(yaw) Ry(pitch) Rx(roll)) = (90, -90, 0) deg
    ee_rpy_deg = [90.0, -90.0, 0.0]
    ee_from_tool0 = Rotation.from_euler("x", 90, degrees=True) * Rotation.from_euler(
        "z", 90, degrees=True
    )
    assert np.allclose(
        Rotation.from_euler("xyz", ee_rpy_deg, degrees=True).as_matrix(),
        ee_from_tool0.as_matrix(),
        atol=1e-12,
    )
    return arm_from_mapping(
        {
            "name": "UR5 (ROS base_link -> ee_link)",
            "convention": "standard",
            "base": {"rpy_deg": [0.0, 0.0, 180.0]},
            "tool": {"rpy_deg": ee_rpy_deg},
            "joints": rows,
        }
    )


def rounding_bounds(arm: Arm, q: np.ndarray, q_step: float) -> tuple[float, float]:
    """How far the published pose can be from the pose of the published angles because the
    angles are rounded to ``q_step`` (rad): each joint moves the tool point by at most its
    lever arm (the Jacobian column's length) times half a step, and each axis by half a step."""
    columns = jacobian(arm, q)
    half = q_step / 2
    position = half * float(np.sum(np.linalg.norm(columns[:3], axis=0)))
    axis = half * float(np.sum(np.linalg.norm(columns[3:], axis=0)))
    return position, axis


def test_ur5_zero_configuration_is_compas_fabs_frame() -> None:
    # test_forward_kinematics: the zero configuration, published to 1e-5 m (0.01 mm): our
    # pose agrees to half that last digit; its axes are exact (0 and 1)
    pose = forward(ur5_in_ros_frames(), np.zeros(6))
    np.testing.assert_allclose(pose[:3, 3], [817.25, 191.45, -5.49], atol=0.005)
    np.testing.assert_allclose(pose[:3, 0], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 1], [1.0, 0.0, 0.0], atol=1e-12)


def test_ur5_inverse_kinematics_solution_reaches_compas_fabs_target() -> None:
    # test_inverse_kinematics: the target frame and its first solution, both published to
    # 1e-3 (m, unit-vector components, rad). Tolerance: the target's own rounding (0.5 mm,
    # 0.0005) plus what rounding each angle by 0.0005 rad moves the tool (rounding_bounds)
    arm = ur5_in_ros_frames()
    q = np.array([0.022, 4.827, 1.508, 1.126, 1.876, 3.163])
    pose = forward(arm, q)
    position_tol, axis_tol = rounding_bounds(arm, q, 1e-3)
    assert position_tol < 2.0 and axis_tol < 0.004  # the bound itself is tight: < 2 mm
    np.testing.assert_allclose(pose[:3, 3], [381.0, 93.0, 382.0], atol=0.5 + position_tol)
    np.testing.assert_allclose(pose[:3, 0], [0.371, -0.292, -0.882], atol=0.0005 + axis_tol)
    np.testing.assert_allclose(pose[:3, 1], [0.113, 0.956, -0.269], atol=0.0005 + axis_tol)


def test_ur5_urdf_example_point_of_compas_fab_docs() -> None:
    # 03_forward_kinematics_urdf.py: angles and point published to 1e-3 (rad, m)
    arm = ur5_in_ros_frames()
    q = np.array([-2.238, -1.153, -2.174, 0.185, 0.667, 0.0])
    pose = forward(arm, q)
    position_tol, _ = rounding_bounds(arm, q, 1e-3)
    np.testing.assert_allclose(pose[:3, 3], [300.0, 100.0, 500.0], atol=0.5 + position_tol)


def test_a_wrong_dh_value_misses_the_published_pose() -> None:
    """The comparison can fail: the UR5e's a3 (-0.3922 m) in place of the UR5's (-0.39225 m)
    moves the zero configuration's tool by 0.05 mm, ten times the tolerance above."""
    wrong = forward(ur5_in_ros_frames(a3=-0.3922), np.zeros(6))
    moved = float(np.linalg.norm(wrong[:3, 3] - [817.25, 191.45, -5.49]))
    assert math.isclose(moved, 0.05, abs_tol=0.002)
