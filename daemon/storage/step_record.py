"""One recorded step (issue 2 onwards): the row of the steps table, whose field order is the
column order of the table, the CSV and every export (the contract with daemon.analysis), and
the SQL that creates that table (daemon/storage/recorder.py writes it)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any


@dataclass(slots=True)
class StepRecord:
    """One step as recorded; field order is the column order of the steps table and CSV."""

    run_id: int  # the run's number
    step: int  # 0, 1, 2, ... in the run
    scheduled_s: float  # the step's deadline on the run clock
    actual_s: float  # when it began on the run clock
    lateness_s: float  # actual_s - scheduled_s
    model_time_s: float | None = None  # the time the model was advanced to (model time)
    predicted_x_um: float | None = None  # unscaled predicted deformation
    predicted_y_um: float | None = None
    predicted_z_um: float | None = None
    offset_x_mm: float | None = None  # commanded compensation offset
    offset_y_mm: float | None = None
    offset_z_mm: float | None = None
    pose_x_mm: float | None = None  # actual pose read back
    pose_y_mm: float | None = None
    pose_z_mm: float | None = None
    centroid_x_px: float | None = None  # the laser spot's centroid on the chip (px)
    centroid_y_px: float | None = None
    centroid_x_um: float | None = None  # ... in um (camera.um_per_px)
    centroid_y_um: float | None = None
    drift_x_um: float | None = None  # centroid minus the reference (at the goal, before
    drift_y_um: float | None = None  # the first move; else step 0's centroid)
    residual_um: float | None = None  # drift projected on the link direction
    ir_json: str | None = None  # {"region": {"mean_c": .., "max_c": ..}}
    flags: str = ""  # comma-separated
    error: str = ""  # the flags' messages, "; "-separated
    # --- extra columns (after the contract's) ---
    deformation_scale: float | None = None  # the run's scale (residuals are scaled motion)
    model_temperatures_json: str | None = None  # {"node": predicted degC} of the model
    frame_path: str | None = None  # archived 16-bit PNG, relative to the data directory
    stage_ms_json: str | None = None  # {"model": ms, "move": ms, ...} wall time per stage
    deformation_sigma_um: float | None = None  # 1-sigma of the prediction (model+ir)
    innovation_nis: float | None = None  # normalised innovation squared of the IR update
    # --- arm runs (issue 20): 6-DOF in the arm's base frame; empty on a two-link run ---
    arm_pose: str | None = None  # the duty cycle's measured pose of this step
    predicted_tx_um: float | None = None  # predicted tool error: translation (um)
    predicted_ty_um: float | None = None
    predicted_tz_um: float | None = None
    predicted_rx_urad: float | None = None  # ... and rotation vector (urad)
    predicted_ry_urad: float | None = None
    predicted_rz_urad: float | None = None
    correction_tx_mm: float | None = None  # commanded correction from the taught pose (mm)
    correction_ty_mm: float | None = None
    correction_tz_mm: float | None = None
    correction_rx_urad: float | None = None  # ... and its rotation vector (urad)
    correction_ry_urad: float | None = None
    correction_rz_urad: float | None = None
    measured_tx_um: float | None = None  # measured tool pose less its reference: translation
    measured_ty_um: float | None = None
    measured_tz_um: float | None = None
    measured_rx_urad: float | None = None  # ... and rotation vector (urad; >= 3 markers)
    measured_ry_urad: float | None = None
    measured_rz_urad: float | None = None
    drift_3d_um: float | None = None  # |measured translation|: the 3-D drift (the residual)
    rotation_error_urad: float | None = None  # |measured rotation|: the rotation error
    measured_sigma_um: float | None = None  # 1-sigma of the 3-D position (sqrt trace cov)
    # the observer's estimates after the IR update: {"heat": [factor, 1-sigma], ...,
    # "offset:REGION": [degC, 1-sigma]} (model+ir; the factors with observer.adapt, issue 19)
    observer_json: str | None = None
    # 1-sigma of the measured orientation (sqrt trace of the pose covariance's rotation block;
    # arm runs, issue 20): the rotation error's noise, as measured_sigma_um is the drift's
    measured_rotation_sigma_urad: float | None = None
    # the room thermometer's reading at the step (degC; issue 29, room.driver): the ambient
    # the arm model followed; empty without a thermometer (the model held model.ambient_c)
    room_c: float | None = None
    # a followed run's motor heat over the model's advance (issue 31, arm.heat_from measured:
    # daemon/run/followed/heat.py): {"from_s", "to_s" (arm time), "joint_w": [W per joint],
    # "source"}; `calibrate model` reads it back; empty: the duty cycle's heat
    heat_json: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


STEP_COLUMNS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(StepRecord))
SQL_TYPES = {"int": "INTEGER", "float": "REAL", "str": "TEXT"}


def column_type(field: dataclasses.Field[Any]) -> str:
    base = str(field.type).split("|")[0].strip()
    return SQL_TYPES[base]


STEPS_SCHEMA = (
    "CREATE TABLE IF NOT EXISTS steps ("
    + ", ".join(f"{f.name} {column_type(f)}" for f in dataclasses.fields(StepRecord))
    + ", PRIMARY KEY (run_id, step), FOREIGN KEY (run_id) REFERENCES runs(id))"
)


#: Every flag a step record's ``flags`` column can carry (comma-separated), with its meaning;
#: the documentation's step reference is generated from this table, and a test checks that
#: every flag the step code appends is listed here.
STEP_FLAGS: dict[str, str] = {
    "late": "the step began more than a tenth of a period after its deadline",
    "unsafe-target": "the target (offset or 6-DOF correction) failed a check and was not sent; "
    "the run pauses",
    "robot-error": "the move or its read-back failed",
    "no-readback": "the move was not read back (robot.readback_every > 1): no pose recorded",
    "camera-error": "no frame within camera.grab_timeout_s, or the frame was refused",
    "stale-frame": "the frame was older than camera.max_age_s: recorded, never used",
    "host-timestamp": "the frame's time is when the driver received it, not its exposure "
    "(the backend gave no better stamp)",
    "centroid-error": "no spot could be measured in the frame",
    "marker-error": "arm runs: the tool's markers could not be measured into a pose",
    "first-step-reference": "arm runs: no reference was measured at this pose before the "
    "first correction; this step's measurement is its zero (drift 0 by construction), and the "
    "run's summary lists the pose under reference.missing",
    "ir-error": "no IR reading within ir.read_timeout_s, or the reading was refused",
    "stale-ir": "the IR reading was older than ir.max_age_s: recorded, never fused",
    "room-error": "arm runs: the room thermometer gave no reading; the model kept the last room",
    "no-measurement": "followed runs: no camera measured the tool this step (the correction is the "
    "model's alone)",
    "moved-during-frames": "followed runs: the robot's program left its measured pose (or was "
    "not at rest) while the tool cameras' frames were taken: the measurement was discarded",
    "measuring": "followed runs: this step started a measurement of the tool that was not in "
    "when the row was written; the row is written again when it is (this flag then gives way "
    "to the measurement, or to the reason it was discarded)",
    "model-drifting": "the IR observer's innovations stay biased: consider identification",
    "bench-truth": "followed runs on the UR bench: measured_* is the bench truth's residual "
    "tool error (no camera noise), not a camera measurement",
}
