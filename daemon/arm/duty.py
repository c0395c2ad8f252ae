"""Duty cycles (issue 20): a program of taught poses the arm repeats for hours, with a speed
and acceleration per move and a dwell at each pose; the motion heats the joints' motors.

A cycle starts at rest at its first pose: dwell there, move to the next pose, dwell, ... and
move back to the first. Each move is a synchronised trapezoidal joint-space profile
(Craig, *Introduction to Robotics*, 3rd ed., Sec. 7.3 "linear function with parabolic
blends"; Biagiotti & Melchiorri, *Trajectory Planning for Automatic Machines and Robots*,
2008, Sec. 3.2 and 5.1 for the synchronisation): every joint follows the same normalised
profile ``s(t)`` from 0 to 1, ``q = q_from + (q_to - q_from) s(t)``, whose speed and
acceleration limits are the tightest of the joints' (``v_j / |dq_j|``, ``a_j / |dq_j|``), so
all joints start and stop together and none exceeds its limits; a short move that cannot
reach the speed limit is triangular.

The file (TOML; ``config/duty/`` holds presets)::

    name = "a465-pick-and-place"
    arm = "crs-a465"                       # the arm it was taught on (tool poses need it)
    max_speed_deg_s = [180, 180, 180, 170, 170, 225]   # per joint, or one number
    max_accel_deg_s2 = [360, 360, 360, 340, 340, 450]
    payload_kg = 1.0                       # at the tool point: gripper + part (default 0)

    [[poses]]
    name = "pick"
    joints_deg = [0, 30, 60, 0, 30, 0]     # or tool_mm = [x, y, z] + tool_zyx_deg = [z, y, x]
    speed = 0.8                            # fraction of the limits for the move INTO it
    accel = 0.8
    dwell_s = 0.5
    measure = true                         # the tool is measured and corrected here
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from numpy.typing import ArrayLike
from pydantic import BaseModel, ConfigDict, Field, StrictBool, ValidationError

from config.inputs import InputError, no_such_name
from config.settings import read_toml
from daemon.arm.description import MAX_ARM_JOINTS, Arm
from daemon.arm.kinematics import inverse
from daemon.arm.types import FloatArray, JointSample

PRESET_PACKAGE = "config"
PRESET_FOLDER = "duty"
#: A remainder of time below this (s) is rounding, not a new step.
TIME_TOLERANCE_S = 1e-9
#: Samples evaluated per batch by :meth:`DutyCycle.samples`.
BATCH = 4096

#: Solves a tool pose (4x4, base frame, mm) for joint angles near a seed (rad).
InverseKinematics = Callable[[FloatArray, FloatArray], FloatArray]


class DutyCycleError(InputError):
    """An invalid duty cycle; the message names the file and the pose."""


@dataclass(frozen=True, slots=True)
class TaughtPose:
    """One pose of the program: joint angles (rad), the speed and acceleration fractions of
    the move into it, its dwell, and whether the tool is measured and corrected there."""

    name: str
    q_rad: tuple[float, ...]
    speed: float = 1.0
    accel: float = 1.0
    dwell_s: float = 0.0
    measure: bool = False


@dataclass(frozen=True, slots=True)
class _Move:
    """One synchronised trapezoid from ``start`` to ``start + delta`` beginning at ``t0``."""

    t0: float
    duration: float
    blend: float  # acceleration time
    peak: float  # normalised peak speed (1/s)
    start: FloatArray
    delta: FloatArray


def trapezoid_timing(distance: float, speed: float, accel: float) -> tuple[float, float, float]:
    """(duration, acceleration time, peak speed) of a rest-to-rest trapezoid over
    ``distance`` with limits ``speed`` and ``accel`` (triangular when the limit speed is not
    reached: ``distance < speed^2 / accel``)."""
    if distance <= 0.0:
        return 0.0, 0.0, 0.0
    if distance >= speed**2 / accel:
        blend = speed / accel
        return distance / speed + blend, blend, speed
    blend = math.sqrt(distance / accel)
    return 2.0 * blend, blend, accel * blend


def _profile(
    t: FloatArray, duration: FloatArray, blend: FloatArray, peak: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Normalised position, speed and acceleration of trapezoids at local times ``t``, each
    time its own trapezoid (elementwise; a move that does not move has duration 0)."""
    accel = np.divide(peak, blend, out=np.zeros_like(peak), where=blend > 0.0)
    t = np.clip(t, 0.0, duration)
    rising, falling = t < blend, t > duration - blend
    late = duration - t
    s = np.where(
        rising,
        0.5 * accel * t**2,
        np.where(falling, 1.0 - 0.5 * accel * late**2, peak * (t - blend / 2.0)),
    )
    sd = np.where(rising, accel * t, np.where(falling, accel * late, peak))
    sdd = np.where(rising, accel, np.where(falling, -accel, 0.0))
    ends = (duration > 0.0) & ((t <= 0.0) | (t >= duration))  # exactly at rest at both ends
    return s, np.where(ends, 0.0, sd), np.where(ends, 0.0, sdd)


