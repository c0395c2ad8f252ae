"""An arm run's figures (issue 20): the 3-D drift and the rotation error of the tool, overall
and per measured pose, and their reduction against an uncompensated run. Pure.

The drift of a step is its measured tool pose less the one measured at the same taught goal
before the first correction (daemon/run/arm/step.py): in a compensated run it is the residual of
the compensation, in an uncompensated one the arm's thermal drift. The reduction is the
thesis's (6.7: ``100 (1 - max error / max uncompensated)``) on the 3-D norms, over the time
both runs cover, and likewise for the rotation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from daemon.analysis.steps import FloatArray, RunSteps

#: The arm summary's keys (each None when it cannot be computed).
ARM_SUMMARY_KEYS: tuple[str, ...] = (
    "arm_n",
    "drift_3d_max_um",
    "drift_3d_rms_um",
    "rotation_error_max_urad",
    "rotation_error_rms_urad",
    "predicted_3d_max_um",
    "predicted_rotation_max_urad",
    "reference_drift_3d_max_um",
    "reference_rotation_max_urad",
    "reference_span_s",
    "reduction_3d_percent",
    "reduction_rotation_percent",
    "measurement_sigma_um",
    "measurement_rotation_sigma_urad",
)


def is_arm_run(steps: RunSteps) -> bool:
    """Whether the steps are an arm run's: some step carries a 6-DOF prediction."""
    column = steps.numeric.get("predicted_tx_um")
    return column is not None and bool(np.isfinite(column).any())


def _finite(values: FloatArray) -> FloatArray:
    finite: FloatArray = values[np.isfinite(values)]
    return finite


def _max(values: FloatArray) -> float | None:
    finite = _finite(values)
    return float(np.abs(finite).max()) if finite.size else None


def _rms(values: FloatArray) -> float | None:
    finite = _finite(values)
    return float(math.sqrt(np.mean(finite**2))) if finite.size else None


def _norms(steps: RunSteps, prefix: str, unit: str, axes: Sequence[str]) -> FloatArray:
    columns = [steps.numeric.get(f"{prefix}_{axis}_{unit}") for axis in axes]
    if any(column is None for column in columns):
        return np.full(steps.n_steps, np.nan)
    stacked = np.column_stack([c for c in columns if c is not None])
    norms: FloatArray = np.linalg.norm(stacked, axis=1)
    return norms


def _column(steps: RunSteps, name: str) -> FloatArray:
    return steps.numeric.get(name, np.full(steps.n_steps, np.nan))


def _reduction(ours: float | None, theirs: float | None) -> float | None:
    if ours is None or theirs is None or theirs <= 0:
        return None
    return 100.0 * (1.0 - ours / theirs)


