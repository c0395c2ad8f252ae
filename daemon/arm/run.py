"""What an arm run (issue 20) needs of the arm's model and of its 3-D measurement, as the
daemon's step sees them. Pure: protocols, values and the pose arithmetic of a measurement.

The controller's model of the arm (kinematics + ArmThermalModel + duty cycle: built in
daemon/run/arm/setup.py) is an :class:`ArmPredictor`; the tool's 3-D measurement (N cameras,
markers, triangulation) is a :class:`ToolMeasurement` per step. Keeping the step against these
two small faces lets it be tested with exact fakes and keeps the pieces' own APIs out of it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from daemon.arm.types import Pose6
from daemon.vision.multiview import pose_difference

__all__ = [
    "ArmPredictor",
    "CyclePose",
    "MeasuredPose",
    "MeasurementError",
    "ToolMeasurement",
    "angle_urad",
    "norm_um",
    "pose_difference",
    "rotation_urad",
    "translation_um",
]

FloatArray = NDArray[np.float64]

#: µm per mm, µrad per rad: the recorder's 6-DOF columns are in µm and µrad (the drift of a
#: warm arm is tens to hundreds of µm and µrad, issue 20).
UM_PER_MM = 1000.0
URAD_PER_RAD = 1e6


@dataclass(frozen=True, eq=False)
class MeasuredPose:
    """A pose of the duty cycle that is measured and corrected: taught as the named goal
    ``name`` at joint angles ``q_rad``, where the cold arm puts the tool at ``tool_pose``
    (4x4, base frame)."""

    name: str
    q_rad: FloatArray
    tool_pose: FloatArray


@dataclass(frozen=True, eq=False)
class CyclePose:
    """A pose of the duty cycle as the robot plays it (issue 20, daemon/run/arm/player.py): taught
    as the goal ``pose.name`` (a valid goal name: drivers/goals.py; a measured pose keeps its
    own), moved into at ``speed_percent`` of the controller's maximum speed, held for
    ``dwell_s``; ``measured``: the tool is measured there. ``name`` is the duty cycle's."""

    name: str
    pose: MeasuredPose
    speed_percent: int
    dwell_s: float
    measured: bool


class ArmPredictor(Protocol):
    """The controller's model of the arm during a duty cycle."""

    @property
    def time_s(self) -> float:
        """Model time reached (s)."""
        ...

    def advance_to(self, t_s: float) -> None:
        """Advance the thermal model to ``t_s`` with the motor heat of the duty cycle's
        commanded motion over the interval."""
        ...

    def tool_error(self, pose: MeasuredPose) -> Pose6:
        """The predicted tool error at ``pose``'s configuration now: the warm arm's tool pose
        relative to the cold arm's (kinematics.tool_error)."""
        ...

    def temperatures_c(self) -> Mapping[str, float]:
        """The model's node temperatures (°C) by node name, for the record."""
        ...


@dataclass(frozen=True, eq=False)
class ToolMeasurement:
    """One 3-D measurement of the tool: its pose (4x4, base frame) from the markers seen in
    the cameras, the 1-sigma of its position (mm) and orientation (rad), and whether the
    orientation was measured (>= 3 markers); ``centroids_px`` per camera and marker for the
    record."""

    pose: FloatArray
    sigma_mm: float
    oriented: bool
    centroids_px: Mapping[str, tuple[tuple[float, float], ...]]
    #: 1-sigma of the orientation (rad, sqrt of the rotation block's trace); NaN when the
    #: orientation was not measured
    rotation_sigma_rad: float = math.nan
    #: each camera's last frame of the measurement, by camera name (references to the
    #: grabbed images, for the dashboard's live views; issue 28)
    images: Mapping[str, Any] = field(default_factory=dict)


class MeasurementError(ValueError):
    """The markers could not be measured (not seen in enough cameras, too few markers)."""


def translation_um(pose: Pose6) -> tuple[float, float, float]:
    x, y, z = (float(v) * UM_PER_MM for v in pose.translation_mm)
    return x, y, z


def rotation_urad(pose: Pose6) -> tuple[float, float, float]:
    x, y, z = (float(v) * URAD_PER_RAD for v in pose.rotation_rad)
    return x, y, z


def norm_um(pose: Pose6) -> float:
    return pose.translation_norm_mm * UM_PER_MM


def angle_urad(pose: Pose6) -> float:
    return pose.rotation_angle_rad * URAD_PER_RAD


def finite_pose(pose: FloatArray) -> bool:
    array = np.asarray(pose, dtype=np.float64)
    return (
        array.shape == (4, 4)
        and bool(np.all(np.isfinite(array)))
        and math.isclose(float(array[3, 3]), 1.0)
    )
