"""``thermocomp stats`` and ``thermocomp fit``: statistics and exponential fits of one column
of a CSV file (an exported run, by default its error column) or of a plain list of numbers.

Exit statuses follow api/cli.py: 0 success, 1 the data cannot be analysed, 2 bad usage (a
missing file or column).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import logging
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from daemon.analysis.steps import RESIDUAL_COLUMN, natural_key, number_or_nan

if TYPE_CHECKING:  # SciPy loads when stats or fit runs, not for `thermocomp --help`
    from daemon.analysis.fits import Kind
    from daemon.analysis.statistics import ErrorStatistics

#: fits.KINDS, spelled out so that registering the commands imports no SciPy
#: (tests/test_cli.py checks they agree).
FIT_KINDS = ("rising", "decaying")  # daemon/commands/report_options.py repeats it for --help

logger = logging.getLogger(__name__)


#: The column name a plain list of numbers gets.
PLAIN_COLUMN = "value"

#: Time columns of an exported run, in order of preference.
TIME_COLUMNS = ("scheduled_s", "actual_s")


class InputError(Exception):
    """The input file or column cannot be used (exit status 2)."""


def read_table(path: Path) -> list[dict[str, str]]:
    """Rows of a CSV file with a header, or of a plain list of numbers (one column ``value``,
    numbers separated by whitespace, commas or newlines). ``-`` reads standard input."""
    try:
        text = sys.stdin.read() if str(path) == "-" else path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"cannot read {path}: {err}") from err
    tokens = text.replace(",", " ").split()
    if not tokens:
        raise InputError(f"{path} is empty")
    try:
        return [{PLAIN_COLUMN: str(float(token))} for token in tokens]
    except ValueError:
        pass  # not a plain list: a CSV with a header
    reader = csv.DictReader(io.StringIO(text))
    if not reader.fieldnames:
        raise InputError(f"{path} has no CSV header")
    rows = [dict(row) for row in reader]
    if not rows:
        raise InputError(f"{path} has a header but no rows")
    return rows


#: ``--column ir:<region>`` reads an IR region's mean from the ``ir_json`` column of an
#: exported run (``{"region": {"mean_c": .., "max_c": ..}}``); ``ir:<region>:max`` its maximum.
IR_PREFIX = "ir:"
IR_COLUMN = "ir_json"
IR_READINGS = {"mean": "mean_c", "max": "max_c"}


def _ir_regions(rows: list[dict[str, str]]) -> list[str]:
    regions: set[str] = set()
    for row in rows:
        regions.update(_ir_cell(row))
    return sorted(regions, key=natural_key)


def _ir_cell(row: dict[str, str]) -> dict[str, object]:
    try:
        cell = json.loads(row.get(IR_COLUMN) or "{}")
    except json.JSONDecodeError:
        return {}
    return cell if isinstance(cell, dict) else {}


def ir_values(rows: list[dict[str, str]], spec: str, source: Path) -> NDArray[np.float64]:
    """The series ``ir:<region>[:mean|:max]`` names: one value per row (NaN where the step
    has no reading of that region)."""
    name, reading = spec[len(IR_PREFIX) :], "mean"
    head, _, tail = name.rpartition(":")
    if head and tail in IR_READINGS:
        name, reading = head, tail
    if not rows or IR_COLUMN not in rows[0]:
        raise InputError(f"{source} has no {IR_COLUMN} column: {spec!r} needs an exported run")
    regions = _ir_regions(rows)
    if name not in regions:
        known = ", ".join(f"ir:{r}" for r in regions) or "none recorded"
        raise InputError(f"{source} has no IR region {name!r}; IR regions: {known}")
    key = IR_READINGS[reading]
    values = []
    for row in rows:
        region = _ir_cell(row).get(name)
        values.append(number_or_nan(region.get(key)) if isinstance(region, dict) else math.nan)
    return np.array(values, dtype=float)


def column_values(rows: list[dict[str, str]], name: str, source: Path) -> NDArray[np.float64]:
    """A numeric column, or ``ir:<region>[:mean|:max]`` (see :func:`ir_values`)."""
    if name.startswith(IR_PREFIX):
        return ir_values(rows, name, source)
    if not rows or name not in rows[0]:
        known = ", ".join(rows[0]) if rows else "none"
        hint = ""
        if rows and IR_COLUMN in rows[0]:
            regions = ", ".join(f"ir:{r}" for r in _ir_regions(rows))
            hint = f"; IR regions: {regions}" if regions else ""
        raise InputError(f"{source} has no column {name!r}; columns: {known}{hint}")
    return np.array([number_or_nan(row.get(name)) for row in rows], dtype=float)


def default_column(rows: list[dict[str, str]]) -> str:
    """The error column of an exported run, or the only column of a plain list."""
    return PLAIN_COLUMN if rows and PLAIN_COLUMN in rows[0] else RESIDUAL_COLUMN


def _fail(command: str, message: str, status: int) -> int:
    print(f"thermocomp {command}: {message}", file=sys.stderr)
    return status


def format_statistics(stats: ErrorStatistics, label: str) -> str:
    lines = [
        f"statistics of {label}",
        f"  N                                {stats.n}",
        f"  mean                             {stats.mean:.6g}",
        f"  standard deviation S_x           {stats.std:.6g}",
        f"  std of the mean S_x/sqrt(N)      {stats.std_of_mean:.6g}",
        f"  minimum / maximum / max |x|      {stats.minimum:.6g} / {stats.maximum:.6g} / "
        f"{stats.max_abs:.6g}",
        f"  intervals K                      {stats.intervals}",
    ]
    test = stats.chi_squared
    if test is None:
        lines.append(f"no chi-squared test: {stats.note}")
        return "\n".join(lines)
    lines += [
        "chi-squared test against the normal with the sample's mean and S_x (Eq. 6.2):",
        "    j                   interval    n_j  n_j expected  (n-n')^2/n'",
    ]
    for j, (observed, expected, part) in enumerate(
        zip(test.observed, test.expected, test.contributions, strict=True)
    ):
        low, high = test.edges[j], test.edges[j + 1]
        lines.append(
            f"  {j + 1:>3}  {low:>11.4f} .. {high:>10.4f}  {observed:>5}  {expected:>12.2f}  "
            f"{part:>12.3f}"
        )
    lines += [
        f"  chi-squared = {test.chi_squared:.4g}, nu = K - 2 = {test.degrees_of_freedom}",
        f"  p-value (upper tail, goodness of fit)   = {test.p_value:.4g}",
        f"  thesis's lower-tail reading P(chi2)      = {test.thesis_lower_tail_p:.4g}"
        "   (what thesis 6.6 reported; not a goodness-of-fit p-value)",
    ]
    return "\n".join(lines)


def run_stats(args: argparse.Namespace) -> int:
    from daemon.analysis.statistics import error_statistics  # lazy: SciPy, not for --help

    try:
        rows = read_table(args.file)
        column = args.column or default_column(rows)
        values = column_values(rows, column, args.file)
    except InputError as err:
        return _fail("stats", str(err), EXIT_USAGE)
    try:
        stats = error_statistics(values)
    except ValueError as err:
        return _fail("stats", f"{column}: {err}", EXIT_FAILURE)
    if args.json:
        print(json.dumps({"file": str(args.file), "column": column, **stats.to_dict()}, indent=2))
    else:
        print(format_statistics(stats, f"{column} ({args.file})"))
    return EXIT_OK


def _times(rows: list[dict[str, str]], args: argparse.Namespace) -> NDArray[np.float64]:
    if args.time_column:
        return column_values(rows, args.time_column, args.file)
    for name in TIME_COLUMNS:
        if rows and name in rows[0]:
            values = column_values(rows, name, args.file)
            if np.isfinite(values).any():
                return values
    step_s = float(args.step_s)
    return np.arange(len(rows), dtype=float) * step_s


def run_fit(args: argparse.Namespace) -> int:
    # lazy: SciPy, loaded when the fit runs, not for `fit --help` (issue 16)
    from daemon.analysis.fits import FitError, direction_of, fit_exponential

    try:
        rows = read_table(args.file)
        values = column_values(rows, args.column, args.file)
        times = _times(rows, args)
    except InputError as err:
        return _fail("fit", str(err), EXIT_USAGE)
    if not 0 < args.final_fraction <= 1:
        return _fail("fit", "--final-fraction must be in (0, 1]", EXIT_USAGE)
    if args.smoothing < 1:
        return _fail("fit", "--smoothing must be at least 1", EXIT_USAGE)
    finite = np.isfinite(values) & np.isfinite(times)
    kind: Kind = direction_of(values[finite]) if args.kind == "auto" else args.kind
    try:
        fit = fit_exponential(
            times,
            values,
            kind,
            band=args.band,
            sigmas=args.sigmas,
            final_fraction=args.final_fraction,
            smoothing=args.smoothing,
        )
    except (FitError, ValueError) as err:
        return _fail("fit", f"{args.column}: {err}", EXIT_FAILURE)
    result = {"file": str(args.file), "column": args.column, **fit.to_dict()}
    if args.json:
        print(json.dumps(result, indent=2))
        return EXIT_OK
    curve = fit.curve
    form = "(1 - exp(-(t - t0)/tau))" if kind == "rising" else "exp(-(t - t0)/tau)"
    steady = (
        f"{fit.steady_state_s:.6g} s"
        if fit.steady_state_s is not None
        else f"not steady within the data (tau = {curve.tau_s:.4g} s)"
    )
    settling = f"{curve.settling_time_s(fit.steady_band):.6g} s" if fit.steady_band > 0 else "-"
    print(
        "\n".join(
            [
                f"{kind} exponential fit of {args.column} ({args.file}), {fit.n} points",
                f"  y = y0 + A {form},  t0 = {curve.t0_s:.6g} s",
                f"  y0   = {curve.y0:.6g} ± {fit.y0_stderr:.3g}",
                f"  A    = {curve.amplitude:.6g} ± {fit.amplitude_stderr:.3g}",
                f"  tau  = {curve.tau_s:.6g} ± {fit.tau_stderr_s:.3g} s   (time constant)",
                f"  final value = {curve.final_value:.6g}; residual std = {fit.residual_std:.3g}",
                f"  steady state (data within ±{fit.steady_band:.3g} of the final level): "
                f"{steady}; fitted curve within that band from {settling}",
            ]
        )
    )
    return EXIT_OK