def summarize_arm_run(
    steps: RunSteps,
    poses: Sequence[str | None] = (),
    *,
    compensation: str | None = None,
    reference: RunSteps | None = None,
    reference_run: int | str | None = None,
) -> dict[str, object]:
    """The arm run's figures (ARM_SUMMARY_KEYS), ``per_pose`` (pose -> n, largest and RMS
    3-D drift and rotation error) when ``poses`` names each step's pose, and the
    ``reduction_basis``: "reference" (against ``reference``, an uncompensated run), "drift"
    (this run is uncompensated: its figures are the drift) or "none"."""
    summary: dict[str, object] = dict.fromkeys(ARM_SUMMARY_KEYS)
    drift = _column(steps, "drift_3d_um")
    rotation = _column(steps, "rotation_error_urad")
    summary["arm_n"] = int(np.isfinite(drift).sum())
    summary["drift_3d_max_um"] = _max(drift)
    summary["drift_3d_rms_um"] = _rms(drift)
    summary["rotation_error_max_urad"] = _max(rotation)
    summary["rotation_error_rms_urad"] = _rms(rotation)
    summary["predicted_3d_max_um"] = _max(_norms(steps, "predicted", "um", ("tx", "ty", "tz")))
    summary["predicted_rotation_max_urad"] = _max(
        _norms(steps, "predicted", "urad", ("rx", "ry", "rz"))
    )
    sigma = _finite(_column(steps, "measured_sigma_um"))
    summary["measurement_sigma_um"] = float(np.median(sigma)) if sigma.size else None
    # the rotation error's own noise: a rotation error (or its reduction) at this level is the
    # cameras', not the arm's (four markers 120 mm apart: tens of urad per frame)
    rotation_sigma = _finite(_column(steps, "measured_rotation_sigma_urad"))
    summary["measurement_rotation_sigma_urad"] = (
        float(np.median(rotation_sigma)) if rotation_sigma.size else None
    )
    summary["reference_run"] = None
    summary["reduction_basis"] = "drift" if compensation == "off" else "none"
    if reference is not None and compensation != "off":
        summary["reduction_basis"] = "reference"
        summary["reference_run"] = reference_run if reference_run is not None else reference.run_id
        span = float(min(np.nanmax(steps.time_s), np.nanmax(reference.time_s)))
        summary["reference_span_s"] = span
        ours, theirs = steps.time_s <= span, reference.time_s <= span
        reference_drift = _max(_column(reference, "drift_3d_um")[theirs])
        reference_rotation = _max(_column(reference, "rotation_error_urad")[theirs])
        summary["reference_drift_3d_max_um"] = reference_drift
        summary["reference_rotation_max_urad"] = reference_rotation
        summary["reduction_3d_percent"] = _reduction(_max(drift[ours]), reference_drift)
        summary["reduction_rotation_percent"] = _reduction(_max(rotation[ours]), reference_rotation)
    if len(poses) == steps.n_steps and steps.n_steps:
        names = np.array([name or "" for name in poses])
        summary["per_pose"] = {
            str(name): {
                "n": int(np.isfinite(drift[names == name]).sum()),
                "drift_3d_max_um": _max(drift[names == name]),
                "drift_3d_rms_um": _rms(drift[names == name]),
                "rotation_error_max_urad": _max(rotation[names == name]),
                "rotation_error_rms_urad": _rms(rotation[names == name]),
            }
            for name in dict.fromkeys(names.tolist())
            if name
        }
    return summary


ARM_LABELS: dict[str, tuple[str, str]] = {
    "arm_n": ("steps with a 3-D measurement", ""),
    "drift_3d_max_um": ("largest 3-D drift (residual when compensated)", "µm"),
    "drift_3d_rms_um": ("RMS 3-D drift", "µm"),
    "rotation_error_max_urad": ("largest rotation error", "µrad"),
    "rotation_error_rms_urad": ("RMS rotation error", "µrad"),
    "predicted_3d_max_um": ("largest predicted tool error (translation)", "µm"),
    "predicted_rotation_max_urad": ("largest predicted tool error (rotation)", "µrad"),
    "reference_drift_3d_max_um": ("reference run: largest 3-D drift", "µm"),
    "reference_rotation_max_urad": ("reference run: largest rotation error", "µrad"),
    "reference_span_s": ("run time both runs cover", "s"),
    "reduction_3d_percent": ("reduction of the 3-D drift", "%"),
    "reduction_rotation_percent": ("reduction of the rotation error", "%"),
    "measurement_sigma_um": ("3-D measurement 1-sigma (median)", "µm"),
    "measurement_rotation_sigma_urad": ("rotation measurement 1-sigma (median)", "µrad"),
}


#: What the summary of a run without a room thermometer says (issue 29).
NO_ROOM_NOTE = (
    "no room thermometer: the arm model held its configured ambient (model.ambient_c) for "
    "the whole run, so a room that warms or cools was not followed (room.driver)"
)


def room_summary(steps: RunSteps) -> dict[str, object]:
    """The room as the run's thermometer read it (issue 29): ``measured`` and the readings'
    count, first, last, lowest and highest (degC), or ``measured`` False and a note saying the
    model held its configured ambient."""
    room = _finite(_column(steps, "room_c"))
    if not room.size:
        return {"measured": False, "readings": 0, "note": NO_ROOM_NOTE}
    return {
        "measured": True,
        "readings": int(room.size),
        "first_c": float(room[0]),
        "last_c": float(room[-1]),
        "min_c": float(room.min()),
        "max_c": float(room.max()),
    }
