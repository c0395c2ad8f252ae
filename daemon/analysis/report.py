"""The run report: PNG figures, ``summary.json`` and one HTML page showing them with tables.

The page carries its own style and no scripts or external resources; it references the PNGs
beside it by relative name (or embeds them, ``embed_images=True``, for a single-file copy).
Writing is blocking (matplotlib, files): the daemon calls :func:`write_report` in a thread.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from daemon.analysis.arm import (
    ARM_FIGURE,
    ARM_LABELS,
    draw_arm_figure,
    is_arm_run,
    summarize_arm_run,
)
from daemon.analysis.fits import FitError, direction_of, fit_exponential
from daemon.analysis.plots import (
    plot_compensated_vs_uncompensated,
    plot_compensation,
    plot_error_histogram,
    plot_lateness,
    plot_temperatures,
)
from daemon.analysis.statistics import ErrorStatistics, error_statistics
from daemon.analysis.steps import SUMMARY_KEYS, FloatArray, RunSteps, steps_from_rows, summarize_run

logger = logging.getLogger(__name__)

SUMMARY_FILE = "summary.json"
HTML_FILE = "report.html"
DPI = 100

#: Table 6.1's rows: summary key -> (label, symbol, unit).
SUMMARY_LABELS: dict[str, tuple[str, str, str]] = {
    "n": ("Sample size (steps with a measured error)", "N", ""),
    "residual_max_um": ("Largest |error|", "max |x|", "µm"),
    "residual_mean_um": ("Mean error", "x̄", "µm"),
    "residual_std_um": ("Standard deviation", "S_x", "µm"),
    "residual_std_mean_um": ("Standard deviation of the mean", "S_x̄ = S_x/√N", "µm"),
    "measured_drift_max_um": ("Largest measured drift (compensation off)", "", "µm"),
    "uncompensated_max_um": ("Largest predicted deformation (the model's)", "", "µm"),
    "reduction_percent": (
        "Reduction of the largest displacement, measured against the reference run",
        "",
        "%",
    ),
    "reduction_vs_prediction_percent": (
        "Largest error relative to the largest predicted deformation (not a measured reduction)",
        "1 − max|x| / max prediction",
        "%",
    ),
    "reference_max_um": ("Largest measured drift of the reference run", "", "µm"),
    "reference_span_s": ("Time both runs cover (maxima taken over it)", "", "s"),
}

#: The Table 6.1 rows shown for each ``reduction_basis`` (the rest would be empty).
_BASIS_ROWS: dict[str, frozenset[str]] = {
    "drift": frozenset({"measured_drift_max_um", "uncompensated_max_um"}),
    "prediction": frozenset({"uncompensated_max_um", "reduction_vs_prediction_percent"}),
    "reference": frozenset(
        {
            "uncompensated_max_um",
            "reference_max_um",
            "reference_span_s",
            "reduction_percent",
            "reduction_vs_prediction_percent",
        }
    ),
}
_TABLE_6_1_KEYS = frozenset(
    {"n", "residual_max_um", "residual_mean_um", "residual_std_um", "residual_std_mean_um"}
)


def reduction_note(run_summary: Mapping[str, object]) -> str:
    """One sentence saying what the summary's reduction figure is measured against."""
    basis = run_summary.get("reduction_basis")
    if basis == "drift":
        return (
            "This run was not compensated (compensation off): its error is the measured "
            "thermal drift, and there is no reduction to state."
        )
    if basis == "reference":
        return (
            f"The reduction compares this run's largest error with the largest drift measured "
            f"by the uncompensated reference run {run_summary.get('reference_run')}, both "
            "over the time the two runs cover."
        )
    return (
        "No uncompensated reference run was named (run parameter reference_run, "
        "thermocomp report --reference RUN): the only figure is relative to the model's "
        "own prediction, which says how well the moves followed the model, not how much of "
        "the real drift they removed (a wrong model over-predicts and looks better)."
    )


@dataclass(frozen=True)
class ReportFiles:
    """Where a report was written."""

    directory: Path
    html: Path
    summary: Path
    plots: dict[str, Path]  # figure name -> PNG path


@dataclass(frozen=True)
class _Plot:
    name: str
    caption: str
    draw: Callable[[RunSteps, ErrorStatistics | None, dict[str, float | int | str | None]], Figure]


