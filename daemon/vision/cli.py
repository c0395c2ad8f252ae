"""``thermocomp centroid``: measure the laser spot in image files, as the thesis's
``find_computed_trajectory.m`` did (appendix A.1), with either method.

``thermocomp centroid PATH... [--method robust|thesis] [--low F] [--high F] [--box N]
[--binary] [--um-per-px X Y] [--interval S | --times FILE] [--json | --csv]``

PATH may be files, folders (their image files) or globs; files are taken in natural order
(image2 before image10). Every file gives one record; a file that cannot be measured gets an
``error`` and the batch goes on. With a time base (``--interval`` seconds between frames, or
``--times`` a file of one time in seconds per frame, like the thesis's ``time.txt``) each
record also has ``t_s`` and the drift from the first measured frame in µm.

This module is the one place of ``daemon.vision`` that does I/O (it reads the files); the
estimator it calls stays pure. Exit status: 0 every frame measured, 1 some frame failed,
2 bad usage (nothing to read, a bad option or time file).
"""

from __future__ import annotations

import argparse
import csv
import glob
import json
import logging
import math
import os
import re
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from config import load_settings
from config.cli import (
    EXIT_FAILURE,
    EXIT_OK,
    EXIT_USAGE,
)
from config.inputs import check_regular_file
from daemon.vision.centroid import CentroidError, measure_centroid

logger = logging.getLogger(__name__)

# the options live in daemon/commands/centroid_options.py (light: `thermocomp centroid --help` loads
# neither OpenCV nor NumPy), which calls run when the command runs

#: Files a folder contributes (what OpenCV reads and a frame grabber writes).
IMAGE_SUFFIXES = frozenset(
    {".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg", ".pgm", ".ppm", ".pnm"}
)
#: The numbers every record has (null when the frame failed), in output order.
NUMERIC_FIELDS = (
    "x_px",
    "y_px",
    "x_um",
    "y_um",
    "sigma_x_px",
    "sigma_y_px",
    "sigma_x_um",
    "sigma_y_um",
    "signal",
    "peak",
    "peak_fraction",
    "background",
    "noise",
    "width_x_px",
    "width_y_px",
    "snr",
    "saturated_fraction",
    "gain_e_per_count",
)
TIME_FIELDS = ("t_s", "drift_x_um", "drift_y_um")


class UsageError(Exception):
    """The command line cannot be carried out; ``str()`` says why."""


def natural_key(path: Path) -> list[tuple[int, int | str]]:
    """Sort key reading digit runs as numbers: image2 before image10 (case-insensitive)."""
    parts = re.split(r"(\d+)", str(path))
    return [(0, int(part)) if part.isdigit() else (1, part.lower()) for part in parts if part]


def collect_files(patterns: Iterable[str]) -> list[Path]:
    """Files named by ``patterns`` (files, folders, globs), unique, in natural order."""
    found: set[Path] = set()
    for pattern in patterns:
        path = Path(pattern)
        if path.is_dir():
            matches = [
                p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()
            ]
            if not matches:
                raise UsageError(f"{pattern}: no image files in this folder")
        elif path.exists():
            # a pipe or device would block the reader forever (issue 26)
            check_regular_file(path, "an image file", UsageError)
            matches = [path]
        elif glob.has_magic(pattern):
            matches = [Path(p) for p in glob.glob(pattern) if Path(p).is_file()]
            if not matches:
                raise UsageError(f"{pattern}: no file matches")
        else:
            raise UsageError(f"{pattern}: no such file or folder")
        found.update(matches)
    return sorted(found, key=natural_key)


