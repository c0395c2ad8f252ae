"""A followed run's figures as ``thermocomp run`` prints them (its summary itself is its basis:
daemon/run/followed/kind.py)."""

from __future__ import annotations

from typing import Any

from daemon.run.summary import SummaryRow


def followed_summary_rows(summary: dict[str, Any]) -> list[SummaryRow]:
    """A followed run's figures (a UR playing its own program): the corrections written and,
    with tool cameras the measured residuals (at the program's measured poses, against each
    pose's first measurement) and, on the UR bench, the cameras against the truth and the bench
    truth's 3-D tool error with and without the corrections (the truth, every step)."""
    rows: list[SummaryRow] = [
        ("corrections written", summary.get("corrections_written"), ""),
    ]
    measured = summary.get("measured") or {}
    if measured.get("cameras"):
        removed = measured.get("removed_fraction")
        rows += [
            ("cameras: measurements (N)", measured.get("measurements"), ""),
            ("cameras: 3-D residual RMS", measured.get("rms_residual_um"), "um"),
            ("cameras: 3-D residual max", measured.get("worst_residual_um"), "um"),
            ("cameras: 3-D uncorrected RMS", measured.get("rms_uncompensated_um"), "um"),
            ("cameras: removed (RMS)", None if removed is None else 100.0 * removed, "%"),
            ("cameras: mean 1-sigma", measured.get("mean_sigma_um"), "um"),
        ]
    elif measured:
        rows.append(("tool measured", "none: no camera (model + joint temperatures)", ""))
    versus = summary.get("measured_vs_truth") or {}
    if versus.get("measurements"):
        rows += [
            ("cameras vs bench truth: RMS", versus.get("rms_difference_um"), "um"),
            ("cameras vs bench truth: worst", versus.get("worst_difference_sigmas"), "sigma"),
        ]
    truth = summary.get("bench_truth") or {}
    if truth.get("steps"):
        removed = truth.get("removed_fraction")
        rows += [
            ("bench truth: steps (N)", truth.get("steps"), ""),
            ("3-D error RMS, corrected", truth.get("rms_residual_um"), "um"),
            ("3-D error RMS, uncorrected", truth.get("rms_uncompensated_um"), "um"),
            ("3-D error max, corrected", truth.get("worst_residual_um"), "um"),
            ("3-D error max, uncorrected", truth.get("worst_uncompensated_um"), "um"),
            ("removed (RMS)", None if removed is None else 100.0 * removed, "%"),
        ]
    room = summary.get("room") or {}
    if room.get("measured"):
        rows += [
            ("room: first reading", room.get("first_c"), "degC"),
            ("room: last reading", room.get("last_c"), "degC"),
        ]
    elif room:
        rows.append(("room", "not measured: the model held model.ambient_c (room.driver)", ""))
    return [*rows, ("overruns", summary.get("overruns"), "")]
