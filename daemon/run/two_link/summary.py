"""The two-link run's summary (thesis Table 6.1 and the run's timing): its basis, what only
the running daemon's memory holds (daemon/run/summary.py SummaryBasis), and the summary from the
basis and the steps read back (at the run's end, or at the next start for a deferred one)."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from daemon.analysis import RunSteps, summarize_run
from daemon.run.summary import (
    SUMMARY_COLUMNS,
    SummaryBasis,
    SummaryRow,
    measured_basis,
    measured_summary,
    reference_steps,
)
from daemon.run.two_link.work import RunWork
from daemon.storage.recorder import Recorder


def two_link_basis(
    work: RunWork, *, kind: str, overruns: int, skipped: int, timing: dict[str, Any]
) -> SummaryBasis:
    """A two-link run's summary basis (memory only: cheap, on the event loop)."""
    parameters = work.parameters
    reference = work.reference_um.get(0, (None, None))
    goal = work.goal
    return measured_basis(
        kind,
        work.run_id,
        parameters,
        overruns=overruns,
        skipped=skipped,
        timing=timing,
        reference={"source": work.reference_source, "x_um": reference[0], "y_um": reference[1]},
        inputs={
            "procedure": parameters.procedure,
            "goal_mm": None if goal is None else list(map(float, goal.position)),
            "direction": list(map(float, work.direction)),
        },
    )


def two_link_summary(
    recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
) -> dict[str, Any]:
    """Table 6.1's figures and the run's timing. The steps are columns read chunk by chunk
    (daemon/storage/series.py), never one record object per step: a day at a 20 ms step is
    4.32 M steps (benchmarks/bench_stop.py). ``abandon`` gives the read up (shutdown)."""
    inputs = basis["inputs"]
    steps = recorder.run_series(basis["run_id"], SUMMARY_COLUMNS, abandon)
    # the reduction against a measured uncompensated run, when the run names one (checked
    # at its start: ended, compensation off, same scale); otherwise against the prediction
    drift_run = inputs["reference_run"]
    figures = summarize_run(
        steps,
        compensation=inputs["compensation"],
        reference=reference_steps(recorder, drift_run),
        reference_run=drift_run,
    )
    own = {"uncompensated_measured_max_um": measured_uncompensated_max_um(inputs, steps)}
    return measured_summary(basis, steps, dict(figures), own)


def measured_uncompensated_max_um(inputs: dict[str, Any], steps: RunSteps) -> float | None:
    """The largest drift the spot would have shown without the compensating moves: the
    measured residual less the robot's actual displacement from the goal along the link
    (issue 6 summary; stationary runs only, where the goal is the only pose)."""
    goal_mm = inputs["goal_mm"]
    if goal_mm is None or inputs["procedure"] != "stationary" or steps.n_steps == 0:
        return None
    poses_mm = np.column_stack([steps.column(f"pose_{axis}_mm") for axis in "xyz"])
    direction = np.asarray(inputs["direction"], dtype=float)
    displacement_um = 1000.0 * (poses_mm - np.asarray(goal_mm, dtype=float)) @ direction
    values = steps.residual_um - displacement_um
    values = values[np.isfinite(values)]  # steps with no residual or no pose read back
    return float(np.abs(values).max()) if values.size else None


def two_link_summary_rows(summary: dict[str, Any]) -> list[SummaryRow]:
    """A two-link run's figures as ``thermocomp run`` prints them: the residual's statistics
    (thesis Table 6.1) and the drift or reduction they are measured against."""
    return [
        ("steps with a residual (N)", summary.get("n"), ""),
        ("residual max |x|", summary.get("residual_max_um"), "um"),
        ("residual mean x-bar", summary.get("residual_mean_um"), "um"),
        ("residual std S_x", summary.get("residual_std_um"), "um"),
        ("std of the mean S_x-bar", summary.get("residual_std_mean_um"), "um"),
        *_reduction_rows(summary),
        ("overruns", summary.get("overruns"), ""),
    ]


def _reduction_rows(summary: dict[str, Any]) -> list[SummaryRow]:
    """The drift or reduction lines, named after what they are measured against."""
    basis = summary.get("reduction_basis")
    if basis == "drift":
        return [("measured drift max (off)", summary.get("measured_drift_max_um"), "um")]
    rows: list[SummaryRow] = [
        ("predicted deformation max", summary.get("uncompensated_max_um"), "um"),
        ("  measured (drift - moves)", summary.get("uncompensated_measured_max_um"), "um"),
    ]
    if basis == "reference":
        rows += [
            (
                f"reference run {summary.get('reference_run')} drift",
                summary.get("reference_max_um"),
                "um",
            ),
            ("  over the first", summary.get("reference_span_s"), "s"),
            ("reduction (measured)", summary.get("reduction_percent"), "%"),
        ]
    rows.append(("vs the prediction", summary.get("reduction_vs_prediction_percent"), "%"))
    return rows
