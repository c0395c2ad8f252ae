"""A followed run's motor heat from the motion the robot actually made (issue 31, arm.heat_from
``measured``).

The robot plays its own program: paused (the Dashboard, a protective stop), slowed (the speed
slider) or waiting, it does not make the taught duty cycle's motion, and the duty cycle's heat
(daemon/arm/heat.py JointHeatProfile) would heat the model where the arm rested. Instead each
step drains the driver's log of every state package's joints, speeds and accelerations
(drivers/ur/motion.py), computes each package's heat with the arm's motor model -- the very
function the duty cycle's heat is integrated with (daemon/arm/motors.py
``joint_heat_batch_w``: the same arm file, motors and payload, so the model's heat factors keep
their meaning) -- integrates it between packages (daemon/arm/heat.py HeatMeter, the trapezoid
rule) and holds the step's mean over the model's advance (:class:`RecordedHeat`, the
controller's HeatSource). A package at rest heats by the copper loss of holding the arm
against gravity (the motors hold a paused UR; a real controller's brakes engage only when it
powers the arm off, not modelled).

A gap in the packages (the driver's log keeps drivers/ur/motion.py KEEP_S, 10 s: a run held
longer, whose program the hold paused) holds the heat of the first package after it: the arm's
state when the run resumes (at rest, on a program paused by the hold), not a ramp from the
motion before it.

The step's heat is recorded (``heat_json``: the model's interval and each joint's mean W), and
``calibrate model`` on a followed run reads it back into the same :class:`RecordedHeat`
(daemon/commands/followed_identify.py), so identification sees the heat the run saw.
"""

from __future__ import annotations

import bisect
import json
import math
from collections.abc import Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np

from daemon.arm.controller import ArmController
from daemon.arm.description import Arm
from daemon.arm.heat import HeatMeter, HeatSource
from daemon.arm.motors import arm_motors, joint_heat_batch_w
from daemon.arm.types import FloatArray
from drivers.ur.motion import MotionSamples

MEASURED = "measured"
DUTY_CYCLE = "duty-cycle"
#: The segments a live run keeps (its model only asks for the last one, the adaptation for
#: the last ADAPTATION_STEP_S): 4096 steps of 0.1 s, 7 minutes.
LIVE_SEGMENTS = 4096
#: Packages further apart than this (s of the controller's clock) leave a gap: the heat over it
#: is the later package's (MeasuredHeat.add).
GAP_S = 1.0
#: Two intervals' ends closer than this (s of arm time) are the same instant.
SAME_TIME_S = 1e-9


@runtime_checkable
class MotionFeed(Protocol):
    """A robot that logs the motion it makes (drivers/ur/robot.py URRobot.take_motion)."""

    def take_motion(self) -> MotionSamples: ...


class RecordedHeat:
    """Each joint's heat as a run held it: a mean power (W per joint) over each interval of arm
    time the run recorded, contiguous or not; over time no interval covers, ``fallback``'s (the
    duty cycle's: a gap in the record, e.g. a daemon restart). A HeatSource
    (daemon/arm/heat.py). ``keep``: the most intervals kept (a live run's; None: all)."""

    def __init__(self, fallback: HeatSource, joints: int, keep: int | None = None) -> None:
        self.fallback = fallback
        self.joints = joints
        self._keep = keep
        self._starts: list[float] = []
        self._ends: list[float] = []
        self._powers: list[FloatArray] = []

    def __len__(self) -> int:
        return len(self._starts)

    def hold(self, start_s: float, end_s: float, power_w: Sequence[float] | FloatArray) -> None:
        """Over ``[start_s, end_s]`` the joints released ``power_w`` on average; intervals come
        in time order (one that starts before the last one's end is a ValueError)."""
        power = np.asarray(power_w, dtype=np.float64).reshape(-1)
        if power.size != self.joints or not np.all(np.isfinite(power)):
            raise ValueError(f"expected {self.joints} finite joint powers, got {power_w!r}")
        if not end_s > start_s:
            raise ValueError(f"empty interval [{start_s}, {end_s}] s")
        if self._ends and start_s < self._ends[-1] - SAME_TIME_S:
            raise ValueError(f"interval from {start_s} s before the last one's end")
        self._starts.append(start_s)
        self._ends.append(end_s)
        self._powers.append(power)
        if self._keep is not None and len(self._starts) > 2 * self._keep:
            del self._starts[: self._keep], self._ends[: self._keep], self._powers[: self._keep]

    @property
    def covered_s(self) -> float:
        """Arm time the intervals kept cover (s)."""
        return float(sum(end - start for start, end in zip(self._starts, self._ends, strict=True)))

    def step_power_w(self, t0_s: float, t1_s: float) -> FloatArray:
        """Mean heat per joint over ``[t0_s, t1_s]`` (W): the recorded intervals' powers where
        they cover it, the fallback's elsewhere."""
        if not t1_s > t0_s:
            raise ValueError(f"empty interval [{t0_s}, {t1_s}] s")
        ends, starts = self._ends, self._starts
        last = len(starts) - 1
        # the live run's model asks for exactly the interval it just held
        if (
            last >= 0
            and abs(starts[last] - t0_s) < SAME_TIME_S
            and abs(ends[last] - t1_s) < SAME_TIME_S
        ):
            return self._powers[last].copy()
        energy = np.zeros(self.joints)
        cursor = t0_s
        k = bisect.bisect_right(ends, t0_s)
        while k < len(starts) and starts[k] < t1_s:
            lo, hi = max(starts[k], t0_s), min(ends[k], t1_s)
            if hi > lo:
                if lo > cursor:  # a gap before this interval
                    energy += self.fallback.step_power_w(cursor, lo) * (lo - cursor)
                energy += self._powers[k] * (hi - lo)
                cursor = hi
            k += 1
        if t1_s > cursor:
            energy += self.fallback.step_power_w(cursor, t1_s) * (t1_s - cursor)
        result: FloatArray = energy / (t1_s - t0_s)
        return result


