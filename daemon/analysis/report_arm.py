"""An arm run's report page (issue 28). It leads with what the run says about the whole arm:
one sentence (how much of the measured drift the compensation removed, or why that cannot be
said), the whole-arm table, the 3-D drift and rotation figures over the hours of the arm's
warm-up, then each measured pose's figures. What does not apply to an arm is left out: thesis
Table 6.1 and its figures measure a two-link run's spot along the link, which an arm run does
not record. Pure text: no files, no Matplotlib."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence

from daemon.analysis.arm import ARM_LABELS
from daemon.analysis.removed import NOISE_SIGMAS
from daemon.analysis.report_page import document, figure_html, fmt, table

#: The whole-arm table's reductions and what each is measured against (key -> the
#: reference's largest value, the measurement's 1-sigma).
_REDUCTIONS = {
    "reduction_3d_percent": ("reference_drift_3d_max_um", "measurement_sigma_um"),
    "reduction_rotation_percent": (
        "reference_rotation_max_urad",
        "measurement_rotation_sigma_urad",
    ),
}


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) else None


def reduction_cell(arm: Mapping[str, object], key: str) -> str:
    """A reduction as a person should read it: none when the error grew, and no figure at
    all when the reference's own drift is within the measurement's noise (it would be the
    noise's ratio, e.g. -35 % for a rotation measured to 1σ 99 µrad)."""
    percent = _number(arm.get(key))
    reference_key, noise_key = _REDUCTIONS[key]
    reference, noise = _number(arm.get(reference_key)), _number(arm.get(noise_key))
    if percent is None:
        return "–"
    if reference is not None and noise is not None and reference < NOISE_SIGMAS * noise:
        return (
            f"not stated: the reference's {fmt(reference, 1)} is within the measurement's "
            f"noise (1σ {fmt(noise, 1)})"
        )
    if percent < 0:
        return "none: larger than the reference's"
    return fmt(percent, 1)


def whole_arm_rows(arm: Mapping[str, object]) -> list[tuple[str, str, str]]:
    """The whole-arm table: every figure the run has (none left as a dash)."""
    rows = []
    for key, (label, unit) in ARM_LABELS.items():
        if key in _REDUCTIONS:
            if arm.get(key) is not None:
                cell = reduction_cell(arm, key)
                rows.append((label, cell, unit if cell[0].isdigit() else ""))
            continue
        value = arm.get(key)
        if value is None:
            continue
        rows.append((label, fmt(value, 0 if key == "arm_n" else 3), unit))
    return rows


def _cells(rows: Sequence[tuple[str, str, str]]) -> str:
    body = "".join(
        f"<tr><td>{html.escape(label)}</td><td>{value}</td><td>{html.escape(unit)}</td></tr>"
        for label, value, unit in rows
    )
    return (
        "<table><thead><tr><th>quantity</th><th>value</th><th>unit</th></tr></thead>"
        f"<tbody>{body}</tbody></table>"
    )


def arm_page(
    title: str,
    summary: dict[str, object],
    *,
    figures: Sequence[tuple[str, str]],
    images: Mapping[str, str],
    notes: Mapping[str, str],
) -> str:
    arm = summary["arm"]
    flags = summary["flags"]
    assert isinstance(arm, dict) and isinstance(flags, dict)
    flag_text = ", ".join(f"{html.escape(name)}: {count}" for name, count in flags.items())
    headline = str(summary.get("headline") or "")
    parts = [
        f"<h1>{html.escape(title)}</h1>",
        f'<p class="headline"><b>{html.escape(headline)}</b></p>',
        f"<p>Arm run <b>{fmt(summary['run_id'])}</b>: {summary['steps']} steps, "
        f"{summary['steps_with_error']} with an error; flagged steps: {flag_text or 'none'}.</p>",
        "<h2>Whole arm: 3-D drift and rotation error of the tool</h2>",
        _cells(whole_arm_rows(arm)),
    ]
    by_name = dict(figures)
    lead = [(name, by_name[name]) for name in ("arm_drift", "arm_rotation") if name in by_name]
    parts += figure_html(lead, images, notes)
    per_pose = arm.get("per_pose")
    if isinstance(per_pose, dict) and per_pose:
        parts += [
            "<h2>Per measured pose</h2>",
            table(
                (
                    "pose",
                    "N",
                    "largest 3-D drift (µm)",
                    "RMS 3-D drift (µm)",
                    "largest rotation error (µrad)",
                    "RMS rotation error (µrad)",
                ),
                (
                    (
                        pose,
                        figures_of.get("n"),
                        figures_of.get("drift_3d_max_um"),
                        figures_of.get("drift_3d_rms_um"),
                        figures_of.get("rotation_error_max_urad"),
                        figures_of.get("rotation_error_rms_urad"),
                    )
                    for pose, figures_of in per_pose.items()
                ),
            ),
        ]
    rest = [(name, caption) for name, caption in figures if name not in dict(lead)]
    parts += figure_html(rest, images, notes)
    return document(title, parts)
