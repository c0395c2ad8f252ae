"""The run report's section on the set-up's measurement error budget (thesis Table 4.5): the
latest budget ``thermocomp budget --save`` kept, beside the run it may explain. Pure: a
budget's JSON document in, HTML out."""

from __future__ import annotations

import html
from collections.abc import Mapping

from daemon.analysis.report_page import fmt, table


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _significant(value: float | None) -> str | None:
    """Three significant digits: the sources span orders of magnitude (Table 4.5's point)."""
    return None if value is None else f"{value:.3g}"


def budget_section(budget: Mapping[str, object]) -> str:
    """The section: when and how the budget was made, its verdict, the ranked sources (δL
    against the expected deformation, evidence, what would reduce each) and the warnings."""
    expected = _number(budget.get("expected_um"))
    sources = budget.get("sources")
    rows = []
    for source in sources if isinstance(sources, list) else []:
        if not isinstance(source, Mapping):
            continue
        value = _number(source.get("delta_l_um"))
        share = 100.0 * value / expected if value is not None and expected else None
        mark = " *" if source.get("conditional") else ""
        rows.append(
            (
                f"{source.get('name', '')}{mark}",
                source.get("section"),
                _significant(value),
                _significant(share),
                source.get("evidence"),
                source.get("remedy"),
            )
        )
    made = budget.get("made_at") or "unknown"
    how = "with its recordings" if budget.get("recorded") else "without recordings"
    parts = [
        "<h2>Measurement error budget (thesis Table 4.5)</h2>",
        f"<p>The set-up's latest budget ({html.escape(str(budget.get('setup', '')))}), made "
        f"{html.escape(str(made))} {how} by <code>thermocomp budget --save</code>: it "
        "describes the measurement, not this run.</p>",
        f"<p><b>{html.escape(str(budget.get('verdict', '')))}</b></p>",
        table(("source", "thesis", "δL (µm)", "% of ΔL", "evidence", "what would reduce it"), rows),
    ]
    if any(str(row[0]).endswith(" *") for row in rows):
        parts.append(
            '<p class="note">* a bound that needs a disturbance: not in the resolution</p>'
        )
    warnings = budget.get("warnings")
    parts += [
        f'<p class="note">{html.escape(str(w))}</p>'
        for w in (warnings if isinstance(warnings, list) else [])
    ]
    if expected is not None:
        parts.append(f"<p>Expected deformation ΔL: {fmt(expected)} µm.</p>")
    return "\n".join(parts)


def with_section(page: str, section: str) -> str:
    """``page`` (a whole report document) with ``section`` at the end of its body."""
    index = page.rfind("</body>")
    return page if index < 0 else page[:index] + section + "\n" + page[index:]
