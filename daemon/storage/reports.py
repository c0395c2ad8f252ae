"""Run reports from the run database, and the ``thermocomp report`` command.

daemon.analysis is pure and knows nothing of the recorder; this module is the glue: it reads a
run's steps (and the summary the daemon recorded) from the SQLite database or an exported CSV
and hands them to :func:`daemon.analysis.write_report`. It also registers ``stats`` and
``fit`` (daemon.analysis.cli) so the entry point lists all analysis commands with one entry.

The database is opened READ-ONLY here: opening a ``Recorder`` would mark the run the daemon
is recording right now as interrupted (recorder.py marks live runs left by a crash).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sqlite3
import sys
from collections.abc import Mapping
from contextlib import closing
from pathlib import Path
from typing import TYPE_CHECKING, Any

from config import load_settings
from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from daemon.analysis import RunSteps, compensation_of, steps_from_rows, summarize_run

if TYPE_CHECKING:
    from daemon.analysis import ReportFiles
from daemon.analysis import cli as analysis_cli
from daemon.storage.recorder import DATABASE_NAME, step_rows

logger = logging.getLogger(__name__)


#: Relative tolerance when checking the report's numbers against the daemon's run summary.
SUMMARY_TOLERANCE = 1e-9


class ReportError(Exception):
    """The run or file cannot be reported (unknown run, unreadable database)."""


def report_dir(data_dir: Path, run_id: int) -> Path:
    """Where the report of a run lives: beside the database, like the archived frames."""
    return Path(data_dir) / "reports" / f"run-{run_id:05d}"


def read_run(data_dir: Path, run_id: int) -> tuple[RunSteps, dict[str, Any] | None]:
    """The steps of a run as series, and the summary the daemon recorded for it (None while
    running). The rows are streamed from the database, never held all at once."""
    path = Path(data_dir) / DATABASE_NAME
    if not path.is_file():
        raise ReportError(f"no run database at {path}")
    try:
        with closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as db:
            run = db.execute("SELECT summary_json FROM runs WHERE id = ?", (run_id,)).fetchone()
            if run is None:
                raise ReportError(f"no run {run_id} in {path}")
            steps = steps_from_rows(step_rows(db, run_id))
    except sqlite3.Error as err:
        raise ReportError(f"cannot read {path}: {err}") from err
    summary = json.loads(run[0]) if run[0] else None
    return steps, summary


def _run_json(data_dir: Path, run_id: int, column: str) -> object:
    """One JSON column of a run's row, decoded (None when the row, the value or its JSON is
    missing or broken); ReportError when the database cannot be read."""
    path = Path(data_dir) / DATABASE_NAME
    try:
        with closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as db:
            row = db.execute(f"SELECT {column} FROM runs WHERE id = ?", (run_id,)).fetchone()
    except sqlite3.Error as err:
        raise ReportError(f"cannot read {path}: {err}") from err
    try:
        return json.loads(row[0]) if row and row[0] else None
    except json.JSONDecodeError:
        return None


def run_parameters(data_dir: Path, run_id: int) -> dict[str, Any]:
    """The parameters a run was started with ({} when the database does not say)."""
    parameters = _run_json(data_dir, run_id, "parameters_json")
    return parameters if isinstance(parameters, dict) else {}


def reference_steps(data_dir: Path, reference_run: int) -> RunSteps:
    """The steps of an uncompensated reference run; ReportError if it is not one."""
    compensation = run_parameters(data_dir, reference_run).get("compensation")
    if compensation != "off":
        raise ReportError(
            f"run {reference_run} was compensated ({compensation}): a reference must be an "
            "uncompensated run (compensation off) measuring the drift"
        )
    return read_run(data_dir, reference_run)[0]


def drift_removed_of(
    database: Path,
    run_id: int,
    compensation: str | None,
    reference_run: int | None,
    so_far: bool = True,
) -> dict[str, Any]:
    """The dashboard's "drift removed so far" (daemon.analysis.removed) of a run, from its
    steps recorded until now and its named reference run's, read from ``database``
    read-only. Picklable arguments: the API runs it in an export process, so reading a long
    run never holds the daemon's GIL (issue 15, point 6)."""
    # lazy: SciPy (the fits) loads in the export process that computes it, not for `report
    # --help`, `stats` or `fit` (issue 16)
    from daemon.analysis.removed import REMOVED_COLUMNS, drift_removed

    uri = f"{Path(database).resolve().as_uri()}?mode=ro"
    with closing(sqlite3.connect(uri, uri=True)) as db:
        steps = steps_from_rows(step_rows(db, run_id, REMOVED_COLUMNS))
        poses = [
            row[0]
            for row in db.execute(
                "SELECT arm_pose FROM steps WHERE run_id = ? ORDER BY step", (run_id,)
            )
        ]
        reference = (
            None
            if reference_run is None
            else steps_from_rows(step_rows(db, reference_run, REMOVED_COLUMNS))
        )
    return drift_removed(
        steps,
        compensation=compensation,
        poses=poses,
        reference=reference if reference is not None and reference.n_steps else None,
        reference_run=reference_run,
        so_far=so_far,
    )


