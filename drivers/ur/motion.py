"""The motion the robot actually made, package by package (issue 31): each RTDE state package's
controller time, joint positions, speeds and accelerations, kept in a bounded log that a
followed run drains once per step (daemon/run/followed/heat.py turns it into motor heat with
the arm's motor model, the one the duty cycle's heat comes from).

Why every package and not the step's state: a followed run steps at 10 Hz, the robot streams at
robot.rtde_frequency_hz (125-500 Hz); the heat of a 0.3 s acceleration ramp sampled at 10 Hz
is a matter of luck (measured on the UR bench: within 0.9 % per joint at 10 Hz, 0.1 % at
125 Hz).

The RTDE guide's names (Controller outputs): ``actual_q`` "Actual joint positions" (rad),
``actual_qd`` "Actual joint velocities" (rad/s), ``target_qdd`` "Target joint accelerations"
(rad/s^2). The acceleration is the controller's target because RTDE has no actual one, and a
difference of successive ``actual_qd`` would square its noise into the heat (the inertia's
copper loss goes as qdd^2): on a UR the target and the actual motion differ by the joint
servo's tracking error. Why not ``actual_current`` ("Actual joint currents", which the
emulator sends: drivers/sim/ur/controller.py): docs/how-to/universal-robots.md, "Motor heat".
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivers.ur.rtde_protocol import Recipe, Value

Floats = NDArray[np.float64]
#: The longest stretch the log keeps (s at the package rate): a followed run drains it every
#: step (0.1 s); nothing drains it outside a run, and a step later than this is a fault of its
#: own. At 500 Hz: 5000 packages, ~1 MB.
KEEP_S = 10.0

_Sample = tuple[float, tuple[float, ...], tuple[float, ...], tuple[float, ...]]


@dataclass(frozen=True, slots=True)
class MotionSamples:
    """Packages since the last take, oldest first: ``times_s`` (N, the controller's clock),
    ``q_rad``, ``qd_rad_s``, ``qdd_rad_s2`` (N x joints)."""

    times_s: Floats
    q_rad: Floats
    qd_rad_s: Floats
    qdd_rad_s2: Floats

    def __len__(self) -> int:
        return len(self.times_s)

    @classmethod
    def empty(cls, joints: int = 6) -> MotionSamples:
        return cls(np.zeros(0), np.zeros((0, joints)), np.zeros((0, joints)), np.zeros((0, joints)))


class MotionLog:
    """The packages' motion, bounded (module docstring). Owned by the driver's reader: it adds;
    the followed run's step takes (both on the event loop)."""

    def __init__(self, frequency_hz: float, keep_s: float = KEEP_S) -> None:
        self._samples: deque[_Sample] = deque(maxlen=max(2, math.ceil(frequency_hz * keep_s)))
        #: packages dropped because nobody took them within ``keep_s`` (oldest first)
        self.dropped = 0

    def add(
        self,
        time_s: float,
        q_rad: Sequence[float],
        qd_rad_s: Sequence[float],
        qdd_rad_s2: Sequence[float],
    ) -> None:
        samples = self._samples
        if len(samples) == samples.maxlen:
            self.dropped += 1
        samples.append((time_s, tuple(q_rad), tuple(qd_rad_s), tuple(qdd_rad_s2)))

    def add_package(self, recipe: Recipe, values: tuple[Value, ...]) -> None:
        """One state package of an output recipe with ``timestamp``, ``actual_q``,
        ``actual_qd`` and ``target_qdd``."""
        named = dict(zip(recipe.names, values, strict=True))
        q, qd, qdd = named["actual_q"], named["actual_qd"], named["target_qdd"]
        assert isinstance(q, tuple) and isinstance(qd, tuple) and isinstance(qdd, tuple)
        self.add(float(named["timestamp"]), q, qd, qdd)  # type: ignore[arg-type]

    def take(self) -> MotionSamples:
        """Every package since the last take, and the log emptied."""
        samples = list(self._samples)
        self._samples.clear()
        if not samples:
            return MotionSamples.empty()
        times, q, qd, qdd = zip(*samples, strict=True)
        return MotionSamples(
            np.array(times, dtype=np.float64),
            np.array(q, dtype=np.float64),
            np.array(qd, dtype=np.float64),
            np.array(qdd, dtype=np.float64),
        )


__all__ = ["KEEP_S", "MotionLog", "MotionSamples"]
