"""``thermocomp centroid``: its options (light: ``thermocomp centroid --help`` loads neither
OpenCV nor NumPy, issue 30); the work is daemon/vision/cli.py, imported when it runs."""

from __future__ import annotations

import argparse
from pathlib import Path

from config.cli import non_negative_float, positive_float, positive_int

#: daemon.vision.METHODS (tests/test_vision_cli.py checks they agree)
METHOD_CHOICES = ("robust", "thesis")


def _run(args: argparse.Namespace) -> int:
    from daemon.vision.cli import run  # lazy: the vision (OpenCV) loads to run, not for --help

    return run(args)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "centroid",
        help="measure the laser spot's sub-pixel centroid in image files",
        description="Measure the laser spot in each image (thesis 3.2.3, A.1): position in px "
        "and um, peak, 10-bin histogram, uncertainty and flags. PATH: files, folders or globs, "
        "taken in natural order (image2 before image10). Defaults come from the [camera] "
        "section of --config (or the built-in defaults).",
    )
    parser.add_argument("paths", nargs="+", metavar="PATH", help="image file, folder or glob")
    parser.add_argument(
        "--method", choices=METHOD_CHOICES, help="robust (default) or thesis: the A.1 replica"
    )
    parser.add_argument(
        "--low",
        type=non_negative_float,
        metavar="F",
        help="thesis method: low threshold, fraction of full scale (<= 1) or counts (> 1); "
        "darker pixels count as 0 (default 0.8, as in A.1)",
    )
    parser.add_argument(
        "--high",
        type=non_negative_float,
        metavar="F",
        help="thesis method: high threshold (fraction or counts); brighter pixels count as white",
    )
    parser.add_argument(
        "--box", type=positive_int, metavar="N", help="thesis method: box half-size (px)"
    )
    parser.add_argument(
        "--binary",
        action="store_true",
        default=None,
        help="thesis method: pixels at or above the low threshold count as white",
    )
    parser.add_argument(
        "--um-per-px",
        nargs=2,
        type=positive_float,
        metavar=("X", "Y"),
        help="micrometres per pixel in x and y (default: camera.um_per_px of the settings; "
        "the thesis's optics measured 10.22 9.72)",
    )
    parser.add_argument(
        "--bit-depth",
        type=int,
        choices=(8, 12, 16),
        help="bits per pixel (default: 8 for 8-bit files, 16 for 16-bit ones; 12-bit frames "
        "stored in 16-bit files need 12)",
    )
    timing = parser.add_mutually_exclusive_group()
    timing.add_argument(
        "--interval", type=positive_float, metavar="S", help="seconds between consecutive frames"
    )
    timing.add_argument(
        "--times", type=Path, metavar="FILE", help="file of frame times in seconds, one per line"
    )
    output = parser.add_mutually_exclusive_group()
    output.add_argument("--json", action="store_true", help="print a JSON list, one per file")
    output.add_argument("--csv", action="store_true", help="print CSV, one row per file")
    parser.add_argument(
        "--config",
        type=Path,
        help="TOML settings file for the [camera] defaults (um_per_px, gain, read noise, "
        "centroid_*); THERMOCOMP_CAMERA__<FIELD> environment variables override it",
    )
    parser.set_defaults(handler=_run)
