"""The end-of-run summary (thesis Table 6.1 and the run's timing), read back from the database:
what every kind's summary shares. Each kind computes its own (its ``summary_from_basis``:
daemon/run/two_link/summary.py, daemon/run/arm/summary.py, or :func:`fixed_summary`), and the
factory finds it by the kind's name for a summary a shutdown deferred (daemon/run/kinds.py)."""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from daemon.analysis import NUMERIC_COLUMNS, RunSteps
from daemon.run.scheduler import percentiles
from daemon.run.states import RunParameters
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
#: One figure of a summary as ``thermocomp run`` prints it: label, value, unit.
SummaryRow = tuple[str, object, str]
SummaryFunction = Callable[[Recorder, SummaryBasis, threading.Event | None], dict[str, Any]]


def fixed_summary(
    recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
) -> dict[str, Any]:
    """The summary of a kind whose figures are all in memory (no steps to read back)."""
    return {**basis["fixed"], **basis["after"]}


def measured_basis(
    kind: str,
    run_id: int,
    parameters: RunParameters,
    *,
    overruns: int,
    skipped: int,
    timing: dict[str, Any],
    reference: dict[str, Any],
    fixed: dict[str, Any] | None = None,
    inputs: dict[str, Any] | None = None,
    after: dict[str, Any] | None = None,
) -> SummaryBasis:
    """The summary basis of a kind that measures a drift against a reference (the two-link
    bench's and the arm's): the entries every such summary has, with the kind's own ``fixed``
    entries (after the compensation), its ``reference`` (after its ``source``), its ``inputs``
    and its ``after`` entries."""
    return {
        "kind": kind,
        "run_id": run_id,
        "fixed": {
            "deformation_scale": parameters.deformation_scale,
            "compensation": parameters.compensation,
            **(fixed or {}),
            "step_s": parameters.step_s,
            "overruns": overruns,
            "skipped_deadlines": skipped,
            "reference": reference,
        },
        "inputs": {
            "compensation": parameters.compensation,
            "reference_run": parameters.reference_run,
            "timing": timing,
            **(inputs or {}),
        },
        "after": after or {},
    }


def measured_summary(
    basis: SummaryBasis, steps: RunSteps, figures: dict[str, Any], own: dict[str, Any]
) -> dict[str, Any]:
    """A measured kind's summary: its ``figures`` from the steps, then the entries every such
    summary has -- the number of steps, the basis's fixed entries, the kind's ``own``, the
    timing over every step, the basis's after entries."""
    return {
        **figures,
        "steps": steps.n_steps,
        **basis["fixed"],
        **own,
        "timing": timing_over_steps(basis["inputs"]["timing"], steps),
        **basis["after"],
    }


def reference_steps(recorder: Recorder, drift_run: int | None) -> RunSteps | None:
    """The steps of the measured uncompensated run a run's reduction is against, if it names
    one (checked at its start: ended, compensation off, same scale)."""
    return None if drift_run is None else recorder.run_series(drift_run, SUMMARY_COLUMNS)


def timing_over_steps(timing: dict[str, Any], steps: RunSteps) -> dict[str, Any]:
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
