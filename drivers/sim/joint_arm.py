"""The emulated C500C's arm in joint space (issue 20): the arm's pose IS its joint vector, world
moves go through the inverse kinematics of daemon.arm.kinematics, and every motion is a
synchronised trapezoidal joint-space profile timed by the emulator's clock (the asyncio loop's
time of the loop serving the emulator). ``sample(t_s)`` gives the positions, speeds and
accelerations the emulated arm really had at ``t_s``, so the arm bench's truth can compute motor
heat from the motion the emulator performed (drivers/sim/arm_bench.py, wt-armbench).

No I/O here: drivers/sim/ash.py (the console) uses it when its EmulatorConfig has an arm.

Conventions (ASSUMED where docs/reference/c500c-console.md is silent):
- A world location is x, y, z (mm) and z-rot, y-rot, x-rot (degrees): the tool's position
  and its rotation as intrinsic z-y-x angles (daemon.arm.types.Pose6.zyx_deg's convention).
- `wshift loc,dx,dy,dz,zr,yr,xr` turns the location by the z-y-x rotation (zr, yr, xr) in the
  world frame about its own position and moves it by (dx, dy, dz) (docs/reference/c500c-console.md:
  "shifts a location in world coordinates").
- A location is solved from the current joints (the controller keeps its stance); when that
  local solve does not reach it (a large waist swing: a 190 degree turn stalled, issue 29),
  from the same stance turned to face the target, the wrist as it is or flipped, the solution
  nearest the current joints on the same wrist side (drivers/sim/arm_reach.py); so too over a
  swing of more than 90 degrees or when the local solve flipped the wrist (another branch).
  A location none of these reach within the joint limits is catalogue 003.
- At the wrist singularity (the last three joints' axes in one plane: the A465's joint 5 = 0,
  joints 4 and 6 aligned) the controller keeps the first wrist joint where it is and solves
  the other joints for the position exactly and for the orientation as closely as the wrist
  allows (ASSUMED, docs/reference/c500c-console.md is silent; the usual closed-form treatment of a
  spherical wrist's singularity, Siciliano et al., *Robotics: Modelling, Planning and Control*,
  2009, § 2.12.2 and § 3.3.2: there only the sum of joints 4 and 6 is determined, and an exact
  solution of a location a few µrad off the singular set swings joints 4 and 6 by tens of degrees in
  opposite senses). Without it a µm-scale `wshift` at the camera station swung joints 4 and 6 by ~27
  degrees, and the bench's true arm (other DH values, as any real arm) moved the tool 25-45 µm
  away from the commanded change (docs/explanation/arm.md). A location whose
  orientation the locked wrist cannot reach within ``WRIST_LOCK_ROTATION_TOLERANCE_RAD`` (a
  real reorientation) is solved exactly as elsewhere.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from daemon.arm.description import Arm, ArmError
from daemon.arm.kinematics import IK_SOLVER_OPTIONS, forward, inverse, jacobian
from daemon.arm.types import JointSample, pose_difference, zyx_deg_of
from drivers.sim.arm_reach import nearest_solution, needs_branch_search

FloatArray = NDArray[np.float64]
Location = tuple[float, float, float, float, float, float]

#: Where the emulated arm starts (degrees): elbow up, wrist bent, away from the singularities of
#: a 6-axis elbow arm (shoulder, elbow and wrist pitch all non-zero).
DEFAULT_START_JOINTS_DEG: tuple[float, ...] = (0.0, 30.0, 60.0, 0.0, 30.0, 0.0)
#: Joint speed and acceleration of every motion (deg/s, deg/s^2): emulator values of the order
#: of the A465's at a moderate speed setting (its published maximum joint speeds are ~180 deg/s).
DEFAULT_SPEED_DEG_S = 60.0
DEFAULT_ACCELERATION_DEG_S2 = 240.0
#: The console's speed setting at which ``speed_deg_s`` applies (drivers/sim/ash_state.py
#: START_SPEED_PERCENT: the controller's setting at start-up, which the emulator of before never
#: changed): at another setting the joint speed scales in proportion (`speed N`,
#: docs/reference/c500c-console.md).
REFERENCE_SPEED_PERCENT = 10
#: Encoder pulses per joint degree for the `PULSES` row. ESTIMATED: no public figure for the
#: A465 was found; the order of a 1,000-line quadrature encoder (4,000 counts per motor turn)
#: on a 100:1 harmonic drive: 4,000 x 100 / 360 = 1,111 per degree.
ESTIMATED_A465_PULSES_PER_DEG = 1111.0
#: Motions kept for ``sample()`` of past times (a run's bench samples between its steps).
MOTION_HISTORY = 4096
#: The wrist is singular when the smallest singular value of its three joints' angular
#: Jacobian (|sin| of the middle wrist joint's angle for a spherical wrist) is below the sine
#: of this angle (degrees): a wrist bent less than this keeps its first joint (module docstring).
WRIST_SINGULAR_DEG = 1.0
#: A locked-wrist solution is accepted when the orientation it misses is below this (rad):
#: the unreachable part of a thermal correction (tens of µrad) and of the console's 0.001 degree
#: angle steps; anything larger is a real reorientation and is solved exactly.
WRIST_LOCK_ROTATION_TOLERANCE_RAD = 1e-3
#: ... and its position within this of the target (mm; 0.1 µm, far below the A465's ±50 µm
#: repeatability, thesis 3.2.1).
WRIST_LOCK_POSITION_TOLERANCE_MM = 1e-4
#: Weight of the orientation residual of the locked-wrist solve (mm per rad): small, so that
#: the position is met and the orientation is matched in the directions the wrist can reach.
WRIST_LOCK_ROTATION_WEIGHT_MM_PER_RAD = 1.0
#: Solutions kept with JointArmConfig.cache_solutions (a played cycle's locations, each with
#: its correction of the step: a few per step).
SOLUTION_CACHE = 4096
#: A 6-joint arm's wrist: its last three joints.
WRIST_JOINTS = 3


class UnreachableError(Exception):
    """The location is out of reach from the arm's current joints (catalogue 003)."""


