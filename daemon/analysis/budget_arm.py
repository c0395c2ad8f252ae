"""The error budget of a whole arm watched by several cameras (issue 32). Pure.

An arm measures the tool in 3-D (daemon/vision/multiview.py), so chapter 4's cosine errors of
a one-axis measurement do not arise; what takes their place is the 3-D measurement's own
uncertainty at each measured pose, set by the cameras' geometry, the marker layout and the
centroids' noise, and, when an identified arm model drives the compensation, the uncertainty
of its parameters carried to the tool. Both are computed here per pose:

- the measurement: the markers projected into every camera that sees them at the pose (in
  front of it, on its chip), triangulated and fitted as a run does
  (daemon/vision/tool_pose.py), with each camera's centroid 1-sigma; the covariance of that
  fit at the exact pixels is the first-order covariance of any noisy measurement there. A
  drift is a pose minus its reference, each the mean of its frames, so its variance is the
  pose's times ``1/frames + 1/reference_frames``;
- the model: each identified factor moved by its standard error (of its logarithm), the tool
  drift predicted again, the differences added in quadrature (the arm-model file keeps each
  parameter's error, not their correlation: they are taken as independent).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from daemon.arm.arm_model import ArmModel
from daemon.arm.controller import ArmController, ArmModelOptions
from daemon.arm.description import Arm
from daemon.arm.duty import DutyCycle
from daemon.arm.heat import HeatSource, JointHeatProfile
from daemon.arm.run import MeasuredPose
from daemon.vision.multiview import CameraModel, MultiviewError, depths_mm, project
from daemon.vision.tool_pose import measure_tool_pose

FloatArray = NDArray[np.float64]
UM_PER_MM = 1000.0


@dataclass(frozen=True)
class PoseMeasurement:
    """The predicted 3-D measurement of the tool at one pose: its position's 1-sigma (mm,
    root of the covariance's translation trace) and how many cameras see a marker."""

    sigma_mm: float | None
    cameras_seeing: int
    markers_seen: tuple[int, ...]  # cameras seeing each marker
    why_not: str = ""


def visible_pixels(
    cameras: Sequence[CameraModel], points_mm: ArrayLike
) -> tuple[FloatArray, list[int]]:
    """Pixels (cameras x points x 2) of world points, NaN where a camera does not see one (behind
    it or off its chip), and how many points each camera sees."""
    points = np.asarray(points_mm, dtype=np.float64)
    pixels = np.full((len(cameras), points.shape[0], 2), np.nan)
    counts = []
    for index, camera in enumerate(cameras):
        projected = project(camera, points)
        width, height = camera.image_size_px
        seen = (
            (depths_mm(camera, points) > 0)
            & (projected[:, 0] >= 0)
            & (projected[:, 0] <= width - 1)
            & (projected[:, 1] >= 0)
            & (projected[:, 1] <= height - 1)
        )
        pixels[index, seen] = projected[seen]
        counts.append(int(seen.sum()))
    return pixels, counts


def predicted_measurement(
    cameras: Sequence[CameraModel],
    markers_tool_mm: ArrayLike,
    tool_pose: ArrayLike,
    sigmas_px: Sequence[float] | None = None,
) -> PoseMeasurement:
    """The tool measurement's 1-sigma at ``tool_pose`` (module docstring); ``sigmas_px``: each
    camera's centroid 1-sigma (default its ``pixel_sigma_px``)."""
    markers = np.asarray(markers_tool_mm, dtype=np.float64)
    pose = np.asarray(tool_pose, dtype=np.float64)
    world = markers @ pose[:3, :3].T + pose[:3, 3]
    pixels, counts = visible_pixels(cameras, world)
    per_marker = tuple(int(v) for v in np.isfinite(pixels[:, :, 0]).sum(axis=0))
    seeing = sum(1 for count in counts if count > 0)
    own = [c.pixel_sigma_px for c in cameras] if sigmas_px is None else list(sigmas_px)
    sigmas = np.repeat(np.asarray(own, dtype=np.float64)[:, None, None], markers.shape[0], axis=1)
    sigmas = np.repeat(sigmas, 2, axis=2)
    try:
        measured = measure_tool_pose(tuple(cameras), markers, pixels, sigmas)
    except MultiviewError as err:
        return PoseMeasurement(None, seeing, per_marker, f"no pose from the cameras: {err}")
    sigma = math.sqrt(float(np.trace(measured.covariance[:3, :3])))
    return PoseMeasurement(sigma, seeing, per_marker)