def read_times(path: Path, count: int) -> list[float]:
    """Frame times (s) from ``path``: numbers separated by white space, at least ``count``."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise UsageError(f"{path}: cannot read the times: {err}") from err
    try:
        times = [float(word) for word in text.split()]
    except ValueError as err:
        raise UsageError(f"{path}: not a list of numbers: {err}") from err
    if len(times) < count or not all(math.isfinite(t) for t in times):
        raise UsageError(f"{path}: {len(times)} finite times for {count} frames")
    return times[:count]


def read_image(path: Path) -> NDArray[Any]:
    """The grey image of ``path``; raises :class:`CentroidError` ``unreadable``.

    A colour file gives its red channel (a 635 nm laser; the thesis read ``I(:, :, 1)``, the
    first channel of MATLAB's RGB order)."""
    try:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except cv2.error as err:
        raise CentroidError("unreadable", f"unreadable file: {err}") from err
    if image is None:
        raise CentroidError("unreadable", "unreadable or not an image file")
    if image.ndim == 3:
        image = image[:, :, 2] if image.shape[2] >= 3 else image[:, :, 0]
    return np.ascontiguousarray(image)


def _bit_depth(image: NDArray[Any], requested: int | None) -> int:
    if image.dtype == np.uint8:
        return 8 if requested is None else requested
    if image.dtype == np.uint16:
        return 16 if requested is None else requested
    raise CentroidError(
        "unreadable", f"unsupported pixel type {image.dtype} (8- or 16-bit images only)"
    )


def measure_files(args: argparse.Namespace, files: Sequence[Path]) -> list[dict[str, Any]]:
    """One record per file, in order: the measurement or its error."""
    camera = load_settings(args.config).camera
    method = args.method or camera.centroid_method
    options: dict[str, Any] = {
        "method": method,
        "um_per_px": tuple(args.um_per_px) if args.um_per_px else camera.um_per_px,
        "low": camera.centroid_low if args.low is None else args.low,
        "high": camera.centroid_high if args.high is None else args.high,
        "box": args.box or camera.centroid_box,
        "binary": camera.centroid_binary if args.binary is None else args.binary,
        "gain_e_per_count": camera.gain_e_per_count,
        "read_noise_e": camera.read_noise_e,
    }
    thesis_only = {
        "--low": args.low,
        "--high": args.high,
        "--box": args.box,
        "--binary": args.binary,
    }
    given = [name for name, value in thesis_only.items() if value is not None]
    if method == "robust" and given:
        logger.warning("%s only configure the thesis method; robust ignores them", ", ".join(given))
    records: list[dict[str, Any]] = []
    first_shape: tuple[int, int] | None = None
    for path in files:
        record: dict[str, Any] = {"file": str(path), "method": method}
        try:
            image = read_image(path)
            bit_depth = _bit_depth(image, args.bit_depth)
            expected_shape = first_shape or (image.shape[0], image.shape[1])
            first_shape = expected_shape  # the first readable frame sets the dimensions
            result = measure_centroid(
                image, bit_depth=bit_depth, expected_shape=expected_shape, **options
            )
        except CentroidError as err:
            record.update(dict.fromkeys(NUMERIC_FIELDS), gain_source=None, histogram=None, flags=[])
            record["error"] = str(err)
            logger.debug("%s: %s", path, err)
        else:
            data = result.as_dict()
            record.update({name: _finite_or_none(data[name]) for name in NUMERIC_FIELDS})
            record.update(
                gain_source=data["gain_source"],
                histogram=data["histogram"],
                flags=data["flags"],
                error=None,
            )
        records.append(record)
    return records


def add_drift(records: list[dict[str, Any]], times: Sequence[float]) -> None:
    """``t_s`` and the drift (µm) from the first measured frame, as the thesis plotted."""
    reference: tuple[float, float] | None = None
    for record, time_s in zip(records, times, strict=True):
        record["t_s"] = time_s
        record["drift_x_um"] = record["drift_y_um"] = None
        if record["error"] is not None:
            continue
        if reference is None:
            reference = (record["x_um"], record["y_um"])
        record["drift_x_um"] = record["x_um"] - reference[0]
        record["drift_y_um"] = record["y_um"] - reference[1]


def _finite_or_none(value: Any) -> Any:
    return None if isinstance(value, float) and not math.isfinite(value) else value


def write_csv(records: Sequence[dict[str, Any]], timed: bool) -> None:
    columns = ["file", "method", *(TIME_FIELDS if timed else ()), *NUMERIC_FIELDS, "gain_source"]
    writer = csv.writer(sys.stdout, lineterminator="\n")
    writer.writerow([*columns, *(f"histogram_{i}" for i in range(10)), "flags", "error"])
    for record in records:
        histogram = record["histogram"] or [None] * 10
        cells = [record[name] for name in columns] + list(histogram)
        cells += [",".join(record["flags"]), record["error"] or ""]
        writer.writerow(["" if cell is None else cell for cell in cells])


def write_text(records: Sequence[dict[str, Any]], timed: bool) -> None:
    for record in records:
        if record["error"] is not None:
            print(f"{record['file']}: error: {record['error']}")
            continue
        line = (
            f"{record['file']}: x {record['x_px']:.4f} px ({record['x_um']:.3f} um)  "
            f"y {record['y_px']:.4f} px ({record['y_um']:.3f} um)  peak {record['peak']:g}"
        )
        if record["sigma_x_px"] is not None:
            line += f"  +-{record['sigma_x_px']:.4f}/{record['sigma_y_px']:.4f} px"
            line += f" (gain {record['gain_e_per_count']:.3g} e-/count, {record['gain_source']})"
        if timed:
            line += (
                f"  t {record['t_s']:g} s  drift {record['drift_x_um']:.3f} "
                f"{record['drift_y_um']:.3f} um"
            )
        if record["flags"]:
            line += "  [" + ",".join(record["flags"]) + "]"
        print(line)


def run(args: argparse.Namespace) -> int:
    try:
        files = collect_files(args.paths)
        times: list[float] | None = None
        if args.times is not None:
            times = read_times(args.times, len(files))
        elif args.interval is not None:
            times = [index * args.interval for index in range(len(files))]
    except UsageError as err:
        print(f"thermocomp centroid: {err}", file=sys.stderr)
        return EXIT_USAGE
    records = measure_files(args, files)
    if times is not None:
        add_drift(records, times)
    try:
        if args.json:
            json.dump(records, sys.stdout, indent=1)
            sys.stdout.write("\n")
        elif args.csv:
            write_csv(records, timed=times is not None)
        else:
            write_text(records, timed=times is not None)
        sys.stdout.flush()
    except BrokenPipeError:  # e.g. piped into `head`: the reader has all it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_FAILURE
    failed = sum(record["error"] is not None for record in records)
    if failed:
        print(f"thermocomp centroid: {failed} of {len(records)} frames failed", file=sys.stderr)
        return EXIT_FAILURE
    return EXIT_OK
