"""Lab devices (issue 18): the GenICam camera's grab time per frame on pylon's emulated camera,
and `calibrate camera`'s accuracy on the bench.

GenICam: 100 grabs after one warm-up grab per setting (ROI, pixel format, trigger), exposure
1 ms; the wall time of each ``await camera.grab()`` (event loop to event loop) and the time the
grab took in the driver's worker thread. Needs the genicam extra (pypylon); skipped without it.

Calibration: the whole `thermocomp calibrate camera` procedure (the C500C emulator moving the
spot through the default 5 x 5 grid of +-0.5 mm, the sim camera rendering each frame, the fit)
on a sim camera turned and rescaled by known amounts, five seeds each; the recovered pitch's
relative error and the rotation's error against the bench's truth, and the fit's own 1-sigma.

    .venv/bin/python benchmarks/bench_devices.py
"""

from __future__ import annotations

import asyncio
import importlib.util
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("PYLON_CAMEMU", "1")  # before pylon starts

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.common import print_table, write_results
from config import Settings
from config.settings import CameraSettings
from daemon.commands.calibrate import bench_truth, calibrate, checked_pattern
from drivers.clock import ScaledClock
from drivers.genicam.camera import GenICamCamera

GRABS = 100
SEEDS = (1, 2, 3, 4, 5)
#: (rotation deg, scale) of the sim camera
OPTICS = ((0.0, 1.0), (2.5, 0.85), (-7.0, 1.2))


async def grab_times(**camera: Any) -> dict[str, float]:
    settings = CameraSettings(driver="genicam", exposure_us=1000.0, **camera)
    async with GenICamCamera(settings, ScaledClock()) as device:
        await device.grab()
        walls, threads = [], []
        for _ in range(GRABS):
            started = time.perf_counter()
            await device.grab()
            walls.append(time.perf_counter() - started)
            threads.append(device.last_grab_s)
    walls.sort()
    return {
        "median_ms": 1000 * statistics.median(walls),
        "p95_ms": 1000 * walls[int(0.95 * len(walls)) - 1],
        "max_ms": 1000 * walls[-1],
        "thread_median_ms": 1000 * statistics.median(threads),
    }


def genicam() -> list[dict[str, Any]]:
    cases = [
        ("752x582 Mono12 software trigger", {"width_px": 752, "height_px": 582, "bit_depth": 12}),
        ("752x582 Mono8 software trigger", {"width_px": 752, "height_px": 582, "bit_depth": 8}),
        ("1024x1040 Mono16 software trigger", {"width_px": 1024, "height_px": 1040}),
        (
            "752x582 Mono12 free run",
            {"width_px": 752, "height_px": 582, "bit_depth": 12, "trigger": "off"},
        ),
    ]
    results = []
    for label, camera in cases:
        results.append({"setting": label, **asyncio.run(grab_times(**camera))})
    print_table(
        ["setting", "median ms", "p95 ms", "max ms", "thread median ms"],
        [
            [r["setting"], r["median_ms"], r["p95_ms"], r["max_ms"], r["thread_median_ms"]]
            for r in results
        ],
    )
    return results


def calibration() -> list[dict[str, Any]]:
    results = []
    for rotation, scale in OPTICS:
        for seed in SEEDS:
            settings = Settings.model_validate(
                {"bench": {"seed": seed, "camera_rotation_deg": rotation, "camera_scale": scale}}
            )
            offsets = checked_pattern(
                settings,
                settings.camera.calibration_size_mm,
                settings.camera.calibration_step_mm,
            )
            started = time.perf_counter()
            fit = asyncio.run(calibrate(settings, offsets))
            elapsed = time.perf_counter() - started
            (true_x, true_y), true_rotation = bench_truth(settings)
            results.append(
                {
                    "rotation_deg": rotation,
                    "scale": scale,
                    "seed": seed,
                    "pitch_error_x_percent": 100 * (fit.um_per_px[0] / true_x - 1),
                    "pitch_error_y_percent": 100 * (fit.um_per_px[1] / true_y - 1),
                    "pitch_se_x_percent": 100 * fit.um_per_px_se[0] / true_x,
                    "rotation_error_deg": fit.rotation_deg - true_rotation,
                    "rotation_se_deg": fit.rotation_se_deg,
                    "wall_s": elapsed,
                }
            )
    print()
    print_table(
        ["rot deg", "scale", "seed", "dpx %", "dpy %", "se px %", "drot deg", "se rot", "s"],
        [
            [
                r["rotation_deg"],
                r["scale"],
                r["seed"],
                r["pitch_error_x_percent"],
                r["pitch_error_y_percent"],
                r["pitch_se_x_percent"],
                r["rotation_error_deg"],
                r["rotation_se_deg"],
                r["wall_s"],
            ]
            for r in results
        ],
    )
    worst_pitch = max(
        max(abs(r["pitch_error_x_percent"]), abs(r["pitch_error_y_percent"])) for r in results
    )
    worst_rotation = max(abs(r["rotation_error_deg"]) for r in results)
    print(f"\nworst pitch error {worst_pitch:.3f} %, worst rotation error {worst_rotation:.4f} deg")
    return results


def main() -> None:
    grabs: list[dict[str, Any]] | None = None
    if importlib.util.find_spec("pypylon") is None:
        print("GenICam: skipped, pypylon (the genicam extra) is not installed")
    else:
        grabs = genicam()
    write_results("devices", {"genicam_grabs": grabs, "calibration": calibration()})


if __name__ == "__main__":
    main()
