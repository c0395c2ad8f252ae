"""The 6-DOF correction of a taught pose and its safety checks (issue 20). Pure.

The correction cancels the predicted tool error at the pose's own configuration: ``-scale x
error`` (thesis 6.4.1, "the negative function of the deformation", generalised from one
direction to a rigid displacement). Like the 1-D offset (daemon/model/compensation.py), it is
always relative to the taught goal (DESIGN.md "Absolute location command", 6.4.4) and is
checked before anything reaches the robot: every value finite, the translation and the
rotation each within their size limit and their change since the pose's previous correction
within their step limit. The checks are the 1-D path's :func:`check_vector`, applied to the
translation (mm) and to the rotation vector (degrees).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from daemon.arm.types import Pose6
from daemon.model.compensation import UnsafeTargetError, VectorLimit, check_vector

__all__ = ["CorrectionLimits", "UnsafeTargetError", "check_correction", "correction_for"]


@dataclass(frozen=True, slots=True)
class CorrectionLimits:
    """The bounds of a 6-DOF correction (settings ``arm.max_*``)."""

    max_translation_mm: float
    max_rotation_deg: float
    max_step_translation_mm: float
    max_step_rotation_deg: float

    def translation(self) -> VectorLimit:
        return VectorLimit(
            "translation",
            "mm",
            self.max_step_translation_mm,
            self.max_translation_mm,
            "arm.max_step_translation_mm",
            "arm.max_translation_mm",
        )

    def rotation(self) -> VectorLimit:
        return VectorLimit(
            "rotation",
            "deg",
            self.max_step_rotation_deg,
            self.max_rotation_deg,
            "arm.max_step_rotation_deg",
            "arm.max_rotation_deg",
        )


def correction_for(error: Pose6, deformation_scale: float = 1.0) -> Pose6:
    """The correction that cancels ``error``: ``-scale x error``, translation and rotation.

    A rotation vector scaled by ``s`` is the same axis turned ``s`` times the angle, so the
    scale acts on both parts alike. Non-finite errors give non-finite corrections, which
    :func:`check_correction` refuses.
    """
    with np.errstate(all="ignore"):  # a NaN error must reach the check, not warn here
        translation = -deformation_scale * np.asarray(error.translation_mm)
        rotation = -deformation_scale * np.asarray(error.rotation_rad)
    if not (np.all(np.isfinite(translation)) and np.all(np.isfinite(rotation))):
        raise UnsafeTargetError(
            f"correction is not finite: translation {translation.tolist()} mm, "
            f"rotation {rotation.tolist()} rad"
        )
    return Pose6(translation, rotation)


def check_correction(correction: Pose6, previous: Pose6, limits: CorrectionLimits) -> Pose6:
    """Return ``correction`` when it is safe to send; raise UnsafeTargetError naming the limit.

    The rotation's step change is the norm of the difference of the two rotation vectors: for
    the small rotations admitted here (degrees at most) it equals the angle of the relative
    rotation to second order (Rodrigues' formula), e.g. within 0.3 % at 10 degrees.
    """
    check_vector(correction.translation_mm, previous.translation_mm, limits.translation())
    check_vector(
        np.degrees(correction.rotation_rad), np.degrees(previous.rotation_rad), limits.rotation()
    )
    return correction


def rotation_deg(pose: Pose6) -> float:
    """The rotation angle of ``pose`` in degrees."""
    return math.degrees(pose.rotation_angle_rad)
