"""An arm run's summary (issue 20): its basis, what only the running daemon's memory holds
(daemon/run/summary.py SummaryBasis), and the summary from the basis and the steps read back
(at the run's end, or at the next start for a deferred one)."""

from __future__ import annotations

import threading
from typing import Any

from daemon.analysis.arm import room_summary, summarize_arm_run
from daemon.run.arm.work import ArmRunWork
from daemon.run.summary import (
    SUMMARY_COLUMNS,
    SummaryBasis,
    SummaryRow,
    measured_basis,
    measured_summary,
    reference_steps,
)
from daemon.storage.recorder import Recorder


def arm_basis(
    work: ArmRunWork, *, kind: str, overruns: int, skipped: int, timing: dict[str, Any]
) -> SummaryBasis:
    """An arm run's summary basis (memory only), with the model's warnings and the online
    adaptation's last estimates (issue 29), which only the running predictor knows."""
    parameters = work.parameters
    after: dict[str, Any] = {}
    identified = getattr(work.predictor, "identified", None)
    if identified is not None:
        after["arm_model_warning"] = identified.warning or None
        after["arm_model_implausible"] = list(identified.implausible)
    estimates = getattr(work.predictor, "adaptation_estimates", None)
    if callable(estimates) and getattr(work.predictor, "adapting", False):
        after["adaptation"] = estimates()
    return measured_basis(
        kind,
        work.run_id,
        parameters,
        overruns=overruns,
        skipped=skipped,
        timing=timing,
        fixed={
            "duty_cycle": parameters.duty_cycle,
            "measured_poses": [pose.name for pose in work.poses],
        },
        # a pose with no reference measured: its zero is its first step (flagged
        # first-step-reference), its drift before that step unseen; said, never silent
        reference={"source": work.reference_source, "missing": dict(work.missing_references)},
        after=after,
    )


def arm_summary(
    recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
) -> dict[str, Any]:
    """An arm run's summary (issue 20): the 3-D drift and the rotation error (largest, RMS),
    overall and per measured pose, the largest predicted tool error, and the reduction of the
    3-D drift against a named uncompensated run of the same duty cycle."""
    inputs, run_id = basis["inputs"], basis["run_id"]
    steps = recorder.run_series(run_id, SUMMARY_COLUMNS, abandon)
    drift_run = inputs["reference_run"]
    figures = summarize_arm_run(
        steps,
        recorder.arm_poses(run_id),
        compensation=inputs["compensation"],
        reference=reference_steps(recorder, drift_run),
        reference_run=drift_run,
    )
    return measured_summary(basis, steps, dict(figures), {"room": room_summary(steps)})


def arm_summary_rows(summary: dict[str, Any]) -> list[SummaryRow]:
    """An arm run's figures as ``thermocomp run`` prints them: the tool's 3-D drift and
    rotation error."""
    rows: list[SummaryRow] = [
        ("steps measured in 3-D (N)", summary.get("arm_n"), ""),
        ("3-D drift max", summary.get("drift_3d_max_um"), "um"),
        ("3-D drift RMS", summary.get("drift_3d_rms_um"), "um"),
        ("rotation error max", summary.get("rotation_error_max_urad"), "urad"),
        ("rotation error RMS", summary.get("rotation_error_rms_urad"), "urad"),
        ("predicted tool error max", summary.get("predicted_3d_max_um"), "um"),
        ("3-D measurement 1-sigma", summary.get("measurement_sigma_um"), "um"),
        ("rotation meas. 1-sigma", summary.get("measurement_rotation_sigma_urad"), "urad"),
    ]
    if summary.get("reduction_basis") == "reference":
        reference = summary.get("reference_run")
        rows += [
            (f"3-D reduction vs run {reference}", summary.get("reduction_3d_percent"), "%"),
            (f"rotation red. vs run {reference}", summary.get("reduction_rotation_percent"), "%"),
        ]
    return [*rows, ("overruns", summary.get("overruns"), "")]
