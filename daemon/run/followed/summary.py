"""A followed run's figures as ``thermocomp run`` prints them (its summary itself is its basis:
daemon/run/followed/kind.py)."""

from __future__ import annotations

from typing import Any

from daemon.run.summary import SummaryRow


def followed_summary_rows(summary: dict[str, Any]) -> list[SummaryRow]:
    """A followed run's figures (a UR playing its own program): the corrections written and,
    on the UR bench, the bench truth's 3-D tool error with and without them (the truth, not a
    measurement: a followed run measures with no camera)."""
    rows: list[SummaryRow] = [
        ("corrections written", summary.get("corrections_written"), ""),
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
    return [*rows, ("overruns", summary.get("overruns"), "")]