@dataclass(frozen=True, eq=False)
class JointArmConfig:
    """The arm of a joint-space emulator and how it moves."""

    arm: Arm
    start_joints_deg: tuple[float, ...] = DEFAULT_START_JOINTS_DEG
    speed_deg_s: float = DEFAULT_SPEED_DEG_S
    acceleration_deg_s2: float = DEFAULT_ACCELERATION_DEG_S2
    #: per joint; None: ESTIMATED_A465_PULSES_PER_DEG for every joint
    pulses_per_deg: tuple[float, ...] | None = None
    #: the controller's per-joint speed limits at `speed 100` (deg/s; issue 20: a played duty
    #: cycle's arm moves at its pose's percentage of them, each motion synchronised so that no
    #: joint exceeds its own, as daemon/arm/duty.py plans it); None: one speed for every
    #: joint, ``speed_deg_s`` at REFERENCE_SPEED_PERCENT, scaled by the setting
    max_speed_deg_s: tuple[float, ...] | None = None
    #: keep the exact inverse-kinematics solution of each world location and reuse it when the
    #: arm is sent there again (a played duty cycle goes to the same few locations thousands of
    #: times; the arm keeps its stance, so the solution is the one a solve from the current
    #: joints converges to; the wrist-singular case is still solved from the current joints):
    #: the bench's speed only, off by default
    cache_solutions: bool = False
    #: ... and acceleration limits (deg/s^2), NOT scaled by the speed setting: the console has
    #: no acceleration command (docs/reference/c500c-console.md "Motion and locations" lists `speed
    #: [%]` only), so the controller keeps its own (ASSUMED); None: ``acceleration_deg_s2`` for
    #: every joint
    max_accel_deg_s2: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        joints = len(self.arm.joints)
        if len(self.start_joints_deg) != joints:
            raise ValueError(f"{joints} start joint angles expected")
        if not (self.speed_deg_s > 0 and self.acceleration_deg_s2 > 0):
            raise ValueError("joint speed and acceleration must be positive")
        if self.pulses_per_deg is not None and len(self.pulses_per_deg) != joints:
            raise ValueError(f"{joints} pulses-per-degree values expected")
        for limits in (self.max_speed_deg_s, self.max_accel_deg_s2):
            if limits is not None and (
                len(limits) != joints or not all(math.isfinite(v) and v > 0 for v in limits)
            ):
                raise ValueError(f"{joints} positive joint limits expected, got {limits}")

    def limits_rad(self, speed_percent: int) -> tuple[FloatArray, FloatArray]:
        """Each joint's speed (rad/s) and acceleration (rad/s^2) limit at the console's speed
        setting ``speed_percent`` (the fields' comments)."""
        joints = len(self.arm.joints)
        if self.max_speed_deg_s is None:
            speed = np.full(joints, self.speed_deg_s)
            if speed_percent != REFERENCE_SPEED_PERCENT:
                speed = speed * (speed_percent / REFERENCE_SPEED_PERCENT)
        else:
            speed = np.asarray(self.max_speed_deg_s, dtype=np.float64) * (speed_percent / 100.0)
        accel = (
            np.full(joints, self.acceleration_deg_s2)
            if self.max_accel_deg_s2 is None
            else np.asarray(self.max_accel_deg_s2, dtype=np.float64)
        )
        return np.radians(speed), np.radians(accel)


