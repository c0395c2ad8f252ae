"""Issue 20: the duty cycle played by the robot through the daemon (config/arm-sim-played.toml:
the console driver moves the C500C emulator in joint space on a pty through every pose of the
A465's pick-and-place at its speed and dwell, the arm bench's truth heated by the motion the
emulator performs, time_scale 1 on a virtual clock paced by the cycle).

Runs of the same arm: none (the drift) and the preset arm model (compensated, with the first as
reference); with ``--identify`` first a calibration run of the same arm with another
measurement noise (``bench.noise_seed`` = seed + 1000), its identification (as ``thermocomp
identify RUN --save NAME``: daemon/commands/arm_identify.py, every parameter, then the identifiable
ones refitted) and two more runs: the identified arm model, and it with the IR observer
(``--prediction model+ir``), as benchmarks/bench_arm_daemon.py does on the accelerated bench.
Reported: the measured 3-D residual (RMS and largest over the steps), the share of the
uncompensated RMS removed, the RMS over the meter's own 1-sigma (``measured_sigma_um``), the
rotation error with its own 1-sigma (``measured_rotation_sigma_urad``) and the share removed,
the moves the emulator performed, and the wall time per run (how long minutes or hours of arm
time take through the daemon) with the machine's load.

    .venv/bin/python benchmarks/bench_arm_played.py [--duration 1800] [--step 60] [--seed N]
        [--profile] [--drift-only] [--identify] [--frames N]

``--frames N``: ``arm.frames_per_measurement`` (each marker's centroid the mean of N frames per
camera: the rotation's noise falls by about sqrt(N)).
"""

from __future__ import annotations

import argparse
import asyncio
import cProfile
import logging
import os
import pstats
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.bench_arm_daemon import (
    CALIBRATION_NOISE_OFFSET,
    CONTROLLER_COLUMNS,
    MODEL_NAME,
    add_ratios,
    controller_row,
    figures,
    print_parameter_table,
)
from benchmarks.common import print_table, write_results
from config import Settings, load_settings
from daemon.arm.arm_model import arm_model_toml, new_arm_model_path
from daemon.commands.arm_identify import arm_model_of, identify_arm_run, load_arm_run
from daemon.run.states import RunParameters
from daemon.service import Daemon
from drivers.clock import make_clock
from drivers.factory import Devices

CONFIG = Path(__file__).resolve().parent.parent / "config" / "arm-sim-played.toml"


def settings_for(
    data_dir: Path,
    seed: int,
    duration_s: float,
    step_s: float,
    *,
    noise_seed: int | None = None,
    frames: int | None = None,
) -> Settings:
    data = load_settings(CONFIG).model_dump()
    data["bench"].update({"seed": seed, "noise_seed": noise_seed})
    if frames is not None:
        data["arm"]["frames_per_measurement"] = frames
    data["scheduler"].update({"duration_s": duration_s, "step_s": step_s})
    data["storage"].update({"data_dir": str(data_dir), "report_at_end": False})
    return Settings.model_validate(data)


async def one_run(settings: Settings, **overrides: Any) -> dict[str, Any]:
    """One played run through the daemon: its figures, moves and wall time."""
    started = time.perf_counter()
    async with Daemon(settings, clock=make_clock("virtual")) as daemon:
        opened = time.perf_counter()
        info = await daemon.start_run(RunParameters.from_settings(settings, **overrides))
        final = await daemon.wait_run()
        ran = time.perf_counter()
        assert daemon.recorder is not None
        steps = [record.as_dict() for record in daemon.recorder.steps(info["id"])]
        devices = daemon.devices
        assert isinstance(devices, Devices) and devices.emulator is not None
        moves = devices.emulator.state.motion_count
    if final["state"] != "finished":
        raise RuntimeError(f"run {info['id']} ended {final['state']}: {final.get('reason')}")
    flagged = [s for s in steps if s["flags"]]
    return {
        **figures(steps),
        "run_id": int(info["id"]),
        "steps": len(steps),
        "flagged_steps": len(flagged),
        "moves": moves,
        "wall_open_s": opened - started,
        "wall_run_s": ran - opened,
        "wall_s": time.perf_counter() - started,
        "summary_reduction_3d_percent": (final.get("summary") or {}).get("reduction_3d_percent"),
    }


