"""Compensation on the simulated bench: the thesis's Table 6.1 figures for off, incremental and
absolute commands at a 1 s step, and absolute at the thesis's 34 s step (6.5-6.7).

Stationary two-link case, one hour of bench time on the virtual clock, the bench's truth
network equal to the controller's (thesis-two-link) and the camera-stand drift off, so that
what remains is the robot's positioning noise (bench.robot_noise_um) and the step.
Targets (issue 6): residual RMS <= 1.2 x the noise; largest error in the first 60 s <= 3 x it.

    .venv/bin/python benchmarks/bench_compensation.py [--duration 3600] [--quick]
"""

from __future__ import annotations

import argparse
import asyncio
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, write_results
from config import CONFIG_DIR, Settings, load_settings
from daemon.run.states import RunParameters
from daemon.service import Daemon, RunParameterError

CONFIG = CONFIG_DIR / "sim.toml"
CASES = (("off", 1.0), ("incremental", 1.0), ("absolute", 1.0), ("absolute", 34.0))


def bench_settings(
    data_dir: Path, mode: str, step_s: float, duration_s: float, scale: float
) -> Settings:
    base = load_settings(CONFIG, environ={})
    data = base.model_dump()
    # the controller's own preset as the truth (the default truth is the finer 2 mm geometry)
    data["bench"].update(clock="virtual", truth_network="thesis-two-link", stand_drift_um=0.0)
    data["compensation"].update(mode=mode, deformation_scale=scale)
    data["scheduler"].update(procedure="stationary", step_s=step_s, duration_s=duration_s)
    data["storage"].update(data_dir=data_dir, report_at_end=False)  # time the run alone
    return Settings.model_validate(data)


async def run_case(settings: Settings) -> dict[str, Any]:
    started = time.perf_counter()
    async with Daemon(settings) as daemon:
        info = await daemon.start_run(RunParameters.from_settings(settings))
        final = await daemon.wait_run()
        assert daemon.recorder is not None
        steps = daemon.recorder.steps(info["id"])
    wall_s = time.perf_counter() - started
    residual = np.array([np.nan if s.residual_um is None else s.residual_um for s in steps])
    times = np.array([s.scheduled_s for s in steps])
    first_minute = np.abs(residual[(times < 60.0) & np.isfinite(residual)])
    # captures follow each move, so they never see the drift that builds up between two
    # corrections (thesis 6.7: "the errors of the first two time steps were ten times greater
    # than the mean" at 34 s): the model's change over one step, scaled, is that drift
    scale = settings.compensation.deformation_scale
    predicted = np.array([s.predicted_x_um or 0.0 for s in steps])
    between = scale * np.abs(np.diff(predicted)) if predicted.size > 1 else np.array([math.nan])
    summary = final["summary"]
    return {
        **{k: summary.get(k) for k in ("n", "residual_max_um", "residual_mean_um")},
        "residual_std_um": summary.get("residual_std_um"),
        "residual_std_mean_um": summary.get("residual_std_mean_um"),
        "residual_rms_um": float(np.sqrt(np.nanmean(residual**2))),
        "uncompensated_max_um": summary.get("uncompensated_max_um"),
        # no reference run here: relative to the prediction (issue 19)
        "reduction_percent": summary.get("reduction_vs_prediction_percent"),
        "first_60s_max_um": float(first_minute.max()) if first_minute.size else math.nan,
        "max_drift_between_corrections_um": float(between.max()),
        "state": final["state"],
        "wall_s": wall_s,
    }


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=3600.0, help="bench seconds per run")
    parser.add_argument("--quick", action="store_true", help="600 s runs instead of an hour")
    parser.add_argument(
        "--scale",
        type=float,
        default=1.0,
        help="deformation scale (thesis 6.3 used 28: at 1 the 1 s increments are below the "
        "console's 0.001 mm and the incremental mode never moves)",
    )
    args = parser.parse_args()
    duration = 600.0 if args.quick else args.duration
    results: dict[str, Any] = {"duration_s": duration, "scale": args.scale, "cases": []}
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-compensation-") as folder:
        for index, (mode, step) in enumerate(CASES):
            settings = bench_settings(Path(folder) / str(index), mode, step, duration, args.scale)
            noise = settings.bench.robot_noise_um
            try:
                outcome = await run_case(settings)
            except RunParameterError as err:
                # incremental moves under the console's 0.001 mm are refused (thesis 6.3)
                print(f"{mode} at {step:g} s refused: {err}\n")
                results["cases"].append({"mode": mode, "step_s": step, "refused": str(err)})
                continue
            outcome.update(mode=mode, step_s=step, robot_noise_um=noise)
            outcome["rms_over_noise"] = outcome["residual_rms_um"] / noise if noise else math.nan
            outcome["first_60s_over_noise"] = (
                outcome["first_60s_max_um"] / noise if noise else math.nan
            )
            results["cases"].append(outcome)
            rows.append(
                [
                    mode,
                    step,
                    outcome["n"],
                    outcome["residual_max_um"],
                    outcome["residual_mean_um"],
                    outcome["residual_std_um"],
                    outcome["residual_std_mean_um"],
                    outcome["residual_rms_um"],
                    outcome["reduction_percent"],
                    outcome["first_60s_max_um"],
                    outcome["max_drift_between_corrections_um"],
                    outcome["rms_over_noise"],
                    outcome["first_60s_over_noise"],
                    outcome["wall_s"],
                ]
            )
    print(
        f"stationary two-link, {duration:.0f} s of bench time, deformation scale "
        f"{args.scale:g}, truth = controller's model,"
    )
    print("stand drift off; residuals in um (targets: RMS/noise <= 1.2, first-60s/noise <= 3);")
    print("between_max: predicted drift between two corrections (captures follow the moves)\n")
    print_table(
        [
            "mode",
            "step_s",
            "N",
            "max",
            "mean",
            "S_x",
            "S_xbar",
            "RMS",
            "reduction_%",
            "max_first_60s",
            "between_max",
            "RMS/noise",
            "60s/noise",
            "wall_s",
        ],
        rows,
    )
    write_results(f"bench_compensation_scale{args.scale:g}", results)


if __name__ == "__main__":
    asyncio.run(main())
