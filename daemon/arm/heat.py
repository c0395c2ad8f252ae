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

import numpy as np

from daemon.arm.description import Arm
from daemon.arm.duty import DutyCycle
from daemon.arm.motors import MotorTable, arm_motors, joint_heat_w
from daemon.arm.types import FloatArray, JointSample

#: Default integration step of one cycle's heat (s): a few per acceleration ramp.
DEFAULT_RESOLUTION_S = 0.005


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
        power = np.array(
            [
                joint_heat_w(
                    arm, JointSample(0.0, q[k], qd[k], qdd[k]), motors=table, payload_kg=payload
                )
                for k in range(steps)
            ]
        )
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


__all__ = ["DEFAULT_RESOLUTION_S", "JointHeatProfile"]
