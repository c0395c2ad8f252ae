"""Compensation maths: predicted deformation -> corrective offset, its safety checks, and the
admissible deformation scale. Pure: no I/O, no clocks, no devices.

Thesis 6.4: the compensation is the negative of the (scaled) predicted deformation, with no
deformation at t = 0. DESIGN.md ("Absolute location command", 6.4.4): the offset is always
relative to the operational goal; the incremental mode sends the difference of two consecutive
offsets and exists only to reproduce the thesis's comparison.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from daemon.model.network import UM_PER_MM


class UnsafeTargetError(ValueError):
    """A compensation target failed a safety check; it must not be sent to the robot."""


@dataclass(frozen=True, slots=True)
class CompensationLimits:
    """The bounds every commanded offset must respect (config `compensation.*`)."""

    max_step_change_mm: float
    max_total_offset_mm: float


def compensation_offset_mm(
    predicted_um: ArrayLike, deformation_scale: float
) -> NDArray[np.float64]:
    """Offset from the operational goal that cancels the deformation: ``-scale * d / 1000``.

    Thesis 6.4.1: "the compensation was simply the negative function of the deformation
    function (-y(t))"; 6.3: the deformation may be scaled up by ``deformation_scale``.
    """
    predicted = np.asarray(predicted_um, dtype=np.float64)
    return -deformation_scale * predicted / UM_PER_MM


@dataclass(frozen=True, slots=True)
class VectorLimit:
    """The bounds of one commanded vector (an offset in mm, a rotation vector in degrees): its
    change between two commands and its size, with the setting names a refusal cites."""

    what: str  # "offset", "rotation" ... (the refusal's subject)
    unit: str  # "mm", "deg"
    max_step_change: float
    max_total: float
    step_setting: str  # the setting that bounds the change, named in the refusal
    total_setting: str  # the setting that bounds the size


def check_vector(value: ArrayLike, previous: ArrayLike, limit: VectorLimit) -> NDArray[np.float64]:
    """Return ``value`` as an array when it is safe to send; raise UnsafeTargetError if not.

    Checks, in order: three components, every component finite (NaN and inf never reach the
    serial writer), the change from the previous commanded value within
    ``limit.max_step_change`` (Euclidean), and the value itself within ``limit.max_total`` of
    the goal. The 1-D offset (:func:`check_offset`) and the arm's 6-DOF correction
    (daemon/arm/correction.py: translation and rotation) are both checked here.
    """
    vector = np.asarray(value, dtype=np.float64)
    before = np.asarray(previous, dtype=np.float64)
    what, unit = limit.what, limit.unit
    if vector.shape != (3,):
        raise UnsafeTargetError(f"{what} must have 3 components, not shape {vector.shape}")
    if not np.all(np.isfinite(vector)):
        raise UnsafeTargetError(f"{what} is not finite: {_fmt(vector)} {unit}")
    if not np.all(np.isfinite(before)):
        raise UnsafeTargetError(f"previous {what} is not finite: {_fmt(before)} {unit}")
    change = math.hypot(*(vector - before).tolist())  # hypot: no overflow warning
    if change > limit.max_step_change:
        raise UnsafeTargetError(
            f"{what} change {change:.4f} {unit} exceeds {limit.step_setting} "
            f"{limit.max_step_change} (from {_fmt(before)} to {_fmt(vector)} {unit})"
        )
    total = math.hypot(*vector.tolist())
    if total > limit.max_total:
        raise UnsafeTargetError(
            f"{what} {total:.4f} {unit} from the goal exceeds {limit.total_setting} "
            f"{limit.max_total} ({_fmt(vector)} {unit})"
        )
    return vector


def check_offset(
    offset_mm: ArrayLike, previous_offset_mm: ArrayLike, limits: CompensationLimits
) -> NDArray[np.float64]:
    """Return ``offset_mm`` as an array when it is safe to send; raise UnsafeTargetError if not
    (:func:`check_vector` with the ``compensation.*`` limits)."""
    return check_vector(
        offset_mm,
        previous_offset_mm,
        VectorLimit(
            "offset",
            "mm",
            limits.max_step_change_mm,
            limits.max_total_offset_mm,
            "max_step_change_mm",
            "max_total_offset_mm",
        ),
    )


def max_admissible_scale(
    largest_deformation_um: float,
    direction: Sequence[float],
    chip_extent_um: tuple[float, float],
    spot_size_um: float,
) -> float:
    """The largest deformation scale that keeps the whole spot on the camera chip.

    DESIGN.md (Scaling, thesis 6.3): chip width over the largest predicted deformation, less
    the spot's own size; the thesis's 8,600 um chip allowed 28. The deformation moves the spot
    along ``direction``; its x and y components are bounded by the chip's width and height
    (the camera looks down the z axis, thesis 6.3). Infinite when nothing moves on the chip.
    """
    if largest_deformation_um < 0 or not math.isfinite(largest_deformation_um):
        raise ValueError(f"largest deformation must be finite and >= 0: {largest_deformation_um}")
    unit = np.asarray(direction, dtype=np.float64)
    unit = unit / np.linalg.norm(unit)
    scale = math.inf
    for extent_um, component in zip(chip_extent_um, unit[:2], strict=True):
        travel_um = largest_deformation_um * abs(float(component))
        if travel_um > 0:
            scale = min(scale, max(extent_um - spot_size_um, 0.0) / travel_um)
    return scale


def check_scale(
    deformation_scale: float,
    largest_deformation_um: float,
    direction: Sequence[float],
    chip_extent_um: tuple[float, float],
    spot_size_um: float,
) -> None:
    """Raise ValueError naming the limit when ``deformation_scale`` would push the spot off the
    chip (DESIGN.md Scaling)."""
    limit = max_admissible_scale(largest_deformation_um, direction, chip_extent_um, spot_size_um)
    if deformation_scale > limit:
        raise ValueError(
            f"deformation scale {deformation_scale:g} is not admissible: the largest predicted "
            f"deformation {largest_deformation_um:.1f} um would leave the camera chip "
            f"({chip_extent_um[0]:.0f} x {chip_extent_um[1]:.0f} um, spot {spot_size_um:.0f} um); "
            f"the largest admissible scale is {limit:.2f}"
        )


def _fmt(vector: NDArray[np.float64]) -> str:
    return "(" + ", ".join(f"{v:.4f}" for v in np.atleast_1d(vector)) + ")"


# --------------------------------------------------------------------------- incremental mode

#: docs/reference/c500c-console.md: the console takes and prints positions as ``%.3f`` mm, so every
#: commanded move is rounded to 0.001 mm (drivers/c500c/protocol.py ``round_mm``).
CONSOLE_RESOLUTION_MM = 0.001
#: The share of the scaled deformation that the console's rounding of incremental moves may
#: leave uncompensated before a run is refused. Thesis 6.3 scaled the deformation "to obtain
#: at least 90 % overall compensation accuracy" with moves the robot could make.
MAX_INCREMENT_LOSS_FRACTION = 0.1
#: The largest scale :func:`smallest_working_scale` tries (runs admit up to 1000).
MAX_SEARCHED_SCALE = 1000


@dataclass(frozen=True, slots=True)
class IncrementalRounding:
    """What the console's rounding does to a run's incremental moves (thesis 6.4.3).

    Incremental mode sends each step the difference between this step's and the previous
    step's *intended* offsets; the console rounds it to its resolution, and what is rounded
    away is never sent again, so the rounding errors add up. Lengths are on the chip, i.e.
    scaled (µm), per axis.
    """

    deformation_scale: float
    steps: int
    lost_steps: int  # moves that round to no motion on every axis
    largest_move_um: float  # the largest intended move of one step on one axis
    largest_error_um: float  # the largest accumulated rounding error on one axis
    largest_deformation_um: float  # the largest scaled deformation on one axis

    @property
    def loss_fraction(self) -> float:
        """The accumulated rounding error over the deformation (0 when nothing deforms)."""
        if self.largest_deformation_um <= 0:
            return 0.0
        return self.largest_error_um / self.largest_deformation_um

    @property
    def admissible(self) -> bool:
        return self.loss_fraction <= MAX_INCREMENT_LOSS_FRACTION


def incremental_rounding(
    predicted_um: ArrayLike,
    deformation_scale: float,
    resolution_mm: float = CONSOLE_RESOLUTION_MM,
) -> IncrementalRounding:
    """The rounding of the incremental moves that follow ``predicted_um`` (n x 3: the
    expected deformation at each step, from the goal where it is 0) at ``deformation_scale``.

    Step k moves by ``offset_k - offset_(k-1)`` (the first from the goal), offsets being
    ``-scale x deformation`` (:func:`compensation_offset_mm`); the console executes each move
    rounded to ``resolution_mm`` per axis.
    """
    predicted = np.atleast_2d(np.asarray(predicted_um, dtype=np.float64))
    resolution_um = resolution_mm * UM_PER_MM
    offsets_um = -deformation_scale * predicted
    moves = np.diff(offsets_um, axis=0, prepend=np.zeros((1, predicted.shape[1])))
    sent = np.round(moves / resolution_um) * resolution_um
    error = np.cumsum(sent - moves, axis=0)
    lost = np.all(sent == 0.0, axis=1) & np.any(moves != 0.0, axis=1)
    return IncrementalRounding(
        deformation_scale=deformation_scale,
        steps=int(predicted.shape[0]),
        lost_steps=int(np.count_nonzero(lost)),
        largest_move_um=float(np.abs(moves).max(initial=0.0)),
        largest_error_um=float(np.abs(error).max(initial=0.0)),
        largest_deformation_um=float(np.abs(offsets_um).max(initial=0.0)),
    )


def smallest_working_scale(
    predicted_um: ArrayLike,
    largest_admissible_scale: float,
    resolution_mm: float = CONSOLE_RESOLUTION_MM,
) -> int | None:
    """The smallest whole deformation scale (thesis 6.3 used 28) up to the largest one the
    camera chip admits at which incremental rounding is :attr:`IncrementalRounding.admissible`;
    None when none is."""
    highest = math.floor(min(largest_admissible_scale, MAX_SEARCHED_SCALE))
    for scale in range(1, highest + 1):
        if incremental_rounding(predicted_um, float(scale), resolution_mm).admissible:
            return scale
    return None
