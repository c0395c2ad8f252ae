"""Where the simulated arm's joint motion comes from, and the motor heat it makes.

The arm bench (:mod:`drivers.sim.arm_bench`) heats its motors from the motion the arm actually
performs. That motion comes from a :class:`JointMotionSource`: the C500C emulator in joint space
(it exposes ``joint_sample(t_s) -> JointSample``, helper wt-link) when the bench runs under the
daemon, or a :class:`DutyCycleMotion` that plays a duty cycle in process (benchmarks, tests), or
:class:`StillMotion` (the arm held at one configuration: no speed, gravity torque only).

The energy a motor puts into its joint over ``[t0, t1]`` is the integral of its power
``P_j(t) = motor_heat_w(params_j, qd_j(t), tau_j(t))`` (daemon.arm.motors), evaluated on the
motion's own sample grid (``motion_step_s``) with the trapezoidal rule; the thermal truth takes
the mean power over each of its steps (a zero-order hold of the *energy*, so no heat is lost or
invented between the motion's and the thermal model's grids). A periodic source (a duty cycle)
is integrated over one period once, and any interval is then read off the cumulative integral:
exact on the same samples, and an 8-hour run costs one period of torques.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from daemon.arm.types import FloatArray, JointSample

#: Power of every joint (W) for one motion sample.
PowerFunction = Callable[[JointSample], FloatArray]
#: The same for many samples at once: (q, qd, qdd), rows: samples -> rows of powers.
BatchPowerFunction = Callable[[FloatArray, FloatArray, FloatArray], FloatArray]


@runtime_checkable
class JointMotionSource(Protocol):
    """Anything that says where the arm's joints are at a time: the emulator in joint space or
    a duty cycle played in process."""

    def joint_sample(self, t_s: float) -> JointSample: ...


@runtime_checkable
class PeriodicMotion(JointMotionSource, Protocol):
    """A motion that repeats every ``period_s`` from t = 0 (a duty cycle)."""

    @property
    def period_s(self) -> float: ...


class StillMotion:
    """The arm held at ``q_rad``: zero speed and acceleration for ever; ``holding``: its motors
    hold it against gravity (their copper loss heats them), else it rests on its brakes with
    its motors off (no heat at all)."""

    def __init__(self, q_rad: Sequence[float] | FloatArray, holding: bool = True) -> None:
        self.holding = holding
        self._q = np.array(q_rad, dtype=np.float64)
        self._zero = np.zeros_like(self._q)

    @property
    def period_s(self) -> float:
        return math.inf

    def joint_sample(self, t_s: float) -> JointSample:
        return JointSample(t_s, self._q.copy(), self._zero.copy(), self._zero.copy())


class DutyLike(Protocol):
    """What the bench needs of ``daemon.arm.duty.DutyCycle``: its period and its joint state at
    any times (rows: times; columns: joints)."""

    @property
    def period_s(self) -> float: ...

    def state(self, times_s: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]: ...


class DutyCycleMotion:
    """A duty cycle played in process: ``joint_sample(t)`` is the cycle's state at ``t``."""

    def __init__(self, duty: DutyLike) -> None:
        self.duty = duty

    @property
    def period_s(self) -> float:
        return float(self.duty.period_s)

    def joint_sample(self, t_s: float) -> JointSample:
        q, qd, qdd = self.duty.state([t_s])
        return JointSample(t_s, q[0], qd[0], qdd[0])


class ShiftedMotion:
    """A motion read ``offset_s`` later on its own clock: the emulator's joints (timed on the
    run clock) seen from a truth whose time starts at a run's start (issue 20, a played duty
    cycle: the truth is heated by the motion the emulator performs)."""

    def __init__(self, source: JointMotionSource, offset_s: float) -> None:
        self.source = source
        self.offset_s = float(offset_s)

    def joint_sample(self, t_s: float) -> JointSample:
        sample = self.source.joint_sample(t_s + self.offset_s)
        return JointSample(t_s, sample.q_rad, sample.qd_rad_s, sample.qdd_rad_s2)