class MeasuredHeat:
    """The heat of the packages' motion (module docstring): :meth:`add` each step's packages,
    :meth:`take_mean_w` the mean heat per joint since the last take (W), for the step's
    advance. Owned by the followed run's model (its worker)."""

    def __init__(self, arm: Arm, payload_kg: float) -> None:
        self.arm = arm
        self.payload_kg = payload_kg
        self._motors = arm_motors(arm)
        self.joints = len(arm.joints)
        self._meter = HeatMeter(self.joints)
        self._last_time: float | None = None
        self.packages = 0
        #: times the controller's clock went back (a restarted controller): the meter restarted
        self.clock_resets = 0
        #: gaps of more than GAP_S between two packages (module docstring)
        self.gaps = 0

    def add(self, samples: MotionSamples) -> None:
        if len(samples) == 0:
            return
        power = joint_heat_batch_w(
            self.arm,
            samples.q_rad,
            samples.qd_rad_s,
            samples.qdd_rad_s2,
            motors=self._motors,
            payload_kg=self.payload_kg,
        )
        for t, row in zip(samples.times_s, power, strict=True):
            time_s = float(t)
            last = self._last_time
            if last is not None and time_s < last:
                # a new controller clock: the heat since its start is this package's onwards
                self.clock_resets += 1
                self._meter = HeatMeter(self.joints)
            elif last is not None and time_s - last > GAP_S:
                # packages lost (the driver's log keeps KEEP_S: a run held longer, its program
                # paused on the hold): the gap holds this package's heat, not a ramp to it
                self.gaps += 1
                self._meter.add(last, row)
            self._meter.add(time_s, row)
            self._last_time = time_s
        self.packages += len(samples)

    def take_mean_w(self) -> FloatArray | None:
        """The mean heat per joint since the last take (the last package's when the robot's
        clock has not moved), or None before the first package."""
        if self._last_time is None:
            return None
        return self._meter.take_mean_w()


def heat_json(start_s: float, end_s: float, power_w: FloatArray, source: str) -> str:
    """A step's ``heat_json``: the model's interval (s of arm time), each joint's mean heat
    over it (W, before any identified factor) and where it came from."""
    return json.dumps(
        {
            "from_s": round(start_s, 6),
            "to_s": round(end_s, 6),
            "joint_w": [round(float(v), 6) for v in power_w],
            "source": source,
        }
    )


def parse_heat_json(text: str | None, joints: int) -> tuple[float, float, FloatArray] | None:
    """A recorded step's heat interval and powers, or None (no heat recorded, or not readable:
    the reader falls back to the duty cycle's for that time)."""
    if not text:
        return None
    try:
        value: Any = json.loads(text)
        start, end = float(value["from_s"]), float(value["to_s"])
        power = np.array([float(v) for v in value["joint_w"]], dtype=np.float64)
    except (ValueError, TypeError, KeyError):
        return None
    if power.size != joints or not np.all(np.isfinite(power)) or not math.isfinite(start):
        return None
    if not (math.isfinite(end) and end > start):
        return None
    return start, end, power


__all__ = [
    "DUTY_CYCLE",
    "GAP_S",
    "LIVE_SEGMENTS",
    "MEASURED",
    "FollowedHeat",
    "MeasuredHeat",
    "MotionFeed",
    "RecordedHeat",
    "heat_json",
    "parse_heat_json",
]


class FollowedHeat:
    """A followed run's measured heat (module docstring): the robot's motion log, the heat of
    its packages and the record the model's controller reads its heat from.
    :meth:`on` makes the record ``controller``'s heat source (the duty cycle's as fallback).
    ``feed`` None: the caller passes the packages to :meth:`hold` itself (a replay)."""

    def __init__(
        self, feed: MotionFeed | None, measured: MeasuredHeat, record: RecordedHeat
    ) -> None:
        self.feed = feed
        self.measured = measured
        self.record = record

    @classmethod
    def on(
        cls, controller: ArmController, feed: MotionFeed | None, keep: int | None = LIVE_SEGMENTS
    ) -> FollowedHeat:
        record = RecordedHeat(controller.heat, len(controller.arm.joints), keep=keep)
        controller.heat = record
        measured = MeasuredHeat(controller.arm, controller.duty.payload_kg)
        return cls(feed, measured, record)

    def take(self) -> MotionSamples:
        """The packages since the last take (on the event loop: the driver's log is its)."""
        return MotionSamples.empty() if self.feed is None else self.feed.take_motion()

    def hold(self, samples: MotionSamples, start_s: float, end_s: float) -> str | None:
        """On the model's worker, before its advance from ``start_s`` to ``end_s``: the
        packages' heat into the record for that interval; the step's ``heat_json``, or None
        before the first package (the duty cycle's heat holds: RecordedHeat's fallback)."""
        self.measured.add(samples)
        if not end_s > start_s:
            return None
        power = self.measured.take_mean_w()
        if power is None:
            return None
        self.record.hold(start_s, end_s, power)
        return heat_json(start_s, end_s, power, MEASURED)

    def summary(self) -> dict[str, Any]:
        return {
            "from": MEASURED,
            "packages": self.measured.packages,
            "clock_resets": self.measured.clock_resets,
            "gaps": self.measured.gaps,
        }
