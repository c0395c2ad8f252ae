"""Forward and inverse kinematics of an ``Arm``, its Jacobian, and the tool error of a warm arm.

Conventions (``daemon.arm.types``): mm, rad; poses are 4×4 transforms of the tool in the
arm's base (world) frame; errors are ``Pose6`` (translation + rotation vector, base frame).

The warm arm (issue 20, "Tool error"): each link's thermal growth changes the link's kinematic
parameters, and the tool error at a configuration is the pose from the warm parameters relative
to the pose from the cold ones. A link whose mean temperature rises by ``ΔT`` grows
``alpha·ΔT`` per unit length along its geometry, so its DH ``a`` and ``d`` (or its URDF
origin's translation) scale by ``1 + alpha·ΔT`` (thesis Eq. 3.6, ``alpha = dL/(L dT)``,
integrated over the link as the finite-difference model of thesis 5.3 does:
``ΔL = alpha·mean(ΔT)·L``).

With ``bending``, a temperature difference across the link bends it as a beam. A linear
gradient ``g`` (°C per mm across the section, ``g = ΔT_across/h``) gives the uniform thermal
curvature ``κ = alpha·g`` of an unrestrained beam (Timoshenko & Goodier, *Theory of
Elasticity*, chapter "Thermal stress": ``1/r = alpha·(T1 - T2)/h``; Roark's *Formulas for Stress
and Strain*, 7th ed., Table 8.1, "uniform temperature variation from top to bottom", left end
fixed, right end free: end slope ``gamma·(T1 - T2)·l/t``, end deflection
``gamma·(T1 - T2)·l²/(2t)``). So over the link's length ``L`` its end turns by
``θ = alpha·g·L`` away from the hot side and moves ``alpha·g·L²/2`` towards the cold side.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from daemon.arm.description import Arm, ArmError, FloatArray, rot_axis, rot_z
from daemon.arm.types import LinkThermalState, Pose6, pose_difference

#: ``inverse`` accepts a solution within these of the target pose (far below the A465's
#: ±50 µm repeatability, thesis 3.2.1, and the µm-scale thermal errors it corrects).
IK_POSITION_TOLERANCE_MM = 1e-6  # 1 nm
IK_ROTATION_TOLERANCE_RAD = 1e-9
#: Weight of the rotation residual: 1 rad of orientation error counts as this many mm, about
#: the reach of a small arm, so that position and orientation are balanced.
IK_ROTATION_WEIGHT_MM_PER_RAD = 500.0
#: Extra deterministic starting points tried when the seed does not converge.
IK_RESTARTS = 12
#: SciPy's bounded least squares as the inverse kinematics runs it (trust-region reflective,
#: converged far below IK_POSITION_TOLERANCE_MM); the emulator's wrist-locked solve too.
IK_SOLVER_OPTIONS: dict[str, Any] = {
    "method": "trf",
    "xtol": 1e-15,
    "ftol": 1e-15,
    "gtol": 1e-15,
    "max_nfev": 200,
}
_IK_RNG_SEED = 20


def _q_array(arm: Arm, q_rad: Sequence[float] | FloatArray) -> FloatArray:
    q = np.asarray(q_rad, dtype=np.float64).reshape(-1)
    if q.shape != (arm.dof,):
        raise ArmError(f"arm {arm.name!r} has {arm.dof} joints, got {q.shape[0]} angles")
    if not np.all(np.isfinite(q)):
        raise ArmError(f"arm {arm.name!r}: joint angles must be finite, got {q.tolist()}")
    return q


def _chain(arm: Arm, q: FloatArray) -> tuple[list[FloatArray], list[FloatArray]]:
    """Frames after each joint (base first, without the tool) and, per joint, the frame in
    which it rotates (its axis there is ``joint.axis``)."""
    frames = [np.array(arm.base)]
    pivots = []
    current = frames[0]
    for i, joint in enumerate(arm.joints):
        pivot = current @ arm.pre(i) if arm.convention != "standard" else current
        pivots.append(pivot)
        angle = float(q[i]) + joint.theta_offset_rad
        turn = rot_z(angle) if joint.axis[2] == 1.0 else rot_axis(joint.axis, angle)
        current = pivot @ turn @ arm.post(i)
        frames.append(current)
    return frames, pivots


def link_frames(arm: Arm, q_rad: Sequence[float] | FloatArray) -> list[FloatArray]:
    """The frame of each link in the base frame: ``[base, link 1, ..., link N]`` (N + 1
    transforms, 4×4; ``frames[i + 1]`` is the frame joint ``i`` moves; the tool is not
    included: ``forward`` is ``frames[-1] @ arm.tool``)."""
    frames, _ = _chain(arm, _q_array(arm, q_rad))
    return frames


def forward(arm: Arm, q_rad: Sequence[float] | FloatArray) -> FloatArray:
    """The tool's pose (4×4, base frame, mm) at joint angles ``q_rad``."""
    frames, _ = _chain(arm, _q_array(arm, q_rad))
    return np.asarray(frames[-1] @ arm.tool, dtype=np.float64)


