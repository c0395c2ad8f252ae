"""The end-of-run summary (thesis Table 6.1 and the run's timing), read back from the database."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from daemon.analysis import NUMERIC_COLUMNS, RunSteps, summarize_run
from daemon.analysis.arm import room_summary, summarize_arm_run
from daemon.run.arm.step import ArmRunWork
from daemon.run.scheduler import percentiles
from daemon.run.two_link.step import RunWork
from daemon.storage.recorder import Recorder

#: What the summary reads of the steps: no JSON columns (temperatures, IR, stage timings),
#: which cost most of the time to read back.
SUMMARY_COLUMNS = (*NUMERIC_COLUMNS, "run_id", "flags", "error")


def two_link_summary(
    recorder: Recorder,
    work: RunWork,
    *,
    overruns: int,
    skipped: int,
    timing: dict[str, Any],
    abandon: threading.Event | None = None,
) -> dict[str, Any]:
    """Table 6.1's figures and the run's timing. The steps are columns read chunk by chunk
    (daemon/storage/series.py), never one record object per step: a day at a 20 ms step is
    4.32 M steps (benchmarks/bench_stop.py). ``abandon`` gives the read up (shutdown)."""
    steps = recorder.run_series(work.run_id, SUMMARY_COLUMNS, abandon)
    parameters = work.parameters
    reference = work.reference_um.get(0, (None, None))
    # the reduction against a measured uncompensated run, when the run names one (checked
    # at its start: ended, compensation off, same scale); otherwise against the prediction
    drift_run = parameters.reference_run
    summary: dict[str, Any] = dict(
        summarize_run(
            steps,
            compensation=parameters.compensation,
            reference=_reference_steps(recorder, drift_run),
            reference_run=drift_run,
        )
    )
    summary.update(
        {
            "steps": steps.n_steps,
            "deformation_scale": parameters.deformation_scale,
            "compensation": parameters.compensation,
            "step_s": parameters.step_s,
            "overruns": overruns,
            "skipped_deadlines": skipped,
            "reference": {
                "source": work.reference_source,
                "x_um": reference[0],
                "y_um": reference[1],
            },
            "uncompensated_measured_max_um": measured_uncompensated_max_um(work, steps),
            "timing": _timing(timing, steps),
        }
    )
    return summary


def measured_uncompensated_max_um(work: RunWork, steps: RunSteps) -> float | None:
    """The largest drift the spot would have shown without the compensating moves: the
    measured residual less the robot's actual displacement from the goal along the link
    (issue 6 summary; stationary runs only, where the goal is the only pose)."""
    goal = work.goal
    if goal is None or work.parameters.procedure != "stationary" or steps.n_steps == 0:
        return None
    poses_mm = np.column_stack([steps.column(f"pose_{axis}_mm") for axis in "xyz"])
    displacement_um = 1000.0 * (poses_mm - np.asarray(goal.position)) @ work.direction
    values = steps.residual_um - displacement_um
    values = values[np.isfinite(values)]  # steps with no residual or no pose read back
    return float(np.abs(values).max()) if values.size else None


def arm_summary(
    recorder: Recorder,
    work: ArmRunWork,
    *,
    overruns: int,
    skipped: int,
    timing: dict[str, Any],
    abandon: threading.Event | None = None,
) -> dict[str, Any]:
    """An arm run's summary (issue 20): the 3-D drift and the rotation error (largest, RMS),
    overall and per measured pose, the largest predicted tool error, and the reduction of the
    3-D drift against a named uncompensated run of the same duty cycle."""
    steps = recorder.run_series(work.run_id, SUMMARY_COLUMNS, abandon)
    parameters = work.parameters
    drift_run = parameters.reference_run
    summary: dict[str, Any] = dict(
        summarize_arm_run(
            steps,
            recorder.arm_poses(work.run_id),
            compensation=parameters.compensation,
            reference=_reference_steps(recorder, drift_run),
            reference_run=drift_run,
        )
    )
    summary.update(
        {
            "steps": steps.n_steps,
            "deformation_scale": parameters.deformation_scale,
            "compensation": parameters.compensation,
            "duty_cycle": parameters.duty_cycle,
            "measured_poses": [pose.name for pose in work.poses],
            "step_s": parameters.step_s,
            "overruns": overruns,
            "skipped_deadlines": skipped,
            # a pose with no reference measured: its zero is its first step (flagged
            # first-step-reference), its drift before that step unseen; said, never silent
            "reference": {
                "source": work.reference_source,
                "missing": dict(work.missing_references),
            },
            "room": room_summary(steps),
            "timing": _timing(timing, steps),
        }
    )
    # issue 29: a model that is not fully calibrated says so in every run that uses it, and
    # the online adaptation's last estimates (arm.adapt)
    identified = getattr(work.predictor, "identified", None)
    if identified is not None:
        summary["arm_model_warning"] = identified.warning or None
        summary["arm_model_implausible"] = list(identified.implausible)
    estimates = getattr(work.predictor, "adaptation_estimates", None)
    if callable(estimates) and getattr(work.predictor, "adapting", False):
        summary["adaptation"] = estimates()
    return summary


def _reference_steps(recorder: Recorder, drift_run: int | None) -> RunSteps | None:
    """The steps of the measured uncompensated run a run's reduction is against, if it names
    one (checked at its start: ended, compensation off, same scale)."""
    return None if drift_run is None else recorder.run_series(drift_run, SUMMARY_COLUMNS)


def _timing(timing: dict[str, Any], steps: RunSteps) -> dict[str, Any]:
    """The run's timing with the lateness percentiles over every step of the run, not only
    the recent window."""
    return {**timing, "lateness_s": percentiles(steps.numeric.get("lateness_s", ()))}