class MotorEnergy:
    """The energy each motor has put into its joint since t = 0 (J): the integral of
    ``power(sample)`` over the motion (module docstring). ``energy_j(t)`` must be asked with
    non-decreasing times for a non-periodic source (it integrates forward as asked).
    ``batch``, when given, computes the same powers for many samples at once (faster: e.g.
    ``daemon.arm.motors.joint_heat_batch_w``)."""

    def __init__(
        self,
        source: JointMotionSource,
        power: PowerFunction,
        joints: int,
        motion_step_s: float,
        batch: BatchPowerFunction | None = None,
    ) -> None:
        if not (math.isfinite(motion_step_s) and motion_step_s > 0):
            raise ValueError(f"the motion step must be positive, not {motion_step_s}")
        self.source = source
        self.power = power
        self.batch = batch
        self.joints = joints
        self.motion_step_s = float(motion_step_s)
        period = float(getattr(source, "period_s", math.nan))
        self._periodic = math.isfinite(period) and period > 0
        self._still = period == math.inf
        if self._still:
            self._still_power = (
                np.asarray(power(source.joint_sample(0.0)), dtype=np.float64)
                if getattr(source, "holding", True)
                else np.zeros(joints)
            )
        elif self._periodic:
            count = max(1, round(period / self.motion_step_s))
            self._period_s = period
            grid = np.arange(count + 1) * (period / count)
            watts = self._powers(grid[:-1])
            watts = np.vstack([watts, watts[:1]])  # periodic: the end equals the start
            self._grid = grid
            self._watts = watts
            steps = np.diff(grid)[:, None] * 0.5 * (watts[1:] + watts[:-1])
            self._cumulative = np.vstack([np.zeros(joints), np.cumsum(steps, axis=0)])
        else:
            self._time_s = 0.0
            self._energy = np.zeros(joints)
            self._last_power = np.asarray(power(source.joint_sample(0.0)), dtype=np.float64)

    def _powers(self, times: NDArray[np.floating[Any]]) -> FloatArray:
        """Power per joint at each time (rows)."""
        if self.batch is not None and isinstance(self.source, DutyCycleMotion) and times.size:
            # a played duty cycle's states at once (issue 29: a calibration program's period
            # is 1,300 s, 130,000 samples one by one took minutes)
            q, qd, qdd = self.source.duty.state(times)
            return np.asarray(self.batch(q, qd, qdd), dtype=np.float64).reshape(-1, self.joints)
        samples = [self.source.joint_sample(float(t)) for t in times]
        if not samples:
            return np.zeros((0, self.joints))
        if self.batch is None:
            return np.array([self.power(sample) for sample in samples], dtype=np.float64)
        return np.asarray(
            self.batch(
                np.array([sample.q_rad for sample in samples]),
                np.array([sample.qd_rad_s for sample in samples]),
                np.array([sample.qdd_rad_s2 for sample in samples]),
            ),
            dtype=np.float64,
        ).reshape(len(samples), self.joints)

    def energy_j(self, t_s: float) -> FloatArray:
        """Energy per joint from 0 to ``t_s`` (J)."""
        if self._still:
            result: FloatArray = self._still_power * t_s
            return result
        if self._periodic:
            return self._periodic_energy(t_s)
        return self._forward_energy(t_s)

    def integrate_to(self, t_s: float) -> None:
        """A forward source: integrate the motion up to ``t_s`` now, when not done yet (a
        periodic or still source is integrated at construction: nothing to do). Called
        often, this spreads the sampling over time, so that no single ``energy_j`` call
        samples a whole truth step of motion at once (the UR emulator's cycle:
        drivers/sim/ur/controller.py)."""
        if not (self._still or self._periodic) and t_s > self._time_s:
            self._forward_energy(t_s)

    def _periodic_energy(self, t_s: float) -> FloatArray:
        cycles = math.floor(t_s / self._period_s)
        phase = t_s - cycles * self._period_s
        k = min(int(np.searchsorted(self._grid, phase, side="right")) - 1, self._grid.size - 2)
        fraction = (phase - self._grid[k]) / (self._grid[k + 1] - self._grid[k])
        # Within a motion step the power is linear (the trapezoid's own assumption).
        p0, p1 = self._watts[k], self._watts[k + 1]
        partial = (phase - self._grid[k]) * (p0 + 0.5 * fraction * (p1 - p0))
        result: FloatArray = cycles * self._cumulative[-1] + self._cumulative[k] + partial
        return result

    def _forward_energy(self, t_s: float) -> FloatArray:
        if t_s < self._time_s - 1e-9:
            raise ValueError(f"motion energy asked backwards: {t_s} s < {self._time_s} s")
        span = t_s - self._time_s
        if span > 1e-12:
            whole = math.floor(span / self.motion_step_s + 1e-9)
            times = self._time_s + self.motion_step_s * np.arange(1, whole + 1)
            if times.size == 0 or t_s - times[-1] > 1e-12:
                times = np.append(times, t_s)  # a last partial step
            watts = self._powers(times)
            previous = np.vstack([self._last_power, watts[:-1]])
            steps = np.diff(np.concatenate([[self._time_s], times]))
            self._energy = self._energy + (0.5 * steps[:, None] * (watts + previous)).sum(axis=0)
            self._time_s, self._last_power = float(times[-1]), watts[-1]
        return self._energy.copy()

    def mean_power_w(self, t0_s: float, t1_s: float) -> FloatArray:
        """Mean power per joint over ``[t0, t1]`` (W)."""
        if t1_s <= t0_s:
            result: FloatArray = np.zeros(self.joints)
            return result
        start = self.energy_j(t0_s)  # first: a forward source integrates as it is asked
        mean: FloatArray = (self.energy_j(t1_s) - start) / (t1_s - t0_s)
        return mean


__all__ = [
    "BatchPowerFunction",
    "DutyCycleMotion",
    "DutyLike",
    "JointMotionSource",
    "MotorEnergy",
    "PeriodicMotion",
    "PowerFunction",
    "ShiftedMotion",
    "StillMotion",
]
