"""The heat a duty cycle releases in each joint, over any interval of time (issue 20).

A thermal model stepped every ``dt`` holds each joint's heat constant over the step
(zero-order hold); the right constant is the step's mean power, not the power at one instant
(a 1 s step would alias a 7 s cycle's short moves). :class:`JointHeatProfile` integrates the
heat of one cycle once, finely, into a cumulative energy per joint; the energy up to any time
is whole cycles plus a linear interpolation in that table, so the mean power over any step is
a subtraction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from daemon.arm.description import Arm
from daemon.arm.duty import DutyCycle
from daemon.arm.motors import MotorTable, arm_motors, joint_heat_batch_w
from daemon.arm.types import FloatArray

#: Default integration step of one cycle's heat (s): a few per acceleration ramp.
DEFAULT_RESOLUTION_S = 0.005


class HeatSource(Protocol):
    """Where a model's motor heat comes from: the mean heat per joint over an interval of arm
    time (W). :class:`JointHeatProfile` (a duty cycle's commanded motion), or the heat of the
    motion a robot actually made (a followed run: daemon/run/followed/heat.py)."""

    def step_power_w(self, t0_s: float, t1_s: float) -> FloatArray: ...


@dataclass(frozen=True, eq=False)
class JointHeatProfile:
    """Cumulative heat ``energy_j[k]`` (J per joint) released from the cycle's start up to
    ``times_s[k]``, over one period."""

    period_s: float
    times_s: FloatArray
    energy_j: FloatArray  # (samples, joints)

    @classmethod
    def from_duty(
        cls,
        arm: Arm,
        cycle: DutyCycle,
        *,
        motors: MotorTable | None = None,
        payload_kg: float | None = None,
        resolution_s: float = DEFAULT_RESOLUTION_S,
    ) -> JointHeatProfile:
        """Integrate the motor heat of ``cycle`` on ``arm`` (midpoint rule); the payload is
        the cycle's unless given."""
        table = arm_motors(arm) if motors is None else motors
        payload = cycle.payload_kg if payload_kg is None else payload_kg
        steps = max(1, math.ceil(cycle.period_s / resolution_s))
        h = cycle.period_s / steps
        q, qd, qdd = cycle.state((np.arange(steps) + 0.5) * h)
        power = joint_heat_batch_w(arm, q, qd, qdd, motors=table, payload_kg=payload)
        energy = np.vstack([np.zeros(power.shape[1]), np.cumsum(power * h, axis=0)])
        return cls(cycle.period_s, np.linspace(0.0, cycle.period_s, steps + 1), energy)

    @property
    def cycle_energy_j(self) -> FloatArray:
        """Heat per joint over one cycle (J)."""
        result: FloatArray = self.energy_j[-1].copy()
        return result

    @property
    def mean_power_w(self) -> FloatArray:
        """Mean heat per joint over a cycle (W)."""
        result: FloatArray = self.energy_j[-1] / self.period_s
        return result

    def energy_at_j(self, t_s: float) -> FloatArray:
        """Heat per joint released from time 0 to ``t_s`` (the cycle repeating)."""
        cycles = math.floor(t_s / self.period_s)
        local = t_s - cycles * self.period_s
        intervals = len(self.times_s) - 1
        # the grid is uniform: locate the interval directly (this runs at every model step)
        k = min(max(int(local / self.period_s * intervals), 0), intervals - 1)
        share = (local - self.times_s[k]) / (self.times_s[k + 1] - self.times_s[k])
        within = self.energy_j[k] + share * (self.energy_j[k + 1] - self.energy_j[k])
        result: FloatArray = cycles * self.energy_j[-1] + within
        return result

    def step_power_w(self, t0_s: float, t1_s: float) -> FloatArray:
        """Mean heat per joint over ``[t0_s, t1_s]`` (W): the zero-order hold of a step."""
        if not t1_s > t0_s:
            raise ValueError(f"empty interval [{t0_s}, {t1_s}] s")
        result: FloatArray = (self.energy_at_j(t1_s) - self.energy_at_j(t0_s)) / (t1_s - t0_s)
        return result


class HeatMeter:
    """Each joint's heat from a feed of timed power readings (W per joint): the heat computed
    from the motion actually performed (:func:`~daemon.arm.motors.joint_heat_batch_w` of the
    joint samples a controller reports), or measured power (``heat_from_current_w`` /
    ``heat_from_power_w``). Integrated by the trapezoid rule between readings;
    :meth:`take_mean_w` gives the mean since the last take, the constant a model step holds."""

    def __init__(self, joints: int) -> None:
        self._energy = np.zeros(joints)
        self._last_time: float | None = None
        self._last_power = np.zeros(joints)
        self._since: float | None = None

    def add(self, time_s: float, power_w: FloatArray) -> None:
        power = np.asarray(power_w, dtype=np.float64).reshape(-1)
        if power.shape != self._energy.shape:
            raise ValueError(f"expected {self._energy.size} joint powers, got {power.size}")
        if self._last_time is not None:
            if time_s < self._last_time:
                raise ValueError(f"reading at {time_s} s before the last one ({self._last_time} s)")
            self._energy += (time_s - self._last_time) * (power + self._last_power) / 2.0
        else:
            self._since = time_s
        self._last_time, self._last_power = time_s, power

    def take_mean_w(self) -> FloatArray:
        """Mean power per joint since the last take (or the first reading); the last reading's
        power when no time has passed."""
        if self._last_time is None or self._since is None:
            return np.zeros_like(self._energy)
        span = self._last_time - self._since
        mean: FloatArray = self._energy / span if span > 0.0 else self._last_power.copy()
        self._energy = np.zeros_like(self._energy)
        self._since = self._last_time
        return mean


__all__ = ["DEFAULT_RESOLUTION_S", "HeatMeter", "HeatSource", "JointHeatProfile"]
