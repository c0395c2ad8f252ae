"""The run report: PNG figures, ``summary.json`` and one HTML page showing them with tables.

The page carries its own style and no scripts or external resources; it references the PNGs
beside it by relative name (or embeds them, ``embed_images=True``, for a single-file copy).
Writing is blocking (matplotlib, files): the daemon calls :func:`write_report` in a thread.
"""

from __future__ import annotations

import base64
import json
import logging
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from daemon.analysis.arm import is_arm_run, summarize_arm_run
from daemon.analysis.arm_plots import draw_arm_error, draw_arm_temperatures
from daemon.analysis.budget_report import budget_section, with_section
from daemon.analysis.fits import FitError, direction_of, fit_exponential
from daemon.analysis.plots import (
    plot_compensated_vs_uncompensated,
    plot_compensation,
    plot_error_histogram,
    plot_lateness,
    plot_temperatures,
)
from daemon.analysis.removed import drift_removed
from daemon.analysis.report_arm import arm_page
from daemon.analysis.report_page import two_link_page
from daemon.analysis.statistics import ErrorStatistics, error_statistics
from daemon.analysis.steps import FloatArray, RunSteps, steps_from_rows, summarize_run

logger = logging.getLogger(__name__)

SUMMARY_FILE = "summary.json"
HTML_FILE = "report.html"
DPI = 100


@dataclass(frozen=True)
class ReportFiles:
    """Where a report was written."""

    directory: Path
    html: Path
    summary: Path
    plots: dict[str, Path]  # figure name -> PNG path


@dataclass(frozen=True)
class _Inputs:
    """What a figure is drawn from."""

    steps: RunSteps
    stats: ErrorStatistics | None
    summary: dict[str, float | int | str | None]  # the run summary (Table 6.1's keys)
    reference: RunSteps | None
    reference_run: int | str | None


@dataclass(frozen=True)
class _Plot:
    name: str
    caption: Callable[[_Inputs], str]
    draw: Callable[[_Inputs], Figure]


def _uncompensated_caption(given: _Inputs) -> str:
    if given.reference is not None:
        return (
            "Where the tool went without compensation, measured by the uncompensated run "
            f"{given.reference_run}, against where it went with it (thesis Figure 6.9); the "
            "model's prediction dashed."
        )
    return (
        "Where the model predicts the tool would have gone without compensation (no "
        "uncompensated reference run was named: the curve is predicted, not measured) against "
        "where it went with it (thesis Figure 6.9)."
    )


LATENESS = _Plot(
    "lateness",
    lambda given: "How long after its scheduled time each step started.",
    lambda given: plot_lateness(given.steps),
)

TWO_LINK_PLOTS: tuple[_Plot, ...] = (
    _Plot(
        "compensation",
        lambda given: (
            "Deformation input (model prediction), commanded compensation and "
            "measured error over time, as thesis Figures 6.5-6.7. A perfect compensation mirrors "
            "the deformation and leaves zero error."
        ),
        lambda given: plot_compensation(given.steps, given.stats),
    ),
    _Plot(
        "compensated_vs_uncompensated",
        _uncompensated_caption,
        lambda given: plot_compensated_vs_uncompensated(
            given.steps, given.summary, given.reference
        ),
    ),
    _Plot(
        "error_histogram",
        lambda given: (
            "Histogram of the error over K = 1.87 (N-1)^0.40 + 1 intervals with the "
            "normal distribution of the sample's mean and S_x (thesis Figure 6.8, section 6.6)."
        ),
        lambda given: plot_error_histogram(given.stats),
    ),
    _Plot(
        "temperatures",
        lambda given: (
            "Mean temperature of each infrared region (thick lines) and, when "
            "recorded, of each model node (dashed, coloured by node number along the link)."
        ),
        lambda given: plot_temperatures(given.steps),
    ),
    LATENESS,
)