PLOTS: tuple[_Plot, ...] = (
    _Plot(
        "compensation",
        "Deformation input (model prediction), commanded compensation and measured error over "
        "time, as thesis Figures 6.5-6.7. A perfect compensation mirrors the deformation and "
        "leaves zero error.",
        lambda steps, stats, summary: plot_compensation(steps, stats),
    ),
    _Plot(
        "compensated_vs_uncompensated",
        "Where the tool would have moved without compensation against where it moved with it "
        "(thesis Figure 6.9).",
        lambda steps, stats, summary: plot_compensated_vs_uncompensated(steps, summary),
    ),
    _Plot(
        "error_histogram",
        "Histogram of the error over K = 1.87 (N-1)^0.40 + 1 intervals with the normal "
        "distribution of the sample's mean and S_x (thesis Figure 6.8, section 6.6).",
        lambda steps, stats, summary: plot_error_histogram(stats),
    ),
    _Plot(
        "temperatures",
        "Mean temperature of each infrared region (thick lines) and, when recorded, of "
        "each model node (dashed, coloured by node number along the link).",
        lambda steps, stats, summary: plot_temperatures(steps),
    ),
    _Plot(
        "lateness",
        "How long after its scheduled time each step started.",
        lambda steps, stats, summary: plot_lateness(steps),
    ),
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


def _format(value: object, digits: int = 3) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}" if math.isfinite(value) else "–"
    return html.escape(str(value))