def joint_axes(arm: Arm, q_rad: Sequence[float] | FloatArray) -> tuple[FloatArray, FloatArray]:
    """Each joint's axis in the base frame at ``q_rad``: ``(points, directions)``, both N×3
    (mm; unit vectors): a point the axis passes through and its direction (gravity torques,
    ``tau_i = z_i · sum((p_c - o_i) × m g)``)."""
    _, pivots = _chain(arm, _q_array(arm, q_rad))
    points = np.array([pivot[:3, 3] for pivot in pivots])
    directions = np.array(
        [pivot[:3, :3] @ joint.axis for pivot, joint in zip(pivots, arm.joints, strict=True)]
    )
    return points, directions


def jacobian(arm: Arm, q_rad: Sequence[float] | FloatArray) -> FloatArray:
    """The geometric Jacobian (6×N, base frame) of the tool point: rows ``[v (mm/rad);
    omega (rad/rad)]``; column ``i`` is ``[z_i × (p_tool - o_i); z_i]`` for revolute joint ``i``
    with axis ``z_i`` through ``o_i`` (Spong et al. 2006, § 4.6)."""
    q = _q_array(arm, q_rad)
    frames, pivots = _chain(arm, q)
    tool_point = (frames[-1] @ arm.tool)[:3, 3]
    out = np.zeros((6, arm.dof))
    for i, (pivot, joint) in enumerate(zip(pivots, arm.joints, strict=True)):
        axis = pivot[:3, :3] @ joint.axis
        out[:3, i] = np.cross(axis, tool_point - pivot[:3, 3])
        out[3:, i] = axis
    return out


def inverse(
    arm: Arm,
    pose: FloatArray,
    q_seed: Sequence[float] | FloatArray,
    *,
    position_tolerance_mm: float = IK_POSITION_TOLERANCE_MM,
    rotation_tolerance_rad: float = IK_ROTATION_TOLERANCE_RAD,
    restarts: int = IK_RESTARTS,
) -> FloatArray:
    """Joint angles (rad) within the joint limits that put the tool at ``pose`` (4×4, base
    frame), found by SciPy's bounded least squares (trust-region reflective) from ``q_seed``:
    the solution of the seed's branch (an arm with several solutions returns the one the seed
    leads to). When the seed does not converge, ``restarts`` deterministic starting points are
    tried; they may land on another branch, so pass ``restarts=0`` where continuity with the
    seed matters more than finding a solution. Raises :class:`ArmError` when no solution is
    within the tolerances (the pose is out of reach or outside the joint limits)."""
    target = np.asarray(pose, dtype=np.float64)
    if target.shape != (4, 4) or not np.all(np.isfinite(target)):
        raise ArmError("inverse: the pose must be a finite 4×4 transform")
    seed = _q_array(arm, q_seed)
    lower, upper = arm.lower_rad, arm.upper_rad
    target_rotation = target[:3, :3]
    weight = IK_ROTATION_WEIGHT_MM_PER_RAD

    def residual(q: FloatArray) -> FloatArray:
        current = forward(arm, q)
        rotation = Rotation.from_matrix(current[:3, :3] @ target_rotation.T).as_rotvec()
        return np.concatenate([current[:3, 3] - target[:3, 3], weight * rotation])

    def derivative(q: FloatArray) -> FloatArray:
        # The rotation rows are the angular Jacobian: exact at the solution (the log map's
        # derivative is the identity at zero error), which is where convergence is decided.
        out = jacobian(arm, q)
        out[3:] *= weight
        return out

    def solve(start: FloatArray) -> tuple[FloatArray, float, float]:
        start = np.clip(start, lower, upper)
        result = least_squares(
            residual, start, jac=derivative, bounds=(lower, upper), **IK_SOLVER_OPTIONS
        )
        q = np.clip(result.x, lower, upper)
        error = pose_difference(target, forward(arm, q))
        return q, error.translation_norm_mm, error.rotation_angle_rad

    rng = np.random.default_rng(_IK_RNG_SEED)
    finite_low = np.where(np.isfinite(lower), lower, -np.pi)
    finite_high = np.where(np.isfinite(upper), upper, np.pi)
    best: tuple[FloatArray, float, float] | None = None
    starts = [seed, *(rng.uniform(finite_low, finite_high) for _ in range(restarts))]
    for start in starts:
        q, position_error, rotation_error = solve(start)
        if position_error <= position_tolerance_mm and rotation_error <= rotation_tolerance_rad:
            return q
        if best is None or position_error + weight * rotation_error < best[1] + weight * best[2]:
            best = (q, position_error, rotation_error)
    assert best is not None
    raise ArmError(
        f"arm {arm.name!r}: pose out of reach within the joint limits (best: "
        f"{best[1]:.3g} mm, {best[2]:.3g} rad away)"
    )


