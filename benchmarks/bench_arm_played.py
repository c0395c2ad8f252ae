"""Issue 20: the duty cycle played by the robot through the daemon (config/arm-sim-played.toml:
the console driver moves the C500C emulator in joint space on a pty through every pose of the
A465's pick-and-place at its speed and dwell, the arm bench's truth heated by the motion the
emulator performs, time_scale 1 on a virtual clock paced by the cycle).

Two runs of the same arm: none (the drift) and the preset arm model (compensated, with the
first as reference). Reported: the measured 3-D residual (RMS and largest over the steps), the
share of the uncompensated RMS removed, the rotation error, the moves the emulator performed,
and the wall time per run (how long minutes or hours of arm time take through the daemon).

    .venv/bin/python benchmarks/bench_arm_played.py [--duration 1800] [--step 60] [--seed N]
        [--profile] [--drift-only]
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

from benchmarks.bench_arm_daemon import figures
from benchmarks.common import print_table, write_results
from config import Settings, load_settings
from daemon.runs import RunParameters
from daemon.service import Daemon
from drivers.clock import make_clock
from drivers.factory import Devices

CONFIG = Path(__file__).resolve().parent.parent / "config" / "arm-sim-played.toml"


def settings_for(data_dir: Path, seed: int, duration_s: float, step_s: float) -> Settings:
    data = load_settings(CONFIG).model_dump()
    data["bench"].update({"seed": seed})
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


async def bench(
    seed: int, data_dir: Path, duration_s: float, step_s: float, drift_only: bool = False
) -> dict[str, Any]:
    settings = settings_for(data_dir, seed, duration_s, step_s)
    none = await one_run(settings, compensation="off")
    runs = {"none": none}
    if not drift_only:
        runs["preset"] = await one_run(settings, reference_run=none["run_id"])
    for result in runs.values():
        result["reduction_3d"] = 1.0 - result["rms_3d_um"] / none["rms_3d_um"]
        result["rms_over_noise"] = result["rms_3d_um"] / result["noise_3d_um"]
    return {"seed": seed, "duration_s": duration_s, "step_s": step_s, "runs": runs}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--duration", type=float, default=1800.0, help="arm time (s)")
    parser.add_argument("--step", type=float, default=60.0, help="step (s)")
    parser.add_argument("--profile", action="store_true", help="profile, print the top 25")
    parser.add_argument("--drift-only", action="store_true", help="the uncompensated run only")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    profile = cProfile.Profile() if args.profile else None
    with tempfile.TemporaryDirectory(prefix="bench-arm-played-") as folder:
        if profile is not None:
            profile.enable()
        run = bench(args.seed, Path(folder), args.duration, args.step, args.drift_only)
        result = asyncio.run(run)
        if profile is not None:
            profile.disable()
    load = os.getloadavg()
    result["load_average"] = list(load)
    runs = result["runs"]
    print(
        f"A465 'a465-pick-and-place' played through the daemon, config/arm-sim-played.toml, "
        f"seed {args.seed}: {args.duration / 60:g} min of arm time, a step every {args.step:g} s"
    )
    print_table(
        [
            "controller",
            "RMS 3-D um",
            "max 3-D um",
            "last 1/3 RMS um",
            "3-D removed",
            "RMS/noise",
            "RMS rot urad",
            "moves",
            "wall s",
        ],
        [
            [
                name,
                r["rms_3d_um"],
                r["max_3d_um"],
                r["last_third_rms_3d_um"],
                "-" if name == "none" else f"{100 * r['reduction_3d']:.1f} %",
                r["rms_over_noise"],
                r["rms_rotation_urad"],
                r["moves"],
                r["wall_s"],
            ]
            for name, r in runs.items()
        ],
    )
    drift = np.array(runs["none"]["drift_3d_um_per_step"])
    print(
        f"\nuncompensated drift: {drift.max():.1f} um at most; noise (1-sigma per position) "
        f"{runs['none']['noise_3d_um']:.2f} um; load average {load[0]:.2f} {load[1]:.2f} "
        f"{load[2]:.2f} on {os.cpu_count()} CPUs"
    )
    if profile is not None:
        pstats.Stats(profile).sort_stats("cumulative").print_stats(40)
    write_results("bench_arm_played", result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
