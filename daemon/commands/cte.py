"""``thermocomp cte``: thesis chapter 2's analysis (Tables 2.4-2.7, Eqs. 2.1-2.3) as a command
(issue 32). An apparent expansion coefficient per camera from a calibration run's link
temperature rises and measured drift, their mean, then every other run's drift predicted from
its temperatures (with the start-temperature adjustment of a run that started warm) against
what was measured, with the percentage error.

The runs come from a table (CSV: a row per run, as Table 2.4) or from recorded runs (run
numbers in the run database, or exported run CSVs): each recorded run's start-to-end change
of its links' IR temperatures and of its measured deformation (daemon.analysis.cte.run_change),
and alpha fitted over all its steps beside. The geometry (Eq. 2.2's links, Eq. 2.3's cameras)
is a TOML file (config/cte/). The arithmetic is daemon/analysis/cte.py's; this module only
reads, lays out and prints. Options parse without the numeric stack (``--help``, issue 16).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import sys
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from config.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE, add_config_argument

if TYPE_CHECKING:
    from daemon.analysis.cte import Camera, CteTable, Links, RunChange, RunCteFit

PROG = "thermocomp cte"
HELP = "apparent expansion coefficients from runs and their predictions (thesis 2.2.4)"
#: Columns of a run table: ``dT:LINK`` rise, ``dl:CAMERA`` deformation, ``offset:LINK`` start.
RISE, DEFORMATION, OFFSET = "dT:", "dl:", "offset:"


class CteError(Exception):
    """Bad input (geometry, table, run); ``str()`` is the one line for the user."""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "cte",
        help=HELP,
        description="Thesis 2.2.4 (Tables 2.4-2.7): alpha per camera from the calibration "
        "run (Eq. 2.3 solved for alpha), their mean, and each other run's deformation "
        "predicted from its link temperature rises with each camera's alpha and the mean, "
        "against the measured deformation (a run that started warmer than the calibration: "
        "its offset is added to the predicted rise and its deformation to the measured one), "
        "with the % error = (predicted - measured) / measured. SOURCE: a run table (CSV, "
        "columns run, dT:LINK, dl:CAMERA and optionally offset:LINK; config/cte/"
        "thesis-table-2.4.csv), or recorded runs (run numbers in --config's run database, or "
        "exported run CSVs), whose links take the IR regions the geometry names.",
    )
    parser.add_argument("sources", nargs="+", metavar="SOURCE", help="run table, runs or files")
    parser.add_argument(
        "--geometry",
        type=Path,
        required=True,
        metavar="FILE",
        help="the links (name, length_m, angle_deg, regions) and cameras (name, phi_deg, "
        "theta_deg) of Eqs. 2.2-2.3 (TOML; config/cte/kuka-kr15-2.toml is the thesis's)",
    )
    parser.add_argument(
        "--calibration",
        metavar="RUN",
        help="the run alpha is estimated from (default: the first)",
    )
    parser.add_argument(
        "--digits",
        type=int,
        choices=range(0, 7),
        metavar="N",
        help="round alpha to N decimals of 1e-6/K before predicting, and compute the %% error "
        "from the deformations rounded to 0.01 um, as the thesis did (2 reproduces Tables "
        "2.6-2.7); default: full precision",
    )
    add_config_argument(parser)
    parser.add_argument("--data-dir", type=Path, help="run database folder (default: --config's)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(handler=run_cte)


# --- inputs ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Geometry:
    name: str
    links: Links
    link_names: tuple[str, ...]
    link_regions: tuple[tuple[str, ...], ...]  # IR regions averaged for each link
    cameras: tuple[Camera, ...]


def _number(item: Mapping[str, Any], key: str, where: str, default: float | None = None) -> float:
    value = item.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise CteError(f"{where}: {key}: expected a finite number")
    return float(value)


def load_geometry(path: Path) -> Geometry:
    # lazy: NumPy/SciPy and the analysis load when the command runs, not for --help
    from daemon.analysis.cte import Camera, Links

    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise CteError(f"{path}: cannot read: {err.strerror or err}") from err
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise CteError(f"{path}: not valid TOML: {err}") from err
    links, cameras = data.get("links"), data.get("cameras", [{"name": "camera"}])
    if not isinstance(links, list) or not links or not isinstance(cameras, list) or not cameras:
        raise CteError(f"{path}: needs [[links]] (and [[cameras]]) tables")
    names, regions, lengths, angles = [], [], [], []
    for index, link in enumerate(links):
        where = f"{path}: links[{index}]"
        if not isinstance(link, dict) or not isinstance(link.get("name"), str):
            raise CteError(f"{where}: needs a name")
        lengths.append(_number(link, "length_m", where))
        angles.append(_number(link, "angle_deg", where, 0.0))
        names.append(link["name"])
        own = link.get("regions", [link["name"]])
        if not isinstance(own, list) or not own or not all(isinstance(r, str) for r in own):
            raise CteError(f"{where}: regions: expected a list of IR region names")
        regions.append(tuple(own))
    views = []
    for index, camera in enumerate(cameras):
        where = f"{path}: cameras[{index}]"
        if not isinstance(camera, dict) or not isinstance(camera.get("name"), str):
            raise CteError(f"{where}: needs a name")
        views.append(
            Camera(
                camera["name"],
                _number(camera, "phi_deg", where, 0.0),
                _number(camera, "theta_deg", where, 0.0),
            )
        )
    return Geometry(
        str(data.get("name", path.stem)),
        Links(tuple(lengths), tuple(angles)),
        tuple(names),
        tuple(regions),
        tuple(views),
    )


def read_run_table(path: Path, geometry: Geometry) -> list[RunChange]:
    """Table 2.4's rows: ``#`` lines are comments; an empty cell of offset: means none."""
    # lazy: NumPy/SciPy and the analysis load when the command runs, not for --help
    from daemon.analysis.cte import RunChange

    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as err:
        raise CteError(f"cannot read {path}: {err}") from err
    lines = [line for line in text.splitlines() if line.strip() and not line.startswith("#")]
    reader = csv.DictReader(io.StringIO("\n".join(lines)))
    columns = reader.fieldnames or []
    needed = [RISE + n for n in geometry.link_names] + [
        DEFORMATION + c.name for c in geometry.cameras
    ]
    missing = [c for c in ["run", *needed] if c not in columns]
    if missing:
        raise CteError(f"{path}: missing column(s) {', '.join(missing)}")
    runs = []
    for number, row in enumerate(reader, start=2):

        def cell(column: str, row: dict[str, str] = row, number: int = number) -> float:
            try:
                value = float(row[column])
            except (TypeError, ValueError):
                raise CteError(f"{path}: row {number}: {column}: not a number") from None
            if not math.isfinite(value):
                raise CteError(f"{path}: row {number}: {column}: not finite")
            return value

        offsets = [(row.get(OFFSET + n) or "").strip() for n in geometry.link_names]
        runs.append(
            RunChange(
                name=row["run"],
                delta_t_k=tuple(cell(RISE + n) for n in geometry.link_names),
                deformation_um={c.name: cell(DEFORMATION + c.name) for c in geometry.cameras},
                start_offset_k=(
                    tuple(cell(OFFSET + n) for n in geometry.link_names) if any(offsets) else None
                ),
            )
        )
    if not runs:
        raise CteError(f"{path}: no run")
    return runs