ARM_PLOTS: tuple[_Plot, ...] = (
    _Plot(
        "arm_drift",
        lambda given: (
            "The tool's measured 3-D drift from its pose at the start, per measured "
            "pose, over the hours of the arm's warm-up; the band is ±1σ of the measurement, "
            "dotted the model's predicted tool error"
            + (
                f", dashed the uncompensated run {given.reference_run}'s measured drift."
                if given.reference is not None
                else "."
            )
        ),
        lambda given: draw_arm_error(
            given.steps, what="drift", reference=given.reference, reference_run=given.reference_run
        ),
    ),
    _Plot(
        "arm_rotation",
        lambda given: (
            "The tool's measured rotation error per measured pose; the band is ±1σ "
            "of the measurement (a rotation error inside it is the cameras' noise, not the arm's)."
        ),
        lambda given: draw_arm_error(
            given.steps,
            what="rotation",
            reference=given.reference,
            reference_run=given.reference_run,
        ),
    ),
    _Plot(
        "arm_temperatures",
        lambda given: (
            "The model's mean temperature of each link and joint and the measured IR regions."
        ),
        lambda given: draw_arm_temperatures(given.steps),
    ),
    LATENESS,
)


#: The clock setting (``bench.clock``) on which simulated time jumps to each deadline.
VIRTUAL_CLOCK = "virtual"


def lateness_note(steps: RunSteps, clock: str | None) -> str | None:
    """Why the lateness figure would say nothing, or None when it is worth drawing.

    On the virtual clock (``bench.clock = "virtual"``) simulated time jumps to each step's
    deadline, so every step starts exactly on time: a flat line at zero. A CSV export does
    not carry the settings; there a lateness of exactly 0 s on every step tells the same."""
    if clock == VIRTUAL_CLOCK:
        return (
            'This run used a virtual clock (bench.clock = "virtual"): simulated time jumps '
            "to each step's scheduled time, so every step starts exactly on time and the "
            "lateness measures nothing. No lateness figure."
        )
    lateness = steps.numeric.get("lateness_s")
    if clock is None and lateness is not None:
        finite = lateness[np.isfinite(lateness)]
        if finite.size and not finite.any():
            return (
                "Every step started exactly at its scheduled time (lateness 0 s): the run "
                "used a virtual clock, on which lateness measures nothing. No lateness figure."
            )
    return None