def _table(header: Iterable[str], rows: Iterable[Iterable[object]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{_format(c)}</td>" for c in row) + "</tr>" for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _html_page(
    title: str,
    summary: dict[str, object],
    stats: ErrorStatistics | None,
    images: Mapping[str, str],
    notes: Mapping[str, str],
) -> str:
    run_summary = summary["run_summary"]
    flags = summary["flags"]
    assert isinstance(run_summary, dict) and isinstance(flags, dict)
    flag_text = ", ".join(f"{html.escape(name)}: {count}" for name, count in flags.items())
    parts = [
        f"<h1>{html.escape(title)}</h1>",
        f"<p>Run <b>{_format(summary['run_id'])}</b>: {summary['steps']} steps, "
        f"{summary['steps_with_error']} with an error; flagged steps: {flag_text or 'none'}.</p>",
        "<h2>Statistical results (thesis Table 6.1)</h2>",
        _table(
            ("quantity", "symbol", "value", "unit"),
            (
                (label, symbol, run_summary.get(key), unit)
                for key in SUMMARY_KEYS
                if key in _TABLE_6_1_KEYS
                or key in _BASIS_ROWS.get(str(run_summary.get("reduction_basis")), frozenset())
                for label, symbol, unit in (SUMMARY_LABELS[key],)
            ),
        ),
        f'<p class="note">{html.escape(reduction_note(run_summary))}</p>',
    ]
    arm = summary.get("arm")
    if isinstance(arm, dict):
        parts += [
            "<h2>Whole arm: 3-D drift and rotation error of the tool</h2>",
            _table(
                ("quantity", "value", "unit"),
                ((label, arm.get(key), unit) for key, (label, unit) in ARM_LABELS.items()),
            ),
            f'<figure><img src="{html.escape(images[ARM_FIGURE])}" alt="{ARM_FIGURE}">'
            "<figcaption>The tool's measured drift from its pose at the start (norm and "
            "components, base frame) and the predicted tool error (dashed).</figcaption>"
            "</figure>",
        ]
    if stats is not None and stats.chi_squared is not None:
        test = stats.chi_squared
        parts += [
            "<h2>Chi-squared test for normality (thesis Table C.4)</h2>",
            f"<p>χ² = {test.chi_squared:.3f} with ν = K − 2 = {test.degrees_of_freedom}. "
            f"Goodness-of-fit p-value (upper tail): <b>{test.p_value:.3f}</b> "
            f"({'no evidence against' if test.p_value >= 0.05 else 'evidence against'} "
            f"a normal distribution at 5 %). The thesis read the lower tail, "
            f"P(χ²) = {test.thesis_lower_tail_p:.3f}, which is not a goodness-of-fit "
            "p-value: a small upper tail rejects normality, while the lower tail only says how "
            'unusually close the fit is (README "Run reports").</p>',
            _table(
                ("j", "interval (µm)", "n_j", "n'_j", "(n_j − n'_j)²/n'_j"),
                (
                    (
                        j + 1,
                        f"{test.edges[j]:.3f} ≤ x < {test.edges[j + 1]:.3f}",
                        test.observed[j],
                        test.expected[j],
                        test.contributions[j],
                    )
                    for j in range(len(test.observed))
                ),
            ),
        ]
    elif stats is not None:
        parts.append(f"<p>No chi-squared test: {html.escape(stats.note)}.</p>")
    fits = summary["fits"]
    assert isinstance(fits, dict)
    fit_rows: list[tuple[object, ...]] = []
    for name, fit in fits.items():
        if "error" in fit:
            fit_rows.append((name, "–", None, None, None, None, None, fit["error"]))
        else:
            steady = fit["steady_state_s"]
            fit_rows.append(
                (
                    name,
                    fit["kind"],
                    fit["final_value"],
                    fit["tau_s"],
                    fit["tau_stderr_s"],
                    steady
                    if steady is not None
                    else f"not steady within the run (τ = {fit['tau_s']:.4g} s)",
                    fit.get("fit_settling_s"),
                    f"band ±{fit['steady_band']:.3g}",
                )
            )
    parts += [
        "<h2>First-order exponential fits</h2>",
        "<p>y = y0 + A (1 − e^(−(t − t0)/τ)) (or the decaying form). τ is the time constant "
        "(63 % of the change); steady state is the first time after which the data (running "
        "mean of 9 samples) stay within ±3σ of the mean of their final 20 % (thesis 3.5.1); "
        "σ is that final segment's. A signal is called steady only when the fitted curve also "
        "enters that band before the run ends (fit settles, s); otherwise it is still moving "
        "and the time constant says how far it has to go.</p>",
        _table(
            (
                "signal",
                "form",
                "final value",
                "τ (s)",
                "± (s)",
                "steady from (s)",
                "fit settles (s)",
                "note",
            ),
            fit_rows,
        ),
        "<h2>Figures</h2>",
    ]
    for plot in PLOTS:
        if plot.name in notes:  # a figure that would say nothing: one line saying why
            parts.append(f'<p class="note">{html.escape(notes[plot.name])}</p>')
            continue
        parts.append(
            f'<figure><img src="{html.escape(images[plot.name])}" alt="{plot.name}">'
            f"<figcaption>{html.escape(plot.caption)}</figcaption></figure>"
        )
    style = (
        "body{font-family:system-ui,sans-serif;max-width:1040px;margin:2em auto;padding:0 1em;"
        "color:#222}table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #ccc;"
        "padding:4px 10px;text-align:right}th{background:#f0f0f0}td:first-child{text-align:left}"
        "img{max-width:100%;border:1px solid #ddd}figure{margin:2em 0}"
        "figcaption{color:#555;font-size:.95em}.note{color:#555;font-style:italic}"
    )
    body = "\n".join(parts)
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title><style>{style}</style></head>\n"
        f"<body>\n{body}\n</body></html>\n"
    )


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
) -> ReportFiles:
    """Write the figures, ``summary.json`` and ``report.html`` of one run into ``out_dir``.

    ``rows`` are the run's step records (the columns of daemon/storage/recorder.py's StepRecord).
    ``clock`` is the run's ``bench.clock`` setting when known: on a virtual clock the
    lateness figure is replaced by a line saying why it would be empty. ``compensation`` (the
    run's mode, inferred from its offsets when None), ``reference`` and ``reference_run``
    (an uncompensated run's steps and name) decide what the reduction is measured against
    (:func:`summarize_run`). Blocking.
    """
    steps = rows if isinstance(rows, RunSteps) else steps_from_rows(rows)
    out_dir.mkdir(parents=True, exist_ok=True)
    summary, stats = build_summary(
        steps, compensation=compensation, reference=reference, reference_run=reference_run
    )
    run_summary = summary["run_summary"]
    assert isinstance(run_summary, dict)
    plots: dict[str, Path] = {}
    images: dict[str, str] = {}
    notes: dict[str, str] = {}
    note = lateness_note(steps, clock)
    if note is not None:
        notes["lateness"] = note
    for plot in PLOTS:
        if plot.name in notes:
            (out_dir / f"{plot.name}.png").unlink(missing_ok=True)  # not a stale one
            continue
        figure = plot.draw(steps, stats, run_summary)
        path = out_dir / f"{plot.name}.png"
        figure.savefig(path, dpi=DPI)
        plots[plot.name] = path
        if embed_images:
            encoded = base64.b64encode(path.read_bytes()).decode("ascii")
            images[plot.name] = f"data:image/png;base64,{encoded}"
        else:
            images[plot.name] = path.name
    if is_arm_run(steps):  # issue 20: the tool's 3-D drift and rotation error
        summary["arm"] = summarize_arm_run(
            steps, compensation=compensation, reference=reference, reference_run=reference_run
        )
        arm_figure = draw_arm_figure(steps)
        path = out_dir / f"{ARM_FIGURE}.png"
        arm_figure.savefig(path, dpi=DPI)
        plots[ARM_FIGURE] = path
        images[ARM_FIGURE] = (
            f"data:image/png;base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"
            if embed_images
            else path.name
        )
    summary["plots"] = {name: path.name for name, path in plots.items()}
    summary["notes"] = notes
    summary_path = out_dir / SUMMARY_FILE
    summary_path.write_text(
        json.dumps(_json_safe(summary), indent=2, allow_nan=False) + "\n", encoding="utf-8"
    )
    html_path = out_dir / HTML_FILE
    html_path.write_text(_html_page(title, summary, stats, images, notes), encoding="utf-8")
    logger.info("wrote the report of run %s to %s", steps.run_id, out_dir)
    return ReportFiles(directory=out_dir, html=html_path, summary=summary_path, plots=plots)
