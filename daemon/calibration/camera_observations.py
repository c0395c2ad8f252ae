"""The observations of ``thermocomp calibrate cameras`` (issue 20): one camera's centroid of a
marker with the tool at a known pose, as rows of ``moves.csv`` (columns
``camera,x_mm,y_mm,z_mm,x_px,y_px``, optionally ``rx_rad,ry_rad,rz_rad`` and
``sigma_x_px,sigma_y_px``: docs/reference/files.md "Calibration observations"). Light: the CLI's
``--help`` imports it."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

#: The command these observations are of: its name starts every message of its work.
PROG = "thermocomp calibrate cameras"
CSV_COLUMNS = ("camera", "x_mm", "y_mm", "z_mm", "x_px", "y_px")
SIGMA_COLUMNS = ("sigma_x_px", "sigma_y_px")
ROTATION_COLUMNS = ("rx_rad", "ry_rad", "rz_rad")


class ObservationError(Exception):
    """The observations cannot be read or used (exit 2) ."""


@dataclass(frozen=True, slots=True)
class Observation:
    """One camera's centroid of the marker with the tool at (position, rotation vector)."""

    camera: str
    position_mm: tuple[float, float, float]
    pixel_px: tuple[float, float]
    sigma_px: tuple[float, float] | None
    rotation_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)


def read_observations(path: Path) -> list[Observation]:
    """The CSV's rows (module docstring); ObservationError names the file and the row."""
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            missing = [c for c in CSV_COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                raise ObservationError(f"{path}: missing column(s) {', '.join(missing)}")
            with_sigma = all(c in (reader.fieldnames or []) for c in SIGMA_COLUMNS)
            with_rotation = all(c in (reader.fieldnames or []) for c in ROTATION_COLUMNS)
            rows = []
            for number, row in enumerate(reader, start=2):
                try:
                    values = [float(row[c]) for c in CSV_COLUMNS[1:]]
                    sigma = (
                        (float(row["sigma_x_px"]), float(row["sigma_y_px"])) if with_sigma else None
                    )
                    turn = [float(row[c]) for c in ROTATION_COLUMNS] if with_rotation else [0.0] * 3
                except (TypeError, ValueError) as err:
                    raise ObservationError(f"{path}: line {number}: not a number ({err})") from err
                rows.append(
                    Observation(
                        row["camera"],
                        (values[0], values[1], values[2]),
                        (values[3], values[4]),
                        sigma,
                        (turn[0], turn[1], turn[2]),
                    )
                )
    except OSError as err:
        raise ObservationError(f"{path}: cannot read: {err.strerror}") from err
    if not rows:
        raise ObservationError(f"{path}: no observations")
    return rows


def write_observations(path: Path, rows: list[Observation]) -> None:
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow([*CSV_COLUMNS, *ROTATION_COLUMNS, *SIGMA_COLUMNS])
        for row in rows:
            sigma = row.sigma_px or ("", "")
            writer.writerow(
                [row.camera, *row.position_mm, *row.pixel_px, *row.rotation_rad, *sigma]
            )
