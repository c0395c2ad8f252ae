"""Arm description and kinematics (issue 20, piece 1): forward kinematics against published
geometry, the DH table against an independent URDF, inverse kinematics, the Jacobian, and the
analytic cases of a warm arm (growth along straight and perpendicular links, bending)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from daemon.arm.description import ArmError
from daemon.arm.kinematics import (
    bending_deflection,
    forward,
    inverse,
    jacobian,
    joint_axes,
    link_frames,
    tool_error,
    tool_errors,
    warm_arm,
)
from daemon.arm.loading import arm_from_mapping, available_arms, load_arm
from daemon.arm.types import LinkThermalState, pose_difference
from tests.helpers import REPO_ROOT

ARMS = REPO_ROOT / "config" / "arms"
ALPHA_AL = 23.6e-6  # 6061-T6, thesis Table 3.1


def planar_arm(lengths_mm: list[float], convention: str = "standard", **extra: Any) -> Any:
    """N revolute joints about parallel z axes, link i of length ``lengths_mm[i]`` along x."""
    joints = []
    for i, length in enumerate(lengths_mm):
        row: dict[str, Any] = {"name": f"j{i + 1}", "link": f"l{i + 1}"}
        if convention == "standard":
            row["a_mm"] = length
        else:
            # Modified DH: a_{i-1} sits in row i; the last length goes into the tool.
            row["a_mm"] = lengths_mm[i - 1] if i > 0 else 0.0
            row["grows_with"] = f"l{i}" if i > 0 else ""
        joints.append(row)
    data: dict[str, Any] = {"name": "planar", "convention": convention, "joints": joints}
    if convention == "modified":
        data["tool"] = {"xyz_mm": [lengths_mm[-1], 0.0, 0.0]}
    data.update(extra)
    return arm_from_mapping(data)


def state(link: str, rise_c: float, gradient: tuple[float, float] = (0.0, 0.0)) -> Any:
    return LinkThermalState(link, rise_c, ALPHA_AL, gradient)


# --- presets and published geometry --------------------------------------------------------


def test_presets_load_with_thermal_and_motor_data() -> None:
    assert {"crs-a465", "ur5e"} <= set(available_arms())
    for name in ("crs-a465", "ur5e"):
        arm = load_arm(name)
        assert arm.dof == 6
        for link in arm.links:
            assert link.material is not None and link.section is not None, (name, link.name)
            assert link.material.alpha_per_c > 0 and link.section.area_mm2 > 0
        for joint in arm.joints:
            assert joint.motor is not None, (name, joint.name)
            assert joint.motor.heats_link in arm.link_names


def test_ur5e_zero_pose_is_the_published_stretched_arm() -> None:
    # UR's DH article (config/arms/ur5e.toml): at q = 0 the UR5e lies stretched along -x of its
    # Base frame; the flange sits at (a2 + a3, -(d4 + d6), d1 - d5) with its z axis along -y.
    a2, a3, d1, d4, d5, d6 = -425.0, -392.2, 162.5, 133.3, 99.7, 99.6
    pose = forward(load_arm("ur5e"), np.zeros(6))
    np.testing.assert_allclose(pose[:3, 3], [a2 + a3, -(d4 + d6), d1 - d5], atol=1e-9)
    np.testing.assert_allclose(pose[:3, 2], [0.0, -1.0, 0.0], atol=1e-12)


def test_ur5e_upright_pose() -> None:
    # q = (0, -90°, 0, -90°, 0, 0): upper arm and forearm straight up, wrist 2 on top (UR's
    # upright position): the flange sits d5 above the forearm's end, offset by d4 + d6.
    d1, a2, a3, d4, d5, d6 = 162.5, -425.0, -392.2, 133.3, 99.7, 99.6
    q = np.radians([0.0, -90.0, 0.0, -90.0, 0.0, 0.0])
    pose = forward(load_arm("ur5e"), q)
    np.testing.assert_allclose(pose[:3, 3], [0.0, -(d4 + d6), d1 - a2 - a3 + d5], atol=1e-9)


def test_crs_a465_zero_pose_is_upright_and_shoulder_swings_it_flat() -> None:
    # Catalogue zero (config/arms/crs-a465.toml): the arm stands straight up, tool height
    # d1 + a2 + d4 + d6 = 1041.4 mm; the shoulder at ±90° lays the rest horizontally.
    arm = load_arm("crs-a465")
    pose = forward(arm, np.zeros(6))
    np.testing.assert_allclose(pose[:3, 3], [0.0, 0.0, 1041.4], atol=1e-9)
    np.testing.assert_allclose(pose[:3, :3], np.eye(3), atol=1e-12)
    flat = forward(arm, np.radians([0.0, 90.0, 0.0, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(abs(flat[0, 3]), 304.8 + 330.2 + 76.2, atol=1e-9)
    np.testing.assert_allclose(flat[1:3, 3], [0.0, 330.2], atol=1e-9)


def test_dh_table_agrees_with_the_urdf_of_ur_description() -> None:
    dh = load_arm("ur5e")
    urdf = load_arm(ARMS / "ur5e-urdf.toml")
    assert urdf.convention == "urdf" and urdf.dof == 6
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.uniform(-math.pi, math.pi, 6)
        difference = pose_difference(forward(dh, q), forward(urdf, q))
        assert difference.translation_norm_mm < 1e-5
        assert difference.rotation_angle_rad < 1e-8


def test_bare_urdf_loads_its_kinematics_from_the_deepest_leaf() -> None:
    arm = load_arm(ARMS / "ur5e.urdf")
    assert arm.link_names[-1] == "wrist_3_link"
    assert arm.links[0].material is None
    # base_link is REP-103: the UR "Base" frame is it turned by pi about z.
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    q = np.array([0.2, -1.0, 0.7, 0.1, -0.4, 0.9])
    np.testing.assert_allclose(flip @ forward(arm, q), forward(load_arm("ur5e"), q), atol=1e-6)


def test_link_lengths_follow_grows_with() -> None:
    arm = load_arm("crs-a465")
    assert arm.link_length_mm("turret") == pytest.approx(330.2)
    assert arm.link_length_mm("upper-arm") == pytest.approx(304.8)
    assert arm.link_length_mm("forearm") == pytest.approx(330.2)
    assert arm.link_length_mm("wrist-roll") == 0.0  # no row grows with it
    ur5e = load_arm("ur5e")
    assert ur5e.link_length_mm("upper_arm") == pytest.approx(425.0)
    # d4 lies along z_3, a3 along x_3: the forearm row's geometry is its a only.
    assert ur5e.link_length_mm("forearm") == pytest.approx(392.2)


def test_link_frames_end_at_the_flange() -> None:
    arm = load_arm("crs-a465")
    q = np.radians([10.0, -20.0, 30.0, 40.0, -50.0, 60.0])
    frames = link_frames(arm, q)
    assert len(frames) == arm.dof + 1
    np.testing.assert_allclose(frames[0], arm.base)
    np.testing.assert_allclose(frames[-1] @ arm.tool, forward(arm, q))


def test_standard_and_modified_dh_describe_the_same_planar_arm() -> None:
    lengths = [300.0, 200.0, 100.0]
    q = np.radians([30.0, -45.0, 60.0])
    standard = forward(planar_arm(lengths), q)
    modified = forward(planar_arm(lengths, "modified"), q)
    np.testing.assert_allclose(standard, modified, atol=1e-9)
    angle = math.radians(30.0)
    expected_x = 300 * math.cos(angle) + 200 * math.cos(angle - math.radians(45))
    expected_x += 100 * math.cos(math.radians(45.0))
    assert standard[0, 3] == pytest.approx(expected_x)


# --- Jacobian and inverse kinematics -------------------------------------------------------


@pytest.mark.parametrize("name", ["crs-a465", "ur5e"])
def test_jacobian_matches_finite_differences(name: str) -> None:
    arm = load_arm(name)
    q = np.radians([15.0, -30.0, 40.0, 25.0, -35.0, 50.0])
    step = 1e-6
    numeric = np.zeros((6, arm.dof))
    for i in range(arm.dof):
        dq = np.zeros(arm.dof)
        dq[i] = step
        plus, minus = forward(arm, q + dq), forward(arm, q - dq)
        numeric[:3, i] = (plus[:3, 3] - minus[:3, 3]) / (2 * step)
        turn = Rotation.from_matrix(plus[:3, :3] @ minus[:3, :3].T).as_rotvec()
        numeric[3:, i] = turn / (2 * step)
    np.testing.assert_allclose(jacobian(arm, q), numeric, atol=1e-5)


@pytest.mark.parametrize("name", ["crs-a465", "ur5e"])
def test_inverse_round_trip(name: str) -> None:
    arm = load_arm(name)
    rng = np.random.default_rng(7)
    lower = np.maximum(arm.lower_rad, -math.pi) * 0.8
    upper = np.minimum(arm.upper_rad, math.pi) * 0.8
    for _ in range(5):
        q = rng.uniform(lower, upper)
        target = forward(arm, q)
        solution = inverse(arm, target, q + rng.normal(0.0, 0.15, arm.dof))
        error = pose_difference(target, forward(arm, solution))
        assert error.translation_norm_mm < 1e-6
        assert error.rotation_angle_rad < 1e-9
        assert np.all(solution >= arm.lower_rad) and np.all(solution <= arm.upper_rad)


def test_inverse_refuses_an_unreachable_pose() -> None:
    arm = load_arm("crs-a465")
    target = np.eye(4)
    target[:3, 3] = (2000.0, 0.0, 300.0)  # reach is 711 mm from the shoulder
    with pytest.raises(ArmError, match="out of reach"):
        inverse(arm, target, np.zeros(6))


# --- the warm arm ---------------------------------------------------------------------------


def test_zero_rise_gives_zero_error() -> None:
    arm = load_arm("crs-a465")
    q = np.radians([10.0, 20.0, -30.0, 5.0, 40.0, -60.0])
    error = tool_error(arm, q, [state(name, 0.0) for name in arm.link_names], bending=True)
    assert np.all(error.as_array() == 0.0)


def test_uniform_rise_on_a_straight_arm_moves_the_tool_by_the_sum_along_it() -> None:
    # The A465 at zero stands straight up: every length lies along z.
    arm = load_arm("crs-a465")
    rise = 10.0
    error = tool_error(arm, np.zeros(6), [state(name, rise) for name in arm.link_names])
    lengths = 330.2 + 304.8 + 330.2 + 76.2
    np.testing.assert_allclose(error.translation_mm, [0, 0, ALPHA_AL * rise * lengths], atol=1e-12)
    np.testing.assert_allclose(error.rotation_rad, 0.0, atol=1e-15)


@pytest.mark.parametrize("convention", ["standard", "modified"])
def test_each_link_grows_alpha_dt_l_along_a_straight_planar_arm(convention: str) -> None:
    lengths = [300.0, 200.0, 100.0]
    rises = [5.0, 12.0, 20.0]
    arm = planar_arm(lengths, convention)
    states = [state(f"l{i + 1}", rise) for i, rise in enumerate(rises)]
    if convention == "modified":
        states = states[:-1]  # the last length is the (rigid) tool in this description
        lengths, rises = lengths[:-1], rises[:-1]
    error = tool_error(arm, np.zeros(3), states)
    expected = sum(ALPHA_AL * rise * length for rise, length in zip(rises, lengths, strict=True))
    np.testing.assert_allclose(error.translation_mm, [expected, 0.0, 0.0], atol=1e-12)


def test_a_perpendicular_link_moves_the_tool_sideways() -> None:
    arm = planar_arm([300.0, 200.0])
    q = np.radians([0.0, 90.0])  # link 1 along x, link 2 along y
    first = tool_error(arm, q, [state("l1", 10.0)])
    np.testing.assert_allclose(first.translation_mm, [ALPHA_AL * 10 * 300, 0, 0], atol=1e-12)
    second = tool_error(arm, q, [state("l2", 10.0)])
    np.testing.assert_allclose(second.translation_mm, [0, ALPHA_AL * 10 * 200, 0], atol=1e-12)
    np.testing.assert_allclose(second.rotation_rad, 0.0, atol=1e-15)


def test_bending_matches_the_beam_formula() -> None:
    # A cantilever along x of length L with a gradient g across it (°C/mm along y): thermal
    # curvature alpha·g, end rotation alpha·g·L about -z (away from the hot +y side), end
    # deflection alpha·g·L²/2 towards -y (Roark's Table 8.1, kinematics docstring).
    length, overhang, g = 400.0, 50.0, 0.05
    arm = planar_arm([length], tool={"xyz_mm": [overhang, 0.0, 0.0]})
    error = tool_error(arm, np.zeros(1), [state("l1", 0.0, (g, 0.0))], bending=True)
    angle = ALPHA_AL * g * length
    sideways = ALPHA_AL * g * length**2 / 2 + math.sin(angle) * overhang
    np.testing.assert_allclose(error.rotation_rad, [0.0, 0.0, -angle], rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(error.translation_mm[1], -sideways, rtol=1e-9)
    # The overhang, turned by the angle, comes back by overhang·(1 - cos angle) along x.
    np.testing.assert_allclose(error.translation_mm[0], overhang * (math.cos(angle) - 1), rtol=1e-6)
    assert abs(error.translation_mm[2]) < 1e-15
    # Without bending the gradient does nothing; along z it bends about +y, down in -z.
    assert tool_error(arm, np.zeros(1), [state("l1", 0.0, (g, 0.0))]).translation_norm_mm == 0
    up = tool_error(arm, np.zeros(1), [state("l1", 0.0, (0.0, g))], bending=True)
    np.testing.assert_allclose(up.rotation_rad, [0.0, angle, 0.0], rtol=1e-12, atol=1e-18)
    assert up.translation_mm[2] < 0


def test_tool_errors_at_several_poses_equal_one_at_a_time() -> None:
    arm = load_arm("crs-a465")
    states = [state(name, 3.0 + i, (0.01 * i, -0.02)) for i, name in enumerate(arm.link_names)]
    qs = [np.zeros(6), np.radians([30.0, 20.0, -40.0, 10.0, 60.0, -90.0])]
    together = tool_errors(arm, qs, states, bending=True)
    for q, error in zip(qs, together, strict=True):
        alone = tool_error(arm, q, states, bending=True)
        np.testing.assert_array_equal(error.as_array(), alone.as_array())
    assert together[0].translation_norm_mm != together[1].translation_norm_mm


def test_bending_ignores_a_gradient_along_the_beam() -> None:
    rotation, displacement = bending_deflection(np.array([0.0, 0.0, 100.0]), ALPHA_AL, (0.0, 1.0))
    assert np.all(rotation == 0) and np.all(displacement == 0)


def test_warm_arm_is_a_new_arm_with_longer_links() -> None:
    arm = load_arm("ur5e")
    warm = warm_arm(arm, [state("upper_arm", 20.0)])
    assert warm.joints[1].a_mm == pytest.approx(-425.0 * (1 + ALPHA_AL * 20.0))
    assert arm.joints[1].a_mm == -425.0
    urdf = load_arm(ARMS / "ur5e-urdf.toml")
    # The URDF's elbow origin (the upper arm's length) lies in the upper arm, its parent.
    warm_urdf = warm_arm(urdf, [state("upper_arm_link", 20.0)])
    assert warm_urdf.joints[2].origin[0, 3] == pytest.approx(-425.0 * (1 + ALPHA_AL * 20.0))


def test_dh_and_urdf_arms_warm_alike() -> None:
    dh, urdf = load_arm("ur5e"), load_arm(ARMS / "ur5e-urdf.toml")
    q = np.array([0.3, -1.1, 0.9, -0.6, 1.2, 0.2])
    # Upper arm and forearm lengths are a2, a3 in the DH table and the elbow and wrist 1
    # origins' x in the URDF: heat the same physical links in both.
    dh_error = tool_error(dh, q, [state("upper_arm", 15.0)])
    urdf_error = tool_error(urdf, q, [state("upper_arm_link", 15.0)])
    np.testing.assert_allclose(dh_error.translation_mm, urdf_error.translation_mm, atol=1e-6)


# --- errors ---------------------------------------------------------------------------------


def test_unknown_link_in_a_state_is_refused() -> None:
    with pytest.raises(ArmError, match="no link 'nope'"):
        warm_arm(load_arm("ur5e"), [state("nope", 1.0)])


def test_wrong_number_of_angles_is_refused() -> None:
    with pytest.raises(ArmError, match="6 joints, got 5"):
        forward(load_arm("ur5e"), np.zeros(5))


def test_bad_file_names_the_file_and_field(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(
        'convention = "standard"\n[[joints]]\nname = "j1"\na_mm = "long"\n', encoding="utf-8"
    )
    with pytest.raises(ArmError) as caught:
        load_arm(path)
    message = str(caught.value)
    assert str(path) in message and "joint 'j1': a_mm" in message and "\n" not in message


def test_bad_motor_link_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "motor.toml"
    path.write_text(
        'convention = "standard"\n[[joints]]\nname = "j1"\nlink = "l1"\n[joints.motor]\n'
        "torque_constant_nm_per_a = 0.1\nwinding_resistance_ohm = 1\ngear_ratio = 100\n"
        'heats_link = "elsewhere"\n',
        encoding="utf-8",
    )
    with pytest.raises(ArmError, match=r"motor\.heats_link 'elsewhere' is no link"):
        load_arm(path)


def test_unreadable_urdf_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "broken.urdf"
    path.write_text("<robot name='x'><joint name='j' type='prismatic'>", encoding="utf-8")
    with pytest.raises(ArmError, match=str(path)):
        load_arm(path)


def test_urdf_companion_naming_an_unknown_joint_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "arm.toml"
    path.write_text(
        f'urdf = "{ARMS / "ur5e.urdf"}"\n[[joints]]\nname = "knee_joint"\n', encoding="utf-8"
    )
    with pytest.raises(ArmError, match="joint 'knee_joint': no moving joint"):
        load_arm(path)


def test_urdf_companion_refuses_dh_values(tmp_path: Path) -> None:
    path = tmp_path / "arm.toml"
    path.write_text(
        f'urdf = "{ARMS / "ur5e.urdf"}"\n[[joints]]\nname = "elbow_joint"\na_mm = 3\n',
        encoding="utf-8",
    )
    with pytest.raises(ArmError, match="takes no DH values"):
        load_arm(path)


def test_missing_preset_lists_the_presets() -> None:
    with pytest.raises(ArmError, match="crs-a465"):
        load_arm("no-such-arm")


def test_inverse_without_restarts_stays_on_the_seeds_branch() -> None:
    arm = load_arm("ur5e")
    q = np.array([0.4, -1.2, 1.0, -0.8, 1.3, 0.3])
    target = forward(arm, q)
    solution = inverse(arm, target, q + 0.05, restarts=0)
    assert pose_difference(target, forward(arm, solution)).translation_norm_mm < 1e-6
    np.testing.assert_allclose(solution, q, atol=1e-7)  # the seed's branch, not another


@pytest.mark.parametrize("name", ["crs-a465", "ur5e", "ur5e-urdf"])
def test_growth_superposes_and_never_turns_the_tool(name: str) -> None:
    # Positions are linear in the lengths at fixed angles and lengths never change
    # orientations: the growth errors of separate links add up and carry no rotation.
    arm = load_arm(name)
    q = np.radians([25.0, -35.0, 50.0, -20.0, 40.0, 70.0])
    rises = [4.0, 9.0, 2.5, 6.0, 11.0, 3.0]
    states = [state(link, rise) for link, rise in zip(arm.link_names, rises, strict=True)]
    together = tool_error(arm, q, states)
    apart = sum(tool_error(arm, q, [one]).translation_mm for one in states)
    np.testing.assert_allclose(together.translation_mm, apart, atol=1e-12)
    np.testing.assert_allclose(together.rotation_rad, 0.0, atol=1e-14)
    assert together.translation_norm_mm > 0.01


def reak_a465_axes(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The A465 as the ReaK model builds it (mikael-s-persson/ReaK,
    build_CRS_A465_model.cpp: revolute joints about z, rigid links link_1..link_5 in metres
    given here in mm), independent of the DH table and of its zero angles: joint axes
    (points, directions) and the flange point."""

    def rigid(xyz: tuple[float, float, float], rotation: Rotation) -> np.ndarray:
        out = np.eye(4)
        out[:3, :3] = rotation.as_matrix()
        out[:3, 3] = xyz
        return out

    quarter = math.pi / 2
    about = Rotation.from_rotvec
    links = [
        rigid((0.0, 0.0, 330.2), about([quarter, 0, 0])),
        rigid((304.8, 0.0, 0.0), Rotation.identity()),
        rigid((150.0, 0.0, 0.0), about([0, quarter, 0]) * about([0, 0, quarter])),
        rigid((0.0, 0.0, 180.2), about([-quarter, 0, 0])),
        rigid((76.2, 0.0, 0.0), about([0, quarter, 0]) * about([0, 0, quarter])),
    ]
    frame = np.eye(4)
    points, directions = [], []
    for i in range(6):
        points.append(frame[:3, 3].copy())
        directions.append(frame[:3, 2].copy())
        frame = frame @ rigid((0.0, 0.0, 0.0), about([0, 0, q[i]]))
        if i < len(links):
            frame = frame @ links[i]
    return np.array(points), np.array(directions), frame[:3, 3]