@dataclass(frozen=True, eq=False)
class DutyCycle:
    """A periodic program of taught poses (module docstring). ``max_speed_rad_s`` and
    ``max_accel_rad_s2`` are the per-joint limits the poses' fractions scale."""

    name: str
    poses: tuple[TaughtPose, ...]
    max_speed_rad_s: tuple[float, ...]
    max_accel_rad_s2: tuple[float, ...]
    arm: str = ""
    description: str = ""
    payload_kg: float = 0.0  # carried at the tool point (gripper + part)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.payload_kg) and self.payload_kg >= 0.0):
            raise DutyCycleError(f"payload must be >= 0 kg, got {self.payload_kg}")
        if len(self.poses) < 2:
            raise DutyCycleError(f"duty cycle {self.name!r} needs at least two poses")
        joints = len(self.max_speed_rad_s)
        if len(self.max_accel_rad_s2) != joints:
            raise DutyCycleError("max speed and max acceleration need one value per joint")
        for value in (*self.max_speed_rad_s, *self.max_accel_rad_s2):
            if not (math.isfinite(value) and value > 0.0):
                raise DutyCycleError(f"speed and acceleration limits must be > 0, got {value}")
        for pose in self.poses:
            if len(pose.q_rad) != joints:
                raise DutyCycleError(
                    f"pose {pose.name!r}: {len(pose.q_rad)} joint angles for {joints} joints"
                )
            if not (0.0 < pose.speed <= 1.0 and 0.0 < pose.accel <= 1.0):
                raise DutyCycleError(f"pose {pose.name!r}: speed and accel must be in (0, 1]")
            if not (math.isfinite(pose.dwell_s) and pose.dwell_s >= 0.0):
                raise DutyCycleError(f"pose {pose.name!r}: dwell must be >= 0 s")
        object.__setattr__(self, "_moves", self._plan())

    @property
    def joint_count(self) -> int:
        return len(self.max_speed_rad_s)

    def _plan(self) -> tuple[_Move, ...]:
        """Dwell at pose i, then move to pose i+1 (the last back to the first)."""
        speed = np.array(self.max_speed_rad_s)
        accel = np.array(self.max_accel_rad_s2)
        moves = []
        t = 0.0
        for i, pose in enumerate(self.poses):
            target = self.poses[(i + 1) % len(self.poses)]
            start = np.array(pose.q_rad)
            delta = np.array(target.q_rad) - start
            t += pose.dwell_s
            moving = np.abs(delta) > 0.0
            if moving.any():
                span = np.abs(delta[moving])
                duration, blend, peak = trapezoid_timing(
                    1.0,
                    float(np.min(target.speed * speed[moving] / span)),
                    float(np.min(target.accel * accel[moving] / span)),
                )
            else:
                duration, blend, peak = 0.0, 0.0, 0.0
            moves.append(_Move(t, duration, blend, peak, start, delta))
            t += duration
        return tuple(moves)

    @property
    def moves(self) -> tuple[_Move, ...]:
        result: tuple[_Move, ...] = self.__dict__["_moves"]
        return result

    @property
    def period_s(self) -> float:
        last = self.moves[-1]
        return last.t0 + last.duration

    def arrival_times_s(self) -> tuple[float, ...]:
        """When the arm arrives at (is at rest at) each pose within a cycle; the first pose's
        arrival is the cycle's start, 0."""
        times = [0.0]
        times.extend(move.t0 + move.duration for move in self.moves[:-1])
        return tuple(times)

    def measured_poses(self) -> tuple[TaughtPose, ...]:
        """The poses measured, each name once (its first visit): a program that visits a
        camera station many times per cycle (daemon/arm/calibration_program.py) has one
        station there, not one per visit."""
        seen: dict[str, TaughtPose] = {}
        for pose in self.poses:
            if pose.measure and pose.name not in seen:
                seen[pose.name] = pose
        return tuple(seen.values())

    def state(self, times_s: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Joint positions, speeds and accelerations (rows: times; columns: joints) at any
        times (the cycle repeats)."""
        times = np.atleast_1d(np.asarray(times_s, dtype=np.float64))
        local = np.mod(times, self.period_s)
        moves = self.moves
        starts = np.array([move.t0 for move in moves])
        # The move whose dwell-then-motion window holds each time (dwell i precedes move i).
        index = np.clip(np.searchsorted(starts, local, side="right") - 1, 0, len(moves) - 1)
        before_first = local < starts[0]
        # Every time's trapezoid at once, its move's parameters gathered by index: a
        # calibration program (calibration_program.py) has thousands of moves and a period of
        # a million motion samples; a loop over the moves with a mask over every time each was
        # O(moves x samples), minutes per cycle.
        s, sd, sdd = _profile(
            local - starts[index],
            np.array([move.duration for move in moves])[index],
            np.array([move.blend for move in moves])[index],
            np.array([move.peak for move in moves])[index],
        )
        delta = np.array([move.delta for move in moves])[index]
        q = np.array([move.start for move in moves])[index] + s[:, None] * delta
        qd = sd[:, None] * delta
        qdd = sdd[:, None] * delta
        q[before_first] = np.array(self.poses[0].q_rad)  # dwell at the first pose
        qd[before_first] = 0.0
        qdd[before_first] = 0.0
        return q, qd, qdd

    def samples(self, dt_s: float, duration_s: float | None = None) -> Iterator[JointSample]:
        """The motion on a fixed step: times ``0, dt, 2 dt, ...`` up to ``duration_s``
        (inclusive; default one period), periodic beyond one cycle."""
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise DutyCycleError(f"dt must be a positive number of seconds, got {dt_s}")
        end = self.period_s if duration_s is None else duration_s
        count = math.floor(end / dt_s + TIME_TOLERANCE_S) + 1
        for first in range(0, count, BATCH):
            times = np.arange(first, min(count, first + BATCH)) * dt_s
            q, qd, qdd = self.state(times)
            for k, t in enumerate(times):
                yield JointSample(float(t), q[k], qd[k], qdd[k])

    def cycle_energy_j(
        self, power_w: Callable[[FloatArray, FloatArray, FloatArray], FloatArray], dt_s: float
    ) -> FloatArray:
        """The energy (J, per joint) of ``power_w(q, qd, qdd)`` (rows: samples) over one cycle,
        by the midpoint rule on ``dt_s``; e.g. each joint's motor heat per cycle."""
        steps = max(1, math.ceil(self.period_s / dt_s))
        h = self.period_s / steps
        q, qd, qdd = self.state((np.arange(steps) + 0.5) * h)
        energy: FloatArray = np.asarray(power_w(q, qd, qdd), np.float64).sum(axis=0) * h
        return energy


# -- files ------------------------------------------------------------------------------------


#: Bounds of a duty cycle file (issue 26: ``dwell_s = 1e308`` crashed the planner): far beyond
#: any program, low enough that no time, sample count or energy computed from them overflows.
#: A calibration program lists every visit (the A465's: 3,493 poses per period), hence 10,000.
MAX_POSES = 10_000
MAX_DWELL_S = 86_400.0  # a day at one pose
MAX_JOINT_DEG = 3_600.0  # a multi-turn joint
MAX_SPEED_DEG_S = 10_000.0
MAX_ACCEL_DEG_S2 = 1_000_000.0
MAX_PAYLOAD_KG = 10_000.0
MAX_TOOL_MM = 100_000.0

JointAngle = Annotated[float, Field(ge=-MAX_JOINT_DEG, le=MAX_JOINT_DEG)]
Speed = Annotated[float, Field(gt=0.0, le=MAX_SPEED_DEG_S)]
Accel = Annotated[float, Field(gt=0.0, le=MAX_ACCEL_DEG_S2)]
ToolLength = Annotated[float, Field(ge=-MAX_TOOL_MM, le=MAX_TOOL_MM)]
ToolAngle = Annotated[float, Field(ge=-360.0, le=360.0)]


class _Strict(BaseModel):
    # allow_inf_nan=False: TOML's nan and inf are refused naming the field
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class _Pose(_Strict):
    name: str
    joints_deg: Annotated[tuple[JointAngle, ...], Field(max_length=MAX_ARM_JOINTS)] | None = None
    tool_mm: tuple[ToolLength, ToolLength, ToolLength] | None = None
    tool_zyx_deg: tuple[ToolAngle, ToolAngle, ToolAngle] = (0.0, 0.0, 0.0)
    speed: float = Field(default=1.0, gt=0.0, le=1.0)
    accel: float = Field(default=1.0, gt=0.0, le=1.0)
    dwell_s: float = Field(default=0.0, ge=0.0, le=MAX_DWELL_S)
    measure: StrictBool = False


class _DutyFile(_Strict):
    name: str | None = None
    description: str = ""
    arm: str = ""
    max_speed_deg_s: Speed | Annotated[tuple[Speed, ...], Field(max_length=MAX_ARM_JOINTS)]
    max_accel_deg_s2: Accel | Annotated[tuple[Accel, ...], Field(max_length=MAX_ARM_JOINTS)]
    payload_kg: float = Field(default=0.0, ge=0.0, le=MAX_PAYLOAD_KG)
    poses: tuple[_Pose, ...]


def _arm_key(text: str) -> str:
    return "".join(ch for ch in text.lower() if ch.isalnum())


def check_taught_on(duty: DutyCycle, arm: Arm, arm_file: str | Path) -> None:
    """A duty cycle's poses are joint angles of the arm it was taught on (``arm = "..."`` in
    its file): on another arm they are other tool poses, and the run would correct the wrong
    thing (issue 26: a UR5e cycle ran on the A465). It fits when it names the arm file's preset
    (``crs-a465``, or a variant of it such as ``ur5e`` for ``ur5e-urdf``) or the arm's name
    (``CRS A465``), case and punctuation aside; a cycle that names no arm fits any arm with its
    number of joints."""
    if duty.joint_count != len(arm.joints):
        raise DutyCycleError(
            f"duty cycle {duty.name!r} has {duty.joint_count} joints, arm {arm.name!r} has "
            f"{len(arm.joints)}: give a duty cycle of this arm"
        )
    if not duty.arm:
        return
    taught = _arm_key(duty.arm)
    preset = _arm_key(Path(str(arm_file)).stem)
    if taught in (preset, _arm_key(arm.name)) or (taught and preset.startswith(taught)):
        return
    raise DutyCycleError(
        f"duty cycle {duty.name!r} was taught on arm {duty.arm!r}, this arm is "
        f"{Path(str(arm_file)).stem!r} ({arm.name}): give a duty cycle of this arm, or set "
        "arm.arm_file to the arm it was taught on"
    )


def duty_dir() -> Path:
    return Path(str(resources.files(PRESET_PACKAGE).joinpath(PRESET_FOLDER)))


def available_duty_cycles() -> list[str]:
    return sorted(path.stem for path in duty_dir().glob("*.toml"))


def tool_pose_matrix(tool_mm: Sequence[float], zyx_deg: Sequence[float]) -> FloatArray:
    """4x4 pose from a position (mm) and the console's z-y-x angles (deg;
    docs/reference/c500c-console.md)."""
    from scipy.spatial.transform import Rotation

    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("ZYX", list(zyx_deg), degrees=True).as_matrix()
    pose[:3, 3] = tool_mm
    return pose


def arm_inverse(arm: Arm) -> InverseKinematics:
    """The arm's inverse kinematics (``kinematics.inverse``) for tool poses in a duty file."""

    def solve(pose: FloatArray, seed: FloatArray) -> FloatArray:
        return inverse(arm, pose, seed)

    return solve


def duty_cycle_from_mapping(
    data: dict[str, Any],
    default_name: str = "duty",
    inverse: InverseKinematics | None = None,
    seed_rad: Sequence[float] | None = None,
) -> DutyCycle:
    """The duty cycle a parsed TOML document describes. Tool poses need ``inverse``
    (``kinematics.inverse`` of the arm), seeded with the previous pose's joints (the first
    with ``seed_rad``, default zeros)."""
    given = data.get("poses")
    if isinstance(given, list) and len(given) > MAX_POSES:  # said before each is checked
        raise DutyCycleError(f"poses: {len(given)} poses: at most {MAX_POSES}")
    try:
        spec = _DutyFile.model_validate(data)
    except ValidationError as err:
        problems = "; ".join(
            ".".join(str(p) for p in e["loc"]) + f": {e['msg']}" for e in err.errors()
        )
        raise DutyCycleError(problems) from err
    joints = next(
        (len(p.joints_deg) for p in spec.poses if p.joints_deg is not None),
        len(spec.max_speed_deg_s) if isinstance(spec.max_speed_deg_s, tuple) else 0,
    )
    if joints == 0:
        raise DutyCycleError("give per-joint limits or at least one pose in joints_deg")

    def per_joint(value: float | tuple[float, ...], what: str) -> tuple[float, ...]:
        values = (value,) * joints if isinstance(value, float | int) else tuple(value)
        if len(values) != joints:
            raise DutyCycleError(f"{what}: {len(values)} values for {joints} joints")
        return tuple(math.radians(v) for v in values)

    seed = np.zeros(joints) if seed_rad is None else np.asarray(seed_rad, np.float64)
    poses = []
    for pose in spec.poses:
        if (pose.joints_deg is None) == (pose.tool_mm is None):
            raise DutyCycleError(f"pose {pose.name!r}: give joints_deg or tool_mm (one of them)")
        if pose.joints_deg is not None:
            q = np.radians(pose.joints_deg)
        else:
            if inverse is None:
                raise DutyCycleError(f"pose {pose.name!r}: a tool pose needs the arm's kinematics")
            assert pose.tool_mm is not None
            try:
                q = np.asarray(inverse(tool_pose_matrix(pose.tool_mm, pose.tool_zyx_deg), seed))
            except ValueError as err:
                raise DutyCycleError(f"pose {pose.name!r}: {err}") from err
        seed = q
        poses.append(
            TaughtPose(
                name=pose.name,
                q_rad=tuple(float(v) for v in q),
                speed=pose.speed,
                accel=pose.accel,
                dwell_s=pose.dwell_s,
                measure=pose.measure,
            )
        )
    return DutyCycle(
        name=spec.name or default_name,
        poses=tuple(poses),
        max_speed_rad_s=per_joint(spec.max_speed_deg_s, "max_speed_deg_s"),
        max_accel_rad_s2=per_joint(spec.max_accel_deg_s2, "max_accel_deg_s2"),
        arm=spec.arm,
        description=spec.description,
        payload_kg=spec.payload_kg,
    )


def load_duty_cycle(
    name_or_path: str | Path,
    inverse: InverseKinematics | None = None,
    seed_rad: Sequence[float] | None = None,
) -> DutyCycle:
    """A preset by name (``"a465-pick-and-place"``) or a TOML file by path."""
    text = str(name_or_path)
    path = Path(text)
    if not (text.endswith(".toml") or path.is_file()):
        path = duty_dir() / f"{text}.toml"
        if not path.is_file():
            presets = available_duty_cycles()
            listed = f"presets: {', '.join(presets) or 'none'}; or a TOML file"
            raise DutyCycleError(no_such_name("duty cycle", text, presets, listed))
    data = read_toml(path, DutyCycleError)
    try:
        return duty_cycle_from_mapping(data, path.stem, inverse, seed_rad)
    except DutyCycleError as err:
        raise DutyCycleError(f"{path}: {err}") from err


__all__ = [
    "DutyCycle",
    "DutyCycleError",
    "TaughtPose",
    "arm_inverse",
    "available_duty_cycles",
    "check_taught_on",
    "duty_cycle_from_mapping",
    "load_duty_cycle",
    "tool_pose_matrix",
    "trapezoid_timing",
]