def run_clock(data_dir: Path, run_id: int) -> str | None:
    """The run's ``bench.clock`` setting, from the settings the daemon recorded with it (None
    when the database does not say): the report drops the lateness figure on a virtual clock."""
    config = _run_json(data_dir, run_id, "config_json")
    bench = config.get("bench") if isinstance(config, dict) else None
    clock = bench.get("clock") if isinstance(bench, dict) else None
    return clock if isinstance(clock, str) else None


def disagreements(recorded: Mapping[str, Any], computed: Mapping[str, Any]) -> list[str]:
    """Keys of the daemon's run summary whose value the report computes differently."""
    differing = []
    for key, value in computed.items():
        if key not in recorded:
            continue
        other = recorded[key]
        if value is None or other is None or isinstance(value, str) or isinstance(other, str):
            if value != other:
                differing.append(key)
        elif not math.isclose(float(value), float(other), rel_tol=SUMMARY_TOLERANCE):
            differing.append(key)
    return differing


def write_run_report(
    data_dir: Path,
    run_id: int,
    out_dir: Path | None = None,
    *,
    embed_images: bool = False,
    reference_run: int | None = None,
) -> ReportFiles:
    """Write the report of a recorded run. Blocking.

    The reduction is measured against ``reference_run`` (an uncompensated run), else against
    the run's own ``reference_run`` parameter, else only stated against the prediction.
    Without ``out_dir`` it goes to :func:`report_dir`, the folder the API serves
    ``GET /api/v1/runs/{id}/report`` from as a single page, so there the images are always
    embedded (the PNG files are written beside it too)."""
    steps, recorded = read_run(data_dir, run_id)
    parameters = run_parameters(data_dir, run_id)
    compensation = parameters.get("compensation")
    if reference_run is None and isinstance(parameters.get("reference_run"), int):
        reference_run = parameters["reference_run"]
    reference = None if reference_run is None else reference_steps(data_dir, reference_run)
    summary_options: dict[str, Any] = {
        "compensation": compensation if isinstance(compensation, str) else None,
        "reference": reference,
        "reference_run": reference_run,
    }
    if recorded is not None:
        differing = disagreements(recorded, summarize_run(steps, **summary_options))
        if differing:
            logger.warning(
                "run %d: the report's %s differ from the daemon's recorded summary",
                run_id,
                ", ".join(differing),
            )
    if out_dir is None:
        out_dir, embed_images = report_dir(data_dir, run_id), True
    # lazy: Matplotlib (and the budget's analysis), loaded to write, not to import
    from daemon.analysis import write_report
    from daemon.storage.budgets import read_saved_budget

    return write_report(
        steps,
        out_dir,
        title=f"thermocomp run {run_id}",
        embed_images=embed_images,
        clock=run_clock(data_dir, run_id),
        budget=read_saved_budget(data_dir),
        **summary_options,
    )


def run_report(args: argparse.Namespace) -> int:
    from daemon.analysis import write_report  # lazy: Matplotlib, not for `report --help`

    target = Path(args.target)
    reference_arg: str | None = args.reference
    try:
        if target.is_file():
            rows = analysis_cli.read_table(target)
            reference = None
            if reference_arg is not None:
                if not Path(reference_arg).is_file():
                    print(
                        f"thermocomp report: --reference {reference_arg!r}: for an exported "
                        "run, name the reference's exported CSV file",
                        file=sys.stderr,
                    )
                    return EXIT_USAGE
                reference = steps_from_rows(analysis_cli.read_table(Path(reference_arg)))
                if compensation_of(reference) != "off":
                    raise ReportError(
                        f"{reference_arg} records compensating offsets: a reference must be "
                        "an uncompensated run (compensation off)"
                    )
            out_dir = args.out or target.with_name(f"{target.stem}-report")
            files = write_report(
                rows,
                out_dir,
                title=f"thermocomp run ({target.name})",
                embed_images=args.embed_images,
                reference=reference,
                reference_run=None if reference_arg is None else Path(reference_arg).name,
            )
        elif args.target.isdigit():
            if reference_arg is not None and not reference_arg.isdigit():
                print(
                    f"thermocomp report: --reference {reference_arg!r} is not a run number",
                    file=sys.stderr,
                )
                return EXIT_USAGE
            data_dir = args.data_dir or load_settings(args.config).storage.data_dir
            files = write_run_report(
                data_dir,
                int(args.target),
                args.out,
                embed_images=args.embed_images,
                reference_run=None if reference_arg is None else int(reference_arg),
            )
        else:
            print(
                f"thermocomp report: {args.target!r} is neither a file nor a run number",
                file=sys.stderr,
            )
            return EXIT_USAGE
    except analysis_cli.InputError as err:
        print(f"thermocomp report: {err}", file=sys.stderr)
        return EXIT_USAGE
    except (ReportError, ValueError, OSError) as err:
        print(f"thermocomp report: {err}", file=sys.stderr)
        return EXIT_FAILURE
    print(files.html)
    return EXIT_OK
