"""``thermocomp stats``, ``fit`` and ``report``: their options (light: their ``--help``
loads neither NumPy, SciPy nor Matplotlib, issue 30); the work is daemon/analysis/cli.py
(stats, fit) and daemon/storage/reports.py (report), imported when it runs."""

from __future__ import annotations

import argparse
from pathlib import Path

from config.cli import positive_float, positive_int

#: daemon.analysis.RESIDUAL_COLUMN (tests/test_analysis_cli.py checks they agree)
RESIDUAL_COLUMN = "residual_um"
#: daemon.analysis.cli.FIT_KINDS (same test)
FIT_KINDS = ("rising", "decaying")


def _run_stats(args: argparse.Namespace) -> int:
    from daemon.analysis.cli import run_stats  # lazy: NumPy/SciPy load to run, not for --help

    return run_stats(args)


def _run_fit(args: argparse.Namespace) -> int:
    from daemon.analysis.cli import run_fit  # lazy: NumPy/SciPy load to run, not for --help

    return run_fit(args)


def _run_report(args: argparse.Namespace) -> int:
    from daemon.storage.reports import run_report  # lazy: matplotlib loads to run, not --help

    return run_report(args)


def _register_analysis(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    stats = subparsers.add_parser(
        "stats",
        help="error statistics of a column (thesis 6.6: N, mean, S_x, chi-squared)",
        description="N, mean, standard deviation S_x, standard deviation of the mean "
        "S_x/sqrt(N), the histogram over K = 1.87 (N-1)^0.40 + 1 intervals and the "
        "chi-squared test against the normal distribution with the sample's mean and S_x "
        "(thesis 6.6). The p-value is the upper tail; the thesis's lower-tail reading is "
        "shown beside it, labelled. Empty cells are skipped.",
    )
    stats.add_argument(
        "file",
        type=Path,
        help="CSV with a header (e.g. an exported run), "
        "a plain list of numbers, or - for standard input",
    )
    stats.add_argument(
        "--column",
        help=f"column to analyse (default {RESIDUAL_COLUMN}, the "
        "measured error of an exported run; ir:<region>[:max] an IR region's mean [maximum])",
    )
    stats.add_argument("--json", action="store_true", help="print JSON instead of a table")
    stats.set_defaults(handler=_run_stats)

    fit = subparsers.add_parser(
        "fit",
        help="first-order exponential fit of a column: time constant and steady state",
        description="Least-squares fit of y = y0 + A (1 - exp(-(t - t0)/tau)) (rising) or "
        "y = y0 + A exp(-(t - t0)/tau) (decaying) with the parameters' standard errors, the "
        "time constant tau and the steady-state time: the first time after which the data "
        "stay within a band around their final level (default +-3 sigma of the last 20 %, "
        "thesis 3.5.1).",
    )
    fit.add_argument("file", type=Path, help="CSV with a header, a plain list, or -")
    fit.add_argument(
        "--column",
        required=True,
        help="column to fit; ir:<region> fits an IR region's mean temperature from an "
        "exported run's ir_json column (ir:<region>:max its maximum)",
    )
    fit.add_argument(
        "--time-column",
        help="time column in s (default scheduled_s or actual_s; "
        "else the row index times --step-s)",
    )
    fit.add_argument(
        "--step-s",
        type=positive_float,
        default=1.0,
        help="time between rows when there is no time column (default 1 s)",
    )
    fit.add_argument(
        "--kind",
        choices=("auto", *FIT_KINDS),
        default="auto",
        help="rising or decaying; auto: from the first and last values",
    )
    fit.add_argument(
        "--band",
        type=positive_float,
        help="steady-state half-band in the column's unit (default: --sigmas of the final segment)",
    )
    fit.add_argument(
        "--sigmas",
        type=positive_float,
        default=3.0,
        help="band in standard deviations "
        "of the final segment when --band is not given (default 3)",
    )
    fit.add_argument(
        "--final-fraction",
        type=float,  # range (and nan) checked by run_fit: 0 < x <= 1
        default=0.2,
        help="final segment as a fraction of the data (default 0.2)",
    )
    fit.add_argument(
        "--smoothing",
        type=positive_int,
        default=9,
        help="judge 'stays within the band' on a running mean of this many samples "
        "(default 9; 1: raw samples)",
    )
    fit.add_argument("--json", action="store_true", help="print JSON instead of text")
    fit.set_defaults(handler=_run_fit)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``stats``, ``fit`` and ``report``."""
    _register_analysis(subparsers)
    parser = subparsers.add_parser(
        "report",
        help="write a run's report: figures, summary.json and an HTML page",
        description="Write the report of a run: PNG figures (deformation, compensation and "
        "error over time; compensated vs uncompensated; error histogram with the normal "
        "curve; temperatures; step lateness), summary.json (thesis Table 6.1, chi-squared "
        "test, exponential fits) and report.html showing them. TARGET is an exported run "
        "(CSV) or a run number in the run database of --config's storage.data_dir.",
    )
    parser.add_argument("target", metavar="RUN_ID|EXPORTED_FILE", help="run number or CSV file")
    parser.add_argument(
        "--out",
        type=Path,
        help="output folder (default: <data_dir>/reports/run-NNNNN for a run, "
        "<file>-report beside an exported file)",
    )
    parser.add_argument(
        "--config",
        type=Path,
        help="TOML settings file naming storage.data_dir (default: built-in defaults)",
    )
    parser.add_argument(
        "--data-dir",
        type=Path,
        help="folder of the run database (default: storage.data_dir of --config), as for "
        "`thermocomp run --data-dir`",
    )
    parser.add_argument(
        "--reference",
        metavar="RUN",
        help="an uncompensated run (run number, or an exported CSV for a CSV target) whose "
        "measured drift the reduction is computed against (default: the run's own "
        "reference_run parameter; none: the figure is only relative to the prediction)",
    )
    parser.add_argument(
        "--embed-images",
        action="store_true",
        help="embed the PNGs in report.html so the page is a single file (always done for "
        "a run's default folder, which the API serves)",
    )
    parser.set_defaults(handler=_run_report)