def axis_invariants(points: np.ndarray, directions: np.ndarray, flange: np.ndarray) -> list[float]:
    """What any description of one mechanism shares, whatever its zero angles: distances and
    angles between successive joint axes, the wrist centre's distance from axis 3, the
    flange's distance from the wrist centre and from axis 6."""

    def line_distance(i: int, j: int) -> float:
        normal = np.cross(directions[i], directions[j])
        gap = points[j] - points[i]
        if np.linalg.norm(normal) < 1e-12:
            return float(np.linalg.norm(np.cross(gap, directions[i])))
        return abs(float(gap @ normal)) / float(np.linalg.norm(normal))

    def angle(i: int, j: int) -> float:
        cross = float(np.linalg.norm(np.cross(directions[i], directions[j])))
        return math.atan2(cross, abs(float(directions[i] @ directions[j])))

    # Wrist centre: the point nearest axes 4, 5 and 6 (they meet there).
    rows = [np.eye(3) - np.outer(d, d) for d in directions[3:]]
    centre = np.linalg.solve(sum(rows), sum(r @ p for r, p in zip(rows, points[3:], strict=True)))
    to_axis_3 = np.cross(centre - points[2], directions[2])
    return [
        *(line_distance(i, i + 1) for i in range(5)),
        *(angle(i, i + 1) for i in range(5)),
        float(np.linalg.norm(to_axis_3)),
        float(np.linalg.norm(flange - centre)),
        float(np.linalg.norm(np.cross(flange - points[5], directions[5]))),
    ]


