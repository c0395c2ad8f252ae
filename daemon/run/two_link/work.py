"""What a two-link run's steps carry from one to the next (daemon/run/two_link/step.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from daemon.model import ThermalModel
from daemon.model.observer import IrObserver
from daemon.run.states import RunParameters
from drivers.base import Pose


@dataclass(eq=False)
class RunWork:
    """What a run's steps carry from one to the next: the model and the compensation's
    memory. Only the pipeline (and the session's resume, for the incremental mode) touch it."""

    run_id: int
    parameters: RunParameters
    model: ThermalModel
    direction: NDArray[np.float64]  # unit vector of the link axis, world coordinates
    observer: IrObserver | None = None  # prediction "model+ir": the IR Kalman filter
    goal: Pose | None = None  # taught operational goal
    start_s: float = math.nan  # run clock at step 0
    last_offset_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    last_target_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    reference_um: dict[int, tuple[float, float]] = field(default_factory=dict)
    reference_source: str = "first step"  # where the drift's zero was measured
    # None until the first step sets the procedure's heat (even an empty one: a run told to
    # heat nothing must not keep its network's own heat)
    model_heat: dict[str, float] | None = None