def drift_sigma_um(pose_sigma_mm: float, frames: int, reference_frames: int) -> float:
    """1-sigma of a drift (µm): a pose's mean of ``frames`` minus its reference's mean of
    ``reference_frames``, the two independent."""
    return UM_PER_MM * pose_sigma_mm * math.sqrt(1.0 / frames + 1.0 / reference_frames)


# --- the model's expected drift and its uncertainty ----------------------------------------------


def tool_drifts_um(
    arm: Arm,
    duty: DutyCycle,
    poses: Sequence[MeasuredPose],
    *,
    end_s: float,
    options: ArmModelOptions,
    identified: ArmModel | None = None,
    heat: HeatSource | None = None,
) -> FloatArray:
    """The model's predicted tool translation (µm, poses x 3) at each pose after ``end_s`` of
    the duty cycle from cold."""
    controller = ArmController(arm, duty, options, heat=heat, identified=identified)
    controller.advance_to(end_s)
    errors = controller.tool_errors(poses)
    return np.array([UM_PER_MM * np.asarray(e.translation_mm) for e in errors], dtype=np.float64)


def perturbed_models(model: ArmModel, joints: int) -> list[tuple[str, ArmModel]]:
    """The model with each identifiable scale factor moved up by its standard error (of its
    logarithm, ``relative_error``): heat of a joint or of all, convection, alpha. IR offsets
    act on the IR observer only, not on an open-loop prediction: left out."""
    variants = []
    for parameter in model.parameters:
        step = parameter.relative_error
        if not parameter.identifiable or step is None or not math.isfinite(step) or step <= 0:
            continue
        factor = math.exp(step)
        kind, _, argument = parameter.name.partition(":")
        if kind == "heat":
            scales = list(model.heat_scales) or [1.0] * joints
            indices = [int(argument) - 1] if argument else list(range(joints))
            for j in indices:
                scales[j] *= factor
            variants.append((parameter.name, dataclasses.replace(model, heat_scales=tuple(scales))))
        elif kind == "convection":
            moved = dataclasses.replace(model, convection_scale=model.convection_scale * factor)
            variants.append((parameter.name, moved))
        elif kind == "alpha":
            variants.append(
                (parameter.name, dataclasses.replace(model, alpha_scale=model.alpha_scale * factor))
            )
    return variants


@dataclass(frozen=True)
class ModelUncertainty:
    """Each pose's 1-sigma of the predicted tool drift (µm) from the identified parameters,
    and each parameter's share at the worst pose."""

    sigma_um: tuple[float, ...]
    contributions_um: dict[str, tuple[float, ...]]


def model_uncertainty(
    arm: Arm,
    duty: DutyCycle,
    poses: Sequence[MeasuredPose],
    *,
    end_s: float,
    options: ArmModelOptions,
    identified: ArmModel,
) -> ModelUncertainty:
    """The identified model's parameter uncertainty carried to the tool (module docstring)."""
    heat = JointHeatProfile.from_duty(arm, duty, resolution_s=options.motion_dt_s)
    nominal = tool_drifts_um(
        arm, duty, poses, end_s=end_s, options=options, identified=identified, heat=heat
    )
    contributions: dict[str, tuple[float, ...]] = {}
    for name, variant in perturbed_models(identified, len(arm.joints)):
        moved = tool_drifts_um(
            arm, duty, poses, end_s=end_s, options=options, identified=variant, heat=heat
        )
        contributions[name] = tuple(np.linalg.norm(moved - nominal, axis=1).tolist())
    total = np.sqrt(sum((np.square(v) for v in contributions.values()), np.zeros(len(poses))))
    return ModelUncertainty(tuple(float(v) for v in total), contributions)
