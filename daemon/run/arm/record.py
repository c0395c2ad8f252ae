"""What an arm step writes into its record (daemon/run/arm/step.py): the model's prediction,
the correction, the measured drift of the tool and each camera's view; and the flags of an arm
step's sensor errors (their flags are appended where they are found: daemon/run/arm/step.py).
Columns in the units of daemon/storage/step_record.py (µm, µrad, mm).
"""

from __future__ import annotations

import json
import math

from daemon.arm.run import (
    MeasuredPose,
    ToolMeasurement,
    angle_urad,
    norm_um,
    pose_difference,
    rotation_urad,
    translation_um,
)
from daemon.arm.types import Pose6
from daemon.run.arm.work import ArmRunWork
from daemon.run.step import CameraView
from daemon.storage.recorder import StepRecord


def camera_views(measurement: ToolMeasurement | None) -> tuple[CameraView, ...]:
    """Each camera's frame of the measurement with the marker centroids it found."""
    if measurement is None:
        return ()
    return tuple(
        CameraView(
            camera,
            image,
            tuple(
                (float(x), float(y))
                for x, y in measurement.centroids_px.get(camera, ())
                if math.isfinite(x) and math.isfinite(y)
            ),
        )
        for camera, image in sorted(measurement.images.items())
    )


def record_model(work: ArmRunWork, record: StepRecord, error: Pose6) -> None:
    """The model's prediction at the step's pose and its temperatures."""
    record.model_time_s = work.predictor.time_s
    record.predicted_tx_um, record.predicted_ty_um, record.predicted_tz_um = translation_um(error)
    record.predicted_rx_urad, record.predicted_ry_urad, record.predicted_rz_urad = rotation_urad(
        error
    )
    temperatures = work.predictor.temperatures_c()
    record.model_temperatures_json = json.dumps(
        {name: round(float(value), 4) for name, value in temperatures.items()}
    )


def record_correction(record: StepRecord, correction: Pose6) -> None:
    """The correction the step sent (or the player's, for the arrival it measures)."""
    record.correction_tx_mm, record.correction_ty_mm, record.correction_tz_mm = (
        float(v) for v in correction.translation_mm
    )
    record.correction_rx_urad, record.correction_ry_urad, record.correction_rz_urad = rotation_urad(
        correction
    )
    # the two-link columns carry the translation too, so 1-D tools still see the offset
    record.offset_x_mm = record.correction_tx_mm
    record.offset_y_mm = record.correction_ty_mm
    record.offset_z_mm = record.correction_tz_mm


def record_measurement(
    work: ArmRunWork, pose: MeasuredPose, measurement: ToolMeasurement, record: StepRecord
) -> bool:
    """The measured drift of the tool at ``pose``: its measured pose relative to the one
    measured at the same taught goal before the first move (the first measurement when there
    was none), in µm and µrad; orientation only from >= 3 markers. True when this measurement
    became the pose's zero (no reference was measured: its drift is zero by construction)."""
    taken_as_zero = pose.name not in work.reference
    reference = work.reference.setdefault(pose.name, measurement.pose)
    drift = pose_difference(reference, measurement.pose)
    record.measured_tx_um, record.measured_ty_um, record.measured_tz_um = translation_um(drift)
    record.drift_3d_um = norm_um(drift)
    record.measured_sigma_um = measurement.sigma_mm * 1000.0
    if measurement.oriented:
        record.measured_rx_urad, record.measured_ry_urad, record.measured_rz_urad = rotation_urad(
            drift
        )
        record.rotation_error_urad = angle_urad(drift)
        if math.isfinite(measurement.rotation_sigma_rad):
            record.measured_rotation_sigma_urad = measurement.rotation_sigma_rad * 1e6
    return taken_as_zero