async def calibrate(settings: Settings, data_dir: Path) -> dict[str, Any]:
    """The calibration run (uncompensated), its identification saved as arm model MODEL_NAME."""
    calibration = await one_run(settings, compensation="off")
    started = time.perf_counter()
    run = await asyncio.to_thread(load_arm_run, data_dir, calibration["run_id"])
    full, refit = await asyncio.to_thread(identify_arm_run, run, None)
    model = arm_model_of(MODEL_NAME, run, full, refit)
    path = new_arm_model_path(MODEL_NAME, data_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(arm_model_toml(model), encoding="utf-8")
    return {
        **calibration,
        "noise_seed": settings.bench.noise_seed,
        "all": full.to_dict(),
        "refit": refit.to_dict(),
        "arm_model": model.provenance(),
        "wall_identification_s": time.perf_counter() - started,
    }


async def bench(
    seed: int,
    data_dir: Path,
    duration_s: float,
    step_s: float,
    *,
    drift_only: bool = False,
    identify: bool = False,
    frames: int | None = None,
) -> dict[str, Any]:
    settings = settings_for(data_dir, seed, duration_s, step_s, frames=frames)
    result: dict[str, Any] = {
        "seed": seed,
        "duration_s": duration_s,
        "step_s": step_s,
        "frames": settings.arm.frames_per_measurement,
    }
    if identify:
        noise_seed = seed + CALIBRATION_NOISE_OFFSET
        calibration_settings = settings_for(
            data_dir, seed, duration_s, step_s, noise_seed=noise_seed, frames=frames
        )
        result["calibration"] = await calibrate(calibration_settings, data_dir)
    none = await one_run(settings, compensation="off")
    runs = {"none": none}
    if not drift_only:
        runs["preset"] = await one_run(settings, reference_run=none["run_id"])
    if identify:
        runs["identified"] = await one_run(
            settings, arm_model=MODEL_NAME, reference_run=none["run_id"]
        )
        runs["identified + model+ir"] = await one_run(
            settings, arm_model=MODEL_NAME, prediction="model+ir", reference_run=none["run_id"]
        )
    add_ratios(runs)
    return {**result, "runs": runs}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--duration", type=float, default=1800.0, help="arm time (s)")
    parser.add_argument("--step", type=float, default=60.0, help="step (s)")
    parser.add_argument("--profile", action="store_true", help="profile, print the top 25")
    parser.add_argument("--drift-only", action="store_true", help="the uncompensated run only")
    parser.add_argument(
        "--identify", action="store_true", help="calibration run, identification, two more runs"
    )
    parser.add_argument("--frames", type=int, default=None, help="arm.frames_per_measurement")
    args = parser.parse_args(argv)
    if args.identify and args.drift_only:
        parser.error("--identify needs the compensated runs (not with --drift-only)")
    logging.basicConfig(level=logging.WARNING)
    profile = cProfile.Profile() if args.profile else None
    load_before = os.getloadavg()
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-arm-played-") as folder:
        if profile is not None:
            profile.enable()
        run = bench(
            args.seed,
            Path(folder),
            args.duration,
            args.step,
            drift_only=args.drift_only,
            identify=args.identify,
            frames=args.frames,
        )
        result = asyncio.run(run)
        if profile is not None:
            profile.disable()
    load = os.getloadavg()
    result["wall_total_s"] = time.perf_counter() - started
    result["load_average_before"] = list(load_before)
    result["load_average"] = list(load)
    runs = result["runs"]
    print(
        f"A465 'a465-pick-and-place' played through the daemon, config/arm-sim-played.toml, "
        f"seed {args.seed}: {args.duration / 60:g} min of arm time, a step every {args.step:g} s, "
        f"{result['frames']} frame(s) per measurement"
    )
    print_table(
        [*CONTROLLER_COLUMNS, "moves", "wall s"],
        [[*controller_row(name, r), r["moves"], r["wall_s"]] for name, r in runs.items()],
    )
    drift = np.array(runs["none"]["drift_3d_um_per_step"])
    print(
        f"\nuncompensated drift: {drift.max():.1f} um at most; noise (1-sigma per position) "
        f"{runs['none']['noise_3d_um']:.2f} um, of the orientation "
        f"{runs['none']['noise_rotation_urad']:.1f} urad"
    )
    calibration = result.get("calibration")
    if calibration is not None:
        print_identification(calibration)
    print(
        f"wall time {result['wall_total_s']:.1f} s in all; load average before "
        f"{load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}, after "
        f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs"
    )
    if profile is not None:
        pstats.Stats(profile).sort_stats("cumulative").print_stats(40)
    name = "bench_arm_played"
    if args.identify:
        name += f"_identify_seed{args.seed}_frames{result['frames']}"
    write_results(name, result)
    return 0


def print_identification(calibration: dict[str, Any]) -> None:
    print(
        f"\nidentification of the calibration run (noise seed {calibration['noise_seed']}, "
        f"drift {calibration['max_3d_um']:.1f} um max, {calibration['rms_3d_um']:.1f} um RMS; "
        f"run {calibration['wall_s']:.1f} s, identification "
        f"{calibration['wall_identification_s']:.1f} s wall):"
    )
    print_parameter_table(calibration)


if __name__ == "__main__":
    raise SystemExit(main())