def _json_safe(value: object) -> object:
    """NaN and infinity are not JSON: they become null."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


def _fit_summary(times: FloatArray, values: FloatArray) -> dict[str, object]:
    finite = np.isfinite(times) & np.isfinite(values)
    if finite.sum() < 4 or np.ptp(values[finite]) == 0:
        return {"error": "not enough varying data to fit"}
    try:
        fit = fit_exponential(times, values, direction_of(values[finite]))
    except FitError as err:
        return {"error": str(err)}
    if abs(fit.curve.amplitude) < 3 * fit.amplitude_stderr:
        # A flat, noisy signal still "fits"; its time constant would mean nothing.
        return {"error": "no significant change (|A| < 3 standard errors)"}
    return fit.to_dict()


def build_summary(
    steps: RunSteps,
    *,
    compensation: str | None = None,
    reference: RunSteps | None = None,
    reference_run: int | str | None = None,
) -> tuple[dict[str, object], ErrorStatistics | None]:
    """Everything the report states in numbers: Table 6.1 (its reduction against the
    uncompensated ``reference`` run when given, see :func:`summarize_run`), the chi-squared
    test, the time constants and steady-state times, and counts of flagged steps."""
    run_summary = summarize_run(
        steps, compensation=compensation, reference=reference, reference_run=reference_run
    )
    stats: ErrorStatistics | None = None
    statistics: dict[str, object] | None = None
    try:
        stats = error_statistics(steps.residual_um)
        statistics = stats.to_dict()
    except ValueError as err:
        statistics = {"error": str(err)}
    times = steps.time_s
    fits: dict[str, object] = {
        "deformation_input_um": _fit_summary(times, steps.deformation_input_um)
    }
    for region, series in steps.ir_mean_c.items():
        fits[f"ir_{region}_mean_c"] = _fit_summary(times, series)
    flag_names = sorted({flag for flags in steps.flags for flag in flags})
    summary: dict[str, object] = {
        "run_id": steps.run_id,
        "steps": steps.n_steps,
        "run_summary": run_summary,
        "statistics": statistics,
        "fits": fits,
        "flags": {flag: steps.flag_count(flag) for flag in flag_names},
        "steps_with_error": sum(bool(e) for e in steps.errors),
    }
    return summary, stats


def write_report(
    rows: Iterable[Mapping[str, object]] | RunSteps,
    out_dir: Path,
    *,
    title: str = "thermocomp run",
    embed_images: bool = False,
    clock: str | None = None,
    compensation: str | None = None,
    reference: RunSteps | None = None,
    reference_run: int | str | None = None,
    budget: Mapping[str, object] | None = None,
) -> ReportFiles:
    """Write the figures, ``summary.json`` and ``report.html`` of one run into ``out_dir``.

    ``rows`` are the run's step records (the columns of daemon/storage/recorder.py's StepRecord).
    ``clock`` is the run's ``bench.clock`` setting when known: on a virtual clock the
    lateness figure is replaced by a line saying why it would be empty. ``compensation`` (the
    run's mode, inferred from its offsets when None), ``reference`` and ``reference_run``
    (an uncompensated run's steps and name) decide what the reduction is measured against
    (:func:`summarize_run`). ``budget``: the set-up's latest measurement error budget (a
    saved budget's document), shown in its own section. Blocking.
    """
    steps = rows if isinstance(rows, RunSteps) else steps_from_rows(rows)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary, stats = build_summary(
        steps, compensation=compensation, reference=reference, reference_run=reference_run
    )
    run_summary = summary["run_summary"]
    assert isinstance(run_summary, dict)
    arm = is_arm_run(steps)
    if arm:  # issue 20: the tool's 3-D drift and rotation error lead
        summary["arm"] = summarize_arm_run(
            steps,
            steps.poses,
            compensation=compensation,
            reference=reference,
            reference_run=reference_run,
        )
        summary["headline"] = drift_removed(
            steps,
            poses=steps.poses,
            compensation=compensation,
            reference=reference,
            reference_run=reference_run if isinstance(reference_run, int) else None,
            so_far=False,
        )["headline"]
    plots: dict[str, Path] = {}
    images: dict[str, str] = {}
    notes: dict[str, str] = {}
    note = lateness_note(steps, clock)
    if note is not None:
        notes["lateness"] = note
    given = _Inputs(steps, stats, run_summary, reference, reference_run)
    chosen = ARM_PLOTS if arm else TWO_LINK_PLOTS
    for plot in ARM_PLOTS + TWO_LINK_PLOTS:  # none of the other kind's left from before
        if plot not in chosen:
            (out_dir / f"{plot.name}.png").unlink(missing_ok=True)
    for plot in chosen:
        path = out_dir / f"{plot.name}.png"
        if plot.name in notes:
            path.unlink(missing_ok=True)  # not a stale one
            continue
        plot.draw(given).savefig(path, dpi=DPI)
        plots[plot.name] = path
        if embed_images:
            encoded = base64.b64encode(path.read_bytes()).decode("ascii")
            images[plot.name] = f"data:image/png;base64,{encoded}"
        else:
            images[plot.name] = path.name
    figures = [(plot.name, plot.caption(given)) for plot in chosen]
    summary["plots"] = {name: path.name for name, path in plots.items()}
    if budget is not None:
        summary["budget"] = {
            key: budget.get(key)
            for key in ("made_at", "setup", "target_um", "resolution_um", "resolves", "verdict")
        }
    summary["notes"] = notes
    summary_path = out_dir / SUMMARY_FILE
    summary_path.write_text(
        json.dumps(_json_safe(summary), indent=2, allow_nan=False) + "\n", encoding="utf-8"
    )
    html_path = out_dir / HTML_FILE
    page = (
        arm_page(title, summary, figures=figures, images=images, notes=notes)
        if arm
        else two_link_page(title, summary, stats=stats, figures=figures, images=images, notes=notes)
    )
    if budget is not None:
        page = with_section(page, budget_section(budget))
    html_path.write_text(page, encoding="utf-8")
    logger.info("wrote the report of run %s to %s", steps.run_id, out_dir)
    return ReportFiles(directory=out_dir, html=html_path, summary=summary_path, plots=plots)
