"""The end-of-run summary (thesis Table 6.1 and the run's timing), read back from the database."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
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


#: What a run's summary needs beyond its steps: what only the running daemon's memory holds
#: (overruns, skipped deadlines, the timing, the kind's own figures), JSON-able so that a
#: summary a shutdown gives up is computed at the next start from the same values
#: (daemon/storage/recorder.py ``pending_summaries``). Keys: ``kind`` (the run kind's name),
#: ``run_id``, ``fixed`` (the summary's entries known without the steps, in order), ``inputs``
#: (what the reading of the steps needs), ``after`` (entries that follow the steps' own).
SummaryBasis = dict[str, Any]
SummaryFunction = Callable[[Recorder, SummaryBasis, threading.Event | None], dict[str, Any]]


def two_link_basis(
    work: RunWork, *, kind: str, overruns: int, skipped: int, timing: dict[str, Any]
) -> SummaryBasis:
    """A two-link run's summary basis (memory only: cheap, on the event loop)."""
    parameters = work.parameters
    reference = work.reference_um.get(0, (None, None))
    goal = work.goal
    return {
        "kind": kind,
        "run_id": work.run_id,
        "fixed": {
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
        },
        "inputs": {
            "compensation": parameters.compensation,
            "reference_run": parameters.reference_run,
            "timing": timing,
            "procedure": parameters.procedure,
            "goal_mm": None if goal is None else list(map(float, goal.position)),
            "direction": list(map(float, work.direction)),
        },
        "after": {},
    }


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
    summary: dict[str, Any] = dict(
        summarize_run(
            steps,
            compensation=inputs["compensation"],
            reference=_reference_steps(recorder, drift_run),
            reference_run=drift_run,
        )
    )
    summary.update(
        {
            "steps": steps.n_steps,
            **basis["fixed"],
            "uncompensated_measured_max_um": measured_uncompensated_max_um(inputs, steps),
            "timing": _timing(inputs["timing"], steps),
            **basis["after"],
        }
    )
    return summary


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
    return {
        "kind": kind,
        "run_id": work.run_id,
        "fixed": {
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
        },
        "inputs": {
            "compensation": parameters.compensation,
            "reference_run": parameters.reference_run,
            "timing": timing,
        },
        "after": after,
    }


def arm_summary(
    recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
) -> dict[str, Any]:
    """An arm run's summary (issue 20): the 3-D drift and the rotation error (largest, RMS),
    overall and per measured pose, the largest predicted tool error, and the reduction of the
    3-D drift against a named uncompensated run of the same duty cycle."""
    inputs, run_id = basis["inputs"], basis["run_id"]
    steps = recorder.run_series(run_id, SUMMARY_COLUMNS, abandon)
    drift_run = inputs["reference_run"]
    summary: dict[str, Any] = dict(
        summarize_arm_run(
            steps,
            recorder.arm_poses(run_id),
            compensation=inputs["compensation"],
            reference=_reference_steps(recorder, drift_run),
            reference_run=drift_run,
        )
    )
    summary.update(
        {
            "steps": steps.n_steps,
            **basis["fixed"],
            "room": room_summary(steps),
            "timing": _timing(inputs["timing"], steps),
            **basis["after"],
        }
    )
    return summary


def fixed_summary(
    recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
) -> dict[str, Any]:
    """The summary of a kind whose figures are all in memory (no steps to read back)."""
    return {**basis["fixed"], **basis["after"]}


def summary_from_basis(
    recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
) -> dict[str, Any]:
    """A run's summary from its basis and the database: at the run's end, and at the next
    start for a summary a shutdown deferred (the same values, so the same summary)."""
    compute = _SUMMARIES.get(basis.get("kind", ""), fixed_summary)
    return compute(recorder, basis, abandon)


def _reference_steps(recorder: Recorder, drift_run: int | None) -> RunSteps | None:
    """The steps of the measured uncompensated run a run's reduction is against, if it names
    one (checked at its start: ended, compensation off, same scale)."""
    return None if drift_run is None else recorder.run_series(drift_run, SUMMARY_COLUMNS)


def _timing(timing: dict[str, Any], steps: RunSteps) -> dict[str, Any]:
    """The run's timing with the lateness percentiles over every step of the run, not only
    the recent window."""
    return {**timing, "lateness_s": percentiles(steps.numeric.get("lateness_s", ()))}


def stored_basis(basis: SummaryBasis) -> SummaryBasis:
    """The basis as it reads back from the database (tuples as lists, numpy scalars and
    arrays as Python values; what the recorder's JSON cannot say, as text): the summary at the
    end and the deferred one are computed from the same values."""
    result: SummaryBasis = json.loads(json.dumps(basis, default=_plain, allow_nan=True))
    return result


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    return str(value)  # as the recorder writes it (daemon/storage/recorder.py _dumps)


#: The summary of each run kind that reads its steps back, by the kind's name (the kinds'
#: ``name``, daemon/run/kinds.py); any other kind's summary is its basis alone.
_SUMMARIES: dict[str, SummaryFunction] = {"two-link": two_link_summary, "arm": arm_summary}