def test_crs_a465_has_the_joint_geometry_of_the_reak_model() -> None:
    arm = load_arm("crs-a465")
    rng = np.random.default_rng(465)
    for _ in range(3):
        q = rng.uniform(arm.lower_rad, arm.upper_rad)
        ours = joint_axes(arm, q)
        flange = forward(arm, q)[:3, 3]
        theirs = reak_a465_axes(rng.uniform(-math.pi, math.pi, 6))
        np.testing.assert_allclose(
            axis_invariants(*ours, flange), axis_invariants(*theirs), atol=1e-9
        )
    # And they are the published lengths: shoulder offset 0, upper arm 304.8, forearm 330.2
    # from axis 3 to the wrist centre, flange 76.2 from it on axis 6.
    invariants = axis_invariants(*joint_axes(arm, np.zeros(6)), forward(arm, np.zeros(6))[:3, 3])
    assert invariants[1] == pytest.approx(304.8)
    assert invariants[10:] == pytest.approx([330.2, 76.2, 0.0], abs=1e-9)


def test_joint_axes_are_the_jacobians_axes() -> None:
    arm = load_arm("ur5e-urdf")
    q = np.array([0.1, -0.9, 1.4, 0.3, -0.7, 2.0])
    points, directions = joint_axes(arm, q)
    tool = forward(arm, q)[:3, 3]
    expected = np.vstack([np.cross(directions, tool - points).T, directions.T])
    np.testing.assert_allclose(jacobian(arm, q), expected, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0)
    np.testing.assert_allclose(points[0], [0.0, 0.0, 162.5], atol=1e-9)  # shoulder pan axis