def _is_run_table(path: Path) -> bool:
    try:
        with path.open(encoding="utf-8-sig") as handle:
            header = next((ln for ln in handle if ln.strip() and not ln.startswith("#")), "")
    except (OSError, UnicodeDecodeError):
        return False
    return any(column.strip().startswith(RISE) for column in header.split(","))


def recorded_runs(
    sources: Sequence[str], geometry: Geometry, data_dir: Path
) -> tuple[list[RunChange], dict[str, RunCteFit]]:
    """Each recorded run's start-to-end change and its all-steps fit, its links' temperatures
    the means of their IR regions."""
    import dataclasses

    import numpy as np

    # lazy: NumPy/SciPy and the analysis load when the command runs, not for --help
    from daemon.analysis import steps_from_rows
    from daemon.analysis.cli import InputError, read_table
    from daemon.analysis.cte import cte_from_run, run_change
    from daemon.storage.reports import ReportError, read_run

    camera = geometry.cameras[0]
    changes, fits = [], {}
    for source in sources:
        try:
            if Path(source).is_file():
                steps = steps_from_rows(read_table(Path(source)))
                name = Path(source).stem
            elif source.isdigit():
                steps, _ = read_run(data_dir, int(source))
                name = f"run {source}"
            else:
                raise CteError(f"{source!r} is neither a file nor a run number")
        except (InputError, ReportError) as err:
            raise CteError(str(err)) from err
        known = ", ".join(sorted(steps.ir_mean_c)) or "none"
        links = {}
        for link, regions in zip(geometry.link_names, geometry.link_regions, strict=True):
            missing = [r for r in regions if r not in steps.ir_mean_c]
            if missing:
                raise CteError(f"{name}: no IR region {', '.join(missing)} (recorded: {known})")
            links[link] = np.mean([steps.ir_mean_c[r] for r in regions], axis=0)
        steps = dataclasses.replace(steps, ir_mean_c=links)
        try:
            change = run_change(steps, geometry.link_names, name=name, camera=camera.name)
            fits[name] = cte_from_run(steps, geometry.link_names, geometry.links, camera)
        except ValueError as err:
            raise CteError(f"{name}: {err}") from err
        changes.append(change)
    return changes, fits


