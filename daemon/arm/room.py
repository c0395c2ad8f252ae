"""The room as an input of the arm model (issue 29): a room thermometer's readings, taken at
the steps of a run, as the ambient of a model stepped on another grid. Pure.

Identification (daemon/arm/response.py ``ArmRunData.ambient_c``: one ambient per heat step)
and any offline replay of a run take the recorded readings (the steps' ``room_c``) through
:func:`ambient_series`; the controller during a run follows each reading as it comes
(daemon/arm/controller.py ``follow_room``), holding over each step the mean of the readings
at its two ends, as here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from daemon.arm.types import FloatArray


def ambient_series(
    times_s: ArrayLike,
    room_c: ArrayLike,
    step_s: float,
    steps: int,
    default_c: float,
) -> FloatArray:
    """The mean ambient (degC) over each of ``steps`` steps of ``step_s`` from time 0, from
    readings ``room_c`` at ``times_s`` (model time, s; missing readings as NaN are skipped):
    the readings joined linearly, held flat before the first and after the last, each step's
    mean by the trapezoid rule over its ends. No reading at all: ``default_c`` throughout
    (the model's configured ambient, a run without a thermometer)."""
    if not (np.isfinite(step_s) and step_s > 0.0) or steps < 0:
        raise ValueError(f"{steps} steps of {step_s} s: need a positive step")
    times = np.asarray(times_s, dtype=np.float64).reshape(-1)
    values = np.asarray(room_c, dtype=np.float64).reshape(-1)
    if times.shape != values.shape:
        raise ValueError(f"{times.size} reading times for {values.size} readings")
    keep = np.isfinite(times) & np.isfinite(values)
    if not keep.any():
        return np.full(steps, float(default_c))
    order = np.argsort(times[keep], kind="stable")
    times, values = times[keep][order], values[keep][order]
    edges = np.interp(np.arange(steps + 1) * step_s, times, values)
    result: FloatArray = 0.5 * (edges[:-1] + edges[1:])
    return result


def readings_of(rows: Sequence[tuple[float | None, float | None]]) -> tuple[FloatArray, FloatArray]:
    """(times, readings) of recorded (model time s, room degC) pairs, None as NaN."""
    times = np.array([np.nan if t is None else float(t) for t, _ in rows], dtype=np.float64)
    values = np.array([np.nan if c is None else float(c) for _, c in rows], dtype=np.float64)
    return times, values


__all__ = ["ambient_series", "readings_of"]
