"""The two-link run report's HTML page (daemon/analysis/report.py writes it): thesis Table 6.1,
the chi-squared test, the exponential fits and the figures; and what every report page shares
(tables, figures, the self-contained document). Pure text: no files, no Matplotlib."""

from __future__ import annotations

import html
import math
from collections.abc import Iterable, Mapping, Sequence

from daemon.analysis.statistics import ErrorStatistics
from daemon.analysis.steps import SUMMARY_KEYS

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


def fmt(value: object, digits: int = 3) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}" if math.isfinite(value) else "–"
    return html.escape(str(value))


def table(header: Iterable[str], rows: Iterable[Iterable[object]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{fmt(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def two_link_page(
    title: str,
    summary: dict[str, object],
    *,
    stats: ErrorStatistics | None,
    figures: Sequence[tuple[str, str]],
    images: Mapping[str, str],
    notes: Mapping[str, str],
) -> str:
    """The two-link run's page: Table 6.1 (or one line when no step measured an error),
    the chi-squared test, the fits and ``figures`` (name, caption), each its image or, in
    ``notes``, the one line saying why it would say nothing."""
    run_summary = summary["run_summary"]
    flags = summary["flags"]
    assert isinstance(run_summary, dict) and isinstance(flags, dict)
    flag_text = ", ".join(f"{html.escape(name)}: {count}" for name, count in flags.items())
    parts = [
        f"<h1>{html.escape(title)}</h1>",
        f"<p>Run <b>{fmt(summary['run_id'])}</b>: {summary['steps']} steps, "
        f"{summary['steps_with_error']} with an error; flagged steps: {flag_text or 'none'}.</p>",
    ]
    if not run_summary.get("n"):
        parts.append(
            '<p class="note">No step measured an error (N = 0): no statistics, no '
            "reduction. The steps' flags and errors above say why.</p>"
        )
    else:
        parts += [
            "<h2>Statistical results (thesis Table 6.1)</h2>",
            table(
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
            table(
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
        table(
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
    parts += figure_html(figures, images, notes)
    return document(title, parts)


def figure_html(
    figures: Sequence[tuple[str, str]], images: Mapping[str, str], notes: Mapping[str, str]
) -> list[str]:
    """Each figure (name, caption) as its image, or the note saying why there is none."""
    parts = []
    for name, caption in figures:
        if name in notes:  # a figure that would say nothing: one line saying why
            parts.append(f'<p class="note">{html.escape(notes[name])}</p>')
        elif name in images:
            parts.append(
                f'<figure><img src="{html.escape(images[name])}" alt="{name}">'
                f"<figcaption>{html.escape(caption)}</figcaption></figure>"
            )
    return parts


STYLE = (
    "body{font-family:system-ui,sans-serif;max-width:1040px;margin:2em auto;padding:0 1em;"
    "color:#222}table{border-collapse:collapse;margin:1em 0}th,td{border:1px solid #ccc;"
    "padding:4px 10px;text-align:right}th{background:#f0f0f0}td:first-child{text-align:left}"
    "img{max-width:100%;border:1px solid #ddd}figure{margin:2em 0}"
    "figcaption{color:#555;font-size:.95em}.note{color:#555;font-style:italic}"
    ".headline{font-size:1.2em}"
)


def document(title: str, parts: Sequence[str]) -> str:
    """The page: its own style, no scripts, no external resources."""
    body = "\n".join(parts)
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title><style>{STYLE}</style></head>\n"
        f"<body>\n{body}\n</body></html>\n"
    )