# --- output ----------------------------------------------------------------------------------


def _rounded_percent(predicted: float, measured: float) -> float:
    """The thesis's % error: of the deformations as it printed them (0.01 um)."""
    shown = round(measured, 2)
    return 100.0 * (round(predicted, 2) - shown) / shown


def to_dict(
    table: CteTable, geometry: Geometry, digits: int | None, fits: Mapping[str, RunCteFit]
) -> dict[str, object]:
    data = table.to_dict()
    data["geometry"] = geometry.name
    if digits is not None:
        for row, source in zip(data["rows"], table.rows, strict=True):  # type: ignore[call-overload]
            row["percent_error"] = _rounded_percent(source.predicted_um, source.measured_um)
    data["run_fits"] = {
        name: {
            "alpha_per_k": fit.alpha_per_k,
            "alpha_stderr_per_k": fit.alpha_stderr_per_k,
            "endpoint_alpha_per_k": fit.endpoint_alpha_per_k,
            "steps": fit.n,
        }
        for name, fit in fits.items()
    }
    return data


def to_text(
    table: CteTable, geometry: Geometry, digits: int | None, fits: Mapping[str, RunCteFit]
) -> str:
    lines = [f"Apparent expansion coefficient (thesis 2.2.4): {geometry.name}", ""]
    lines.append(f"{'alpha (1e-6/K)':<16}from {table.calibration}")
    for camera, alpha in table.alpha_per_camera.items():
        lines.append(f"  alpha_{camera:<9}{alpha * 1e6:>8.2f}")
    lines.append(f"  {'mean':<15}{table.mean_alpha_per_k * 1e6:>8.2f}")
    if fits:
        lines += ["", "alpha fitted over every step of each run (1e-6/K):"]
        lines += [
            f"  {name:<14}{fit.alpha_per_k * 1e6:>8.2f} +- {fit.alpha_stderr_per_k * 1e6:.2f} "
            f"({fit.n} steps; start-to-end {fit.endpoint_alpha_per_k * 1e6:.2f})"
            for name, fit in fits.items()
        ]
    if table.rows:
        how = "of the values shown" if digits is not None else "full precision"
        lines += [
            "",
            f"{'alpha':<14}{'camera':<8}{'run':<12}{'predicted um':>13}{'measured um':>13}"
            f"{'% error':>9}   (% error {how})",
        ]
        for row in table.rows:
            percent = (
                _rounded_percent(row.predicted_um, row.measured_um)
                if digits is not None
                else row.percent_error
            )
            lines.append(
                f"{row.alpha_label:<14}{row.camera:<8}{row.run[:12]:<12}{row.predicted_um:>13.2f}"
                f"{row.measured_um:>13.2f}{percent:>9.2f}"
            )
    return "\n".join(lines)


def run_cte(args: argparse.Namespace) -> int:
    # lazy: NumPy/SciPy and the analysis load when the command runs, not for --help
    from config import load_settings
    from daemon.analysis.cte import cte_table

    try:
        geometry = load_geometry(args.geometry)
        first = Path(args.sources[0])
        fits: dict[str, RunCteFit] = {}
        if len(args.sources) == 1 and first.is_file() and _is_run_table(first):
            runs = read_run_table(first, geometry)
        else:
            data_dir = args.data_dir or load_settings(args.config).storage.data_dir
            runs, fits = recorded_runs(args.sources, geometry, data_dir)
        names = [run.name for run in runs]
        chosen = args.calibration or names[0]
        if chosen not in names:
            raise CteError(f"--calibration {chosen!r}: the runs are {', '.join(names)}")
        calibration = runs[names.index(chosen)]
        others = [run for run in runs if run is not calibration]
        table = cte_table(geometry.links, geometry.cameras, calibration, others, digits=args.digits)
    except CteError as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_USAGE
    except (ValueError, ZeroDivisionError) as err:
        print(f"{PROG}: {err}", file=sys.stderr)
        return EXIT_FAILURE
    if args.json:
        print(json.dumps(to_dict(table, geometry, args.digits, fits), indent=2))
    else:
        print(to_text(table, geometry, args.digits, fits))
    return EXIT_OK
