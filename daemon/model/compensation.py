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


def check_offset(
    offset_mm: ArrayLike, previous_offset_mm: ArrayLike, limits: CompensationLimits
) -> NDArray[np.float64]:
    """Return ``offset_mm`` as an array when it is safe to send; raise UnsafeTargetError if not.

    Checks, in order: every component finite (NaN and inf never reach the serial writer), the
    change from the previous commanded offset within ``max_step_change_mm`` (Euclidean), and
    the offset itself within ``max_total_offset_mm`` of the operational goal.
    """
    offset = np.asarray(offset_mm, dtype=np.float64)
    previous = np.asarray(previous_offset_mm, dtype=np.float64)
    if offset.shape != (3,):
        raise UnsafeTargetError(f"offset must have 3 components, not shape {offset.shape}")
    if not np.all(np.isfinite(offset)):
        raise UnsafeTargetError(f"offset is not finite: {_fmt(offset)} mm")
    if not np.all(np.isfinite(previous)):
        raise UnsafeTargetError(f"previous offset is not finite: {_fmt(previous)} mm")
    change = math.hypot(*(offset - previous).tolist())  # hypot: no overflow warning
    if change > limits.max_step_change_mm:
        raise UnsafeTargetError(
            f"offset change {change:.4f} mm exceeds max_step_change_mm "
            f"{limits.max_step_change_mm} (from {_fmt(previous)} to {_fmt(offset)} mm)"
        )
    total = math.hypot(*offset.tolist())
    if total > limits.max_total_offset_mm:
        raise UnsafeTargetError(
            f"offset {total:.4f} mm from the goal exceeds max_total_offset_mm "
            f"{limits.max_total_offset_mm} ({_fmt(offset)} mm)"
        )
    return offset


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