def _small_transform(rotation_rad: FloatArray, translation_mm: FloatArray) -> FloatArray:
    out = np.eye(4)
    out[:3, :3] = Rotation.from_rotvec(rotation_rad).as_matrix()
    out[:3, 3] = translation_mm
    return out


def bending_deflection(
    geometry_mm: FloatArray, alpha_per_c: float, gradient_c_per_mm: tuple[float, float]
) -> tuple[FloatArray, FloatArray]:
    """(rotation vector, displacement) of the end of a straight beam ``geometry_mm`` (from its
    fixed end to its free end, in the frame at the free end) under a linear temperature
    gradient ``(g_y, g_z)`` (°C/mm along that frame's y and z; the part along the beam does not
    bend it). Curvature ``alpha·g`` (module docstring): the end turns by ``alpha·L·(g × u)``
    (away from the hot side) and moves ``-alpha·L²/2·g`` (towards the cold side)."""
    length = float(np.linalg.norm(geometry_mm))
    if length == 0.0:
        return np.zeros(3), np.zeros(3)
    u = geometry_mm / length
    g = np.array([0.0, gradient_c_per_mm[0], gradient_c_per_mm[1]])
    g_across = g - float(g @ u) * u
    rotation = alpha_per_c * length * np.cross(g_across, u)
    displacement = -alpha_per_c * length * length / 2.0 * g_across
    return rotation, displacement


def warm_arm(arm: Arm, states: Sequence[LinkThermalState], bending: bool = False) -> Arm:
    """The arm with each link's lengths grown by ``1 + alpha·mean_rise`` (its DH ``a`` and
    ``d``, or its URDF origin's translation; ``Arm.grows_with`` says which link's temperature
    scales which joint's lengths) and, with ``bending``, each link's end turned and moved by
    its across-link gradient (``bending_deflection``; the gradient's (y, z) are those of the
    frame at the distal end of the geometry it bends: for a DH arm the link's own frame,
    ``link_frames[i + 1]``; for a URDF arm the frame of the next joint's origin, fixed in the
    link). Links without a state stay cold; a state naming no link of the arm is an error.
    Base and tool do not grow."""
    by_link: dict[str, LinkThermalState] = {}
    state: LinkThermalState | None
    for state in states:
        arm.link_index(state.link)  # raises for an unknown link
        if state.link in by_link:
            raise ArmError(f"arm {arm.name!r}: two thermal states for link {state.link!r}")
        by_link[state.link] = state
    joints = []
    for i, joint in enumerate(arm.joints):
        link = arm.grows_with(i)
        state = by_link.get(link) if link is not None else None
        if state is None:
            joints.append(joint)
            continue
        scale = 1.0 + state.alpha_per_c * state.mean_rise_c
        deflection = np.array(joint.deflection)
        if bending and any(state.gradient_c_per_mm):
            geometry = arm.geometry_mm(i) * scale
            rotation, displacement = bending_deflection(
                geometry, state.alpha_per_c, state.gradient_c_per_mm
            )
            deflection = deflection @ _small_transform(rotation, displacement)
        if arm.convention == "urdf":
            origin = np.array(joint.origin)
            origin[:3, 3] *= scale
            joints.append(dataclasses.replace(joint, origin=origin, deflection=deflection))
        else:
            joints.append(
                dataclasses.replace(
                    joint, a_mm=joint.a_mm * scale, d_mm=joint.d_mm * scale, deflection=deflection
                )
            )
    return dataclasses.replace(arm, joints=tuple(joints))


def tool_error(
    arm: Arm,
    q_rad: Sequence[float] | FloatArray,
    states: Sequence[LinkThermalState],
    bending: bool = False,
) -> Pose6:
    """The warm arm's tool pose relative to the cold arm's at ``q_rad`` (base frame):
    translation (mm) and rotation vector (rad). Its negative is the 6-DOF correction."""
    cold = forward(arm, q_rad)
    warm = forward(warm_arm(arm, states, bending=bending), q_rad)
    return pose_difference(cold, warm)


def tool_errors(
    arm: Arm,
    qs_rad: Sequence[Sequence[float] | FloatArray],
    states: Sequence[LinkThermalState],
    bending: bool = False,
) -> list[Pose6]:
    """``tool_error`` at several configurations (a duty cycle's measured poses) for one thermal
    state: the arm is warmed once."""
    warm = warm_arm(arm, states, bending=bending)
    return [pose_difference(forward(arm, q), forward(warm, q)) for q in qs_rad]
