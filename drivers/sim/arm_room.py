"""The arm bench's room thermometer (issue 29): what a DS18B20 in the lab's air would read of
the truth's room (drivers/sim/arm_bench.py ``ambient_c``).

A real sensor lags the air (its body and package: a first-order time constant of a minute or
two in still air for a TO-92 DS18B20), reads with a constant error (+-0.5 degC from -10 to
+85 degC, Maxim DS18B20 datasheet 19-7487 Rev 6, "Thermometer Error") and some noise, and
reports in steps of its resolution (0.0625 degC at 12 bits). Here the lag is integrated
exactly for the room held over sub-steps of at most a tenth of the time constant (the room
changes over hours), then the offset, the noise (its own seeded generator) and the rounding
are applied to each reading.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

#: The lag's sub-step, as a fraction of the time constant, and at most this long (s).
SUBSTEP_FRACTION = 0.1
MAX_SUBSTEP_S = 60.0


class SimRoomSensor:
    """A thermometer in the room ``room_c(t_s)`` (degC), read at the bench's times; starts in
    equilibrium with the room at time 0 (the lab's air before the run)."""

    def __init__(
        self,
        room_c: Callable[[float], float],
        rng: np.random.Generator,
        *,
        lag_s: float = 120.0,
        noise_c: float = 0.02,
        resolution_c: float = 0.0625,
        offset_c: float = 0.0,
    ) -> None:
        for name, value in (("lag", lag_s), ("noise", noise_c), ("resolution", resolution_c)):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"room sensor {name} must be finite and >= 0, got {value}")
        self._room = room_c
        self._rng = rng
        self.lag_s = lag_s
        self.noise_c = noise_c
        self.resolution_c = resolution_c
        self.offset_c = offset_c
        self.time_s = 0.0
        self.body_c = float(room_c(0.0))  # the sensor's own temperature

    def advance_to(self, t_s: float) -> None:
        """Follow the room to ``t_s`` (never backwards)."""
        if t_s <= self.time_s:
            return
        if self.lag_s == 0.0:
            self.body_c, self.time_s = float(self._room(t_s)), t_s
            return
        span = t_s - self.time_s
        substep = min(self.lag_s * SUBSTEP_FRACTION, MAX_SUBSTEP_S)
        count = max(1, math.ceil(span / substep))
        h = span / count
        decay = math.exp(-h / self.lag_s)
        body = self.body_c
        for k in range(count):
            air = float(self._room(self.time_s + (k + 0.5) * h))
            body = air + (body - air) * decay
        self.body_c, self.time_s = body, t_s

    def read(self, t_s: float) -> float:
        """One reading at ``t_s`` (degC): the sensor's lagged temperature, its offset and
        noise, rounded to its resolution."""
        self.advance_to(t_s)
        value = self.body_c + self.offset_c
        if self.noise_c > 0.0:
            value += float(self._rng.normal(0.0, self.noise_c))
        if self.resolution_c > 0.0:
            value = round(value / self.resolution_c) * self.resolution_c
        return value


__all__ = ["SimRoomSensor"]