@dataclass(frozen=True, eq=False)
class _Motion:
    """One synchronised trapezoidal profile: every joint follows ``q0 + (q1 - q0) * s(t)``
    with s the trapezoid of the joint that moves farthest (the others are slower in
    proportion, so none exceeds the speed and acceleration limits)."""

    start_s: float
    q0: FloatArray
    q1: FloatArray
    distance_rad: float  # of the joint that moves farthest
    acceleration: float  # rad/s^2 of that joint
    ramp_s: float  # time accelerating (= decelerating)
    duration_s: float

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    def along(self, t_s: float) -> tuple[float, float, float]:
        """Distance (rad), speed and acceleration of the farthest joint at ``t_s``."""
        t = t_s - self.start_s
        a, ramp, total, dist = self.acceleration, self.ramp_s, self.duration_s, self.distance_rad
        if t <= 0.0 or total == 0.0:
            return 0.0, 0.0, 0.0
        if t >= total:
            return dist, 0.0, 0.0
        peak = a * ramp
        if t < ramp:
            return 0.5 * a * t * t, a * t, a
        if t <= total - ramp:
            return 0.5 * a * ramp * ramp + peak * (t - ramp), peak, 0.0
        left = total - t
        return dist - 0.5 * a * left * left, a * left, -a

    def sample(self, t_s: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        s, v, acc = self.along(t_s)
        if self.distance_rad == 0.0:
            zero = np.zeros_like(self.q0)
            return self.q0.copy(), zero, zero.copy()
        scale = (self.q1 - self.q0) / self.distance_rad
        return self.q0 + scale * s, scale * v, scale * acc

    def halted_at(self, t_s: float) -> _Motion:
        """This motion cut at ``t_s``: the arm stays where it was then (the emulator's halt
        stops at once; a real halt decelerates)."""
        q, _, _ = self.sample(t_s)
        return _Motion(t_s, q, q, 0.0, self.acceleration, 0.0, 0.0)


def trapezoid(
    q0: FloatArray, q1: FloatArray, start_s: float, speed: float, acceleration: float
) -> _Motion:
    """The time-optimal synchronised profile from ``q0`` to ``q1`` (rad) under one joint speed
    and acceleration limit (rad/s, rad/s^2): trapezoidal when the farthest joint reaches the
    speed limit, triangular otherwise."""
    distance = float(np.max(np.abs(q1 - q0))) if q0.size else 0.0
    if distance == 0.0:
        return _Motion(start_s, q0, q1, 0.0, acceleration, 0.0, 0.0)
    if distance >= speed * speed / acceleration:
        ramp = speed / acceleration
        duration = distance / speed + ramp
    else:
        ramp = math.sqrt(distance / acceleration)
        duration = 2.0 * ramp
    return _Motion(start_s, q0, q1, distance, acceleration, ramp, duration)


def synchronised(
    q0: FloatArray, q1: FloatArray, start_s: float, speed: FloatArray, acceleration: FloatArray
) -> _Motion:
    """The synchronised profile under per-joint limits (daemon/arm/duty.py's plan): every joint
    follows one normalised trapezoid s(t) from 0 to 1 whose speed and acceleration are the
    tightest of the moving joints' ``limit_j / |dq_j|``. With equal limits it is
    :func:`trapezoid` exactly."""
    delta = np.abs(q1 - q0)
    moving = delta > 0.0
    if not moving.any():
        return _Motion(start_s, q0, q1, 0.0, float(np.min(acceleration)), 0.0, 0.0)
    if np.ptp(speed) == 0.0 and np.ptp(acceleration) == 0.0:
        return trapezoid(q0, q1, start_s, float(speed[0]), float(acceleration[0]))
    normal_speed = float(np.min(speed[moving] / delta[moving]))
    normal_accel = float(np.min(acceleration[moving] / delta[moving]))
    # the normalised profile as a motion of "distance 1": sample() scales it by q1 - q0
    unit = trapezoid(np.zeros(1), np.ones(1), start_s, normal_speed, normal_accel)
    return _Motion(start_s, q0, q1, 1.0, unit.acceleration, unit.ramp_s, unit.duration_s)


def wrist_singular(arm: Arm, q_rad: FloatArray) -> bool:
    """Whether the arm's wrist (its last three joints, an arm of six or more) is at its
    singularity: their angular Jacobian loses rank (module docstring)."""
    if arm.dof < 2 * WRIST_JOINTS:
        return False
    angular = jacobian(arm, q_rad)[3:, -WRIST_JOINTS:]
    smallest = float(np.linalg.svd(angular, compute_uv=False)[-1])
    return smallest < math.sin(math.radians(WRIST_SINGULAR_DEG))


def wrist_locked_inverse(
    arm: Arm, pose: FloatArray, seed: FloatArray, q_now: FloatArray
) -> FloatArray | None:
    """The joints that reach ``pose``'s position with the first wrist joint kept at
    ``q_now``'s, the orientation matched as closely as the wrist allows (module docstring),
    solved from ``seed`` (the other joints); None when the position is missed or the
    orientation missed by more than WRIST_LOCK_ROTATION_TOLERANCE_RAD."""
    locked = arm.dof - WRIST_JOINTS
    free = np.array([i for i in range(arm.dof) if i != locked])
    lower, upper = arm.lower_rad[free], arm.upper_rad[free]
    target_rotation = pose[:3, :3]
    weight = WRIST_LOCK_ROTATION_WEIGHT_MM_PER_RAD

    def joints(x: FloatArray) -> FloatArray:
        q = seed.copy()
        q[locked] = q_now[locked]
        q[free] = x
        return q

    def residual(x: FloatArray) -> FloatArray:
        current = forward(arm, joints(x))
        rotation = Rotation.from_matrix(current[:3, :3] @ target_rotation.T).as_rotvec()
        return np.concatenate([current[:3, 3] - pose[:3, 3], weight * rotation])

    def derivative(x: FloatArray) -> FloatArray:
        out = jacobian(arm, joints(x))[:, free]
        out[3:] *= weight
        return out

    result = least_squares(
        residual,
        np.clip(seed[free], lower, upper),
        jac=derivative,
        bounds=(lower, upper),
        **IK_SOLVER_OPTIONS,
    )
    q = joints(np.clip(result.x, lower, upper))
    error = pose_difference(pose, forward(arm, q))
    if (
        error.translation_norm_mm > WRIST_LOCK_POSITION_TOLERANCE_MM
        or error.rotation_angle_rad > WRIST_LOCK_ROTATION_TOLERANCE_RAD
    ):
        return None
    return q


def pose_of(location: Sequence[float]) -> FloatArray:
    """A world location (mm, z-y-x degrees) as a 4x4 transform."""
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("ZYX", list(location[3:6]), degrees=True).as_matrix()
    pose[:3, 3] = location[:3]
    return pose


def location_of(pose: FloatArray) -> Location:
    """A 4x4 transform as a world location (mm, z-y-x degrees)."""
    z, y, x = zyx_deg_of(Rotation.from_matrix(np.array(pose[:3, :3])))
    px, py, pz = (float(v) for v in pose[:3, 3])
    return (px, py, pz, float(z), float(y), float(x))


def shift_location(location: Sequence[float], offset: Sequence[float]) -> Location:
    """`wshift` (module docstring): turned by the offset's z-y-x rotation in the world frame
    about the location's own position, then moved by its translation."""
    pose = pose_of(location)
    turn = Rotation.from_euler("ZYX", list(offset[3:6]), degrees=True).as_matrix()
    pose[:3, :3] = turn @ pose[:3, :3]
    pose[:3, 3] += np.asarray(offset[:3], dtype=np.float64)
    return location_of(pose)


@dataclass(eq=False)
class JointArm:
    """The emulated arm: its motions and where its joints are at any time of the clock."""

    config: JointArmConfig
    _history: deque[_Motion] = field(init=False)
    #: the motions' start times, for a bisection (a truth integrating a played cycle samples
    #: hundreds of motions back); False once a halt made them non-monotonic: a scan then
    _starts: deque[float] = field(init=False)
    _sorted: bool = field(init=False, default=True)
    _commanded_q: FloatArray = field(init=False)
    _solutions: dict[tuple[float, ...], FloatArray] = field(init=False, default_factory=dict)

    def __post_init__(self) -> None:
        q = np.radians(np.asarray(self.config.start_joints_deg, dtype=np.float64))
        self._history = deque([trapezoid(q, q, 0.0, 1.0, 1.0)], maxlen=MOTION_HISTORY)
        self._starts = deque([0.0], maxlen=MOTION_HISTORY)
        self._commanded_q = q.copy()

    @property
    def arm(self) -> Arm:
        return self.config.arm

    @property
    def _last(self) -> _Motion:
        return self._history[-1]

    def joints_at(self, t_s: float) -> FloatArray:
        return self._motion_at(t_s).sample(t_s)[0]

    def _motion_at(self, t_s: float) -> _Motion:
        if self._sorted:  # the latest motion started at or before t_s
            return self._history[max(bisect.bisect_right(self._starts, t_s) - 1, 0)]
        for motion in reversed(self._history):
            if motion.start_s <= t_s:
                return motion
        return self._history[0]

    def sample(self, t_s: float) -> JointSample:
        """Joint positions (rad), speeds (rad/s) and accelerations (rad/s^2) at ``t_s``."""
        q, qd, qdd = self._motion_at(t_s).sample(t_s)
        return JointSample(time_s=t_s, q_rad=q, qd_rad_s=qd, qdd_rad_s2=qdd)

    def location_at(self, t_s: float) -> Location:
        return location_of(forward(self.arm, self.joints_at(t_s)))

    @property
    def commanded_joints(self) -> FloatArray:
        """The joints the latest motion was commanded to (before positioning noise)."""
        return self._commanded_q.copy()

    def end_s(self) -> float:
        return self._last.end_s

    def last_start_s(self) -> float:
        """When the latest motion started (its end: :meth:`end_s`)."""
        return self._last.start_s

    def move_to(
        self,
        target: Sequence[float],
        now_s: float,
        noise_mm: FloatArray,
        *,
        speed_percent: int = REFERENCE_SPEED_PERCENT,
    ) -> float:
        """Start a motion to the world location ``target`` at ``now_s`` (after the current one
        has ended: callers `finish` first); the arm arrives off the target by ``noise_mm`` in
        world x, y, z (repeatability), turned into joint angles through the Jacobian's
        pseudo-inverse, at the console's speed setting ``speed_percent`` (JointArmConfig.
        limits_rad). Returns when the motion ends; UnreachableError when it cannot."""
        start_s = max(now_s, self._last.end_s)
        q_now = self.joints_at(start_s)
        q_target = self.solve(target, q_now)
        q_actual = q_target
        if np.any(noise_mm):
            dq = np.linalg.pinv(jacobian(self.arm, q_target)[:3]) @ noise_mm
            q_actual = np.clip(q_target + dq, self.arm.lower_rad, self.arm.upper_rad)
        config = self.config
        if (
            config.max_speed_deg_s is None
            and config.max_accel_deg_s2 is None
            and speed_percent == REFERENCE_SPEED_PERCENT
        ):  # the emulator of before, to the bit
            motion = trapezoid(
                q_now,
                q_actual,
                start_s,
                math.radians(config.speed_deg_s),
                math.radians(config.acceleration_deg_s2),
            )
        else:
            speed, acceleration = config.limits_rad(speed_percent)
            motion = synchronised(q_now, q_actual, start_s, speed, acceleration)
        self._append(motion)
        self._commanded_q = q_target
        return motion.end_s

    def move_joints(
        self,
        q_target: FloatArray,
        now_s: float,
        speed_rad_s: FloatArray,
        accel_rad_s2: FloatArray,
    ) -> float:
        """Start a joint-space motion to ``q_target`` (rad) at ``now_s`` (after the current one
        has ended), synchronised under per-joint limits (a UR program's `movej` between taught
        joint positions: no inverse kinematics). Returns when the motion ends."""
        start_s = max(now_s, self._last.end_s)
        q_now = self.joints_at(start_s)
        target = np.asarray(q_target, dtype=np.float64)
        motion = synchronised(q_now, target, start_s, speed_rad_s, accel_rad_s2)
        self._append(motion)
        self._commanded_q = target.copy()
        return motion.end_s

    def solve(self, target: Sequence[float], q_now: FloatArray) -> FloatArray:
        """The joints of the world location ``target`` from ``q_now``: on ``q_now``'s branch;
        at the wrist singularity (of the solution, or of ``q_now`` when no exact solution is
        found) with the first wrist joint kept where it is (module docstring).
        UnreachableError when no solution is within the tolerances."""
        arm, pose = self.arm, pose_of(target)
        key = tuple(float(v) for v in target)
        exact: FloatArray | None = self._solutions.get(key)
        failure: ArmError | None = None
        if exact is None:
            try:
                exact = inverse(arm, pose, q_now, restarts=0)
            except ArmError as err:
                failure = err
            if needs_branch_search(arm, pose, q_now, exact):  # module docstring
                exact = nearest_solution(arm, pose, q_now, exact)
            if exact is not None and self.config.cache_solutions:
                if len(self._solutions) >= SOLUTION_CACHE:
                    self._solutions.clear()
                self._solutions[key] = exact
        seed = q_now if exact is None else exact
        if wrist_singular(arm, seed):
            locked = wrist_locked_inverse(arm, pose, seed, q_now)
            if locked is not None:
                return locked
        if exact is None:
            raise UnreachableError(str(failure)) from failure
        return exact.copy()

    def halt(self, now_s: float) -> None:
        """Stop the motion in progress where the arm is at ``now_s``."""
        if now_s < self._last.end_s:
            self._append(self._motion_at(now_s).halted_at(now_s))

    def _append(self, motion: _Motion) -> None:
        if motion.start_s < self._starts[-1]:
            self._sorted = False
        self._history.append(motion)
        self._starts.append(motion.start_s)

    def pulses(self, q_rad: FloatArray) -> tuple[int, ...]:
        """The `PULSES` row: joint degrees x pulses per degree (ESTIMATED, see the constant)."""
        per_deg = self.config.pulses_per_deg or (ESTIMATED_A465_PULSES_PER_DEG,) * q_rad.size
        return tuple(round(math.degrees(q) * p) for q, p in zip(q_rad, per_deg, strict=True))
