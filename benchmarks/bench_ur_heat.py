"""A followed run's motor heat from the measured motion against the duty cycle's (issue 31,
arm.heat_from): the UR5e program PAUSED for an hour in the middle of an 8-h day.

On an ACCELERATED clock (benchmarks/ur_recorded.py, as bench_ur_identify.py), per scenario:

1. the uncompensated calibration run of ``--hours`` is recorded with the program paused over
   ``--pause`` (h from, h to) -- each step's measured heat recorded (``heat_json``);
2. ``calibrate model`` identifies it twice: on the recorded heat (what a followed run with
   arm.heat_from measured records), and on the same run with the heat column emptied (the duty
   cycle's heat: what identification saw before issue 31's measured heat);
3. the compensated day (the same pause) is replayed against the same truth with: the preset
   model alone (no joint temperatures) on each heat; the preset + joint temperatures on each
   heat; each identified model + joint temperatures on its own heat; and the truth's own
   factors + joint temperatures on the measured heat (the reference: what the model's
   structure allows), and the truth's own factors alone (no joint temperatures) on each heat:
   the heat source's effect with nothing to absorb it.

Removal = 1 - rms(residual) / rms(uncompensated) over the last half of the day (a warm arm).
The identified heat factors are printed beside the truth's. Scenarios: the nominal bench
(seed 1) and a truth whose shoulder and elbow motors heat x1.4 (what identification must find).
The model is config/ur5e-sim.toml's (arm.bending off, as shipped; ``--bending`` on, as
bench_ur_identify.py's table; the bench's room thermometer).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sqlite3
import sys
import tempfile
import time
from contextlib import closing
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.bench_ur_identify import (
    CONFIG,
    HOURS,
    MEASURE_EVERY_S,
    NOMINAL,
    SAMPLE_S,
    UM_PER_MM,
    calibrate,
    write_truth_factors,
)
from benchmarks.common import print_table, write_results
from benchmarks.ur_recorded import compensated_removal, emulated, record_calibration_run
from config.settings import Settings, load_settings
from daemon.arm.arm_model import saved_arm_models_dir
from daemon.storage.recorder import DATABASE_NAME

PAUSE_H = (3.0, 4.0)


def scenarios(quick: bool) -> list[tuple[str, int, dict[str, Any]]]:
    if quick:
        return NOMINAL
    return [*NOMINAL, ("shoulder+elbow x1.4", 1, {"heat_scales": (1.0, 1.4, 1.4, 1.0, 1.0, 1.0)})]


BENDING = [False]  # --bending: arm.bending on (as bench_ur_identify.py's table)


def settings_in(data_dir: Path, heat_from: str, prediction: str = "model+ir") -> Settings:
    data = load_settings(CONFIG).model_dump()
    data["arm"]["bending"] = BENDING[0]
    data["storage"]["data_dir"] = str(data_dir)
    data["model"]["prediction"] = prediction
    data["arm"]["heat_from"] = heat_from
    return Settings.model_validate(data)


def without_heat(source: Path, target: Path) -> None:
    """The recorded run as a run recorded without measured heat: the column emptied."""
    shutil.copytree(source, target)
    with closing(sqlite3.connect(target / DATABASE_NAME)) as db:
        db.execute("UPDATE steps SET heat_json = NULL")
        db.commit()


def one(
    name: str, seed: int, truth: dict[str, Any], hours: float, pause_h: tuple[float, float]
) -> dict[str, Any]:
    pauses = ((pause_h[0] * 3600.0, pause_h[1] * 3600.0),)
    with tempfile.TemporaryDirectory(prefix="bench-ur-heat-") as folder:
        measured_dir, duty_dir = Path(folder) / "measured", Path(folder) / "duty"
        began = time.process_time()
        run_id, sigmas_mm = record_calibration_run(
            settings_in(measured_dir, "measured"),
            emulated(seed, truth),
            measured_dir,
            hours=hours,
            measure_every_s=MEASURE_EVERY_S,
            pauses=pauses,
        )
        record_cpu = time.process_time() - began
        without_heat(measured_dir, duty_dir)
        identified = {}
        for label, data_dir in (("measured", measured_dir), ("duty-cycle", duty_dir)):
            outcome, _ = calibrate(data_dir, run_id)
            refit = outcome["identified"]["refit"]
            identified[label] = {
                p["name"]: [p["value"], p["standard_error"]] for p in refit["parameters"]
            }
            shutil.copy(  # both models beside each other for the replay
                saved_arm_models_dir(data_dir) / "bench.toml",
                saved_arm_models_dir(measured_dir) / f"id-{label}.toml",
            )
        controller = emulated(seed, truth)
        write_truth_factors(measured_dir, controller, bending=BENDING[0])
        began = time.process_time()
        rows = compensated_removal(
            {
                "preset, model only, measured heat": (
                    settings_in(measured_dir, "measured", "model"),
                    None,
                ),
                "preset, model only, duty-cycle heat": (
                    settings_in(measured_dir, "duty-cycle", "model"),
                    None,
                ),
                "preset + joints, measured heat": (settings_in(measured_dir, "measured"), None),
                "preset + joints, duty-cycle heat": (settings_in(measured_dir, "duty-cycle"), None),
                "identified + joints, measured heat": (
                    settings_in(measured_dir, "measured"),
                    "id-measured",
                ),
                "identified + joints, duty-cycle heat": (
                    settings_in(measured_dir, "duty-cycle"),
                    "id-duty-cycle",
                ),
                "truth's factors + joints, measured heat": (
                    settings_in(measured_dir, "measured"),
                    "truth",
                ),
                # the heat alone, without the joint temperatures to absorb its error
                "truth's factors, model only, measured heat": (
                    settings_in(measured_dir, "measured", "model"),
                    "truth",
                ),
                "truth's factors, model only, duty-cycle heat": (
                    settings_in(measured_dir, "duty-cycle", "model"),
                    "truth",
                ),
            },
            controller,
            hours=hours,
            sample_s=SAMPLE_S,
            pauses=pauses,
        )
        replay_cpu = time.process_time() - began
    return {
        "scenario": name,
        "pause_h": list(pause_h),
        "truth_heat_scales": [float(v) for v in controller.bench.heat_scales],
        "measurements": len(sigmas_mm),
        "sigma_um": UM_PER_MM * sum(sigmas_mm) / len(sigmas_mm),
        "identified": identified,
        "rows": rows,
        "record_cpu_s": record_cpu,
        "replay_cpu_s": replay_cpu,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 h (paused 0.75-1.25 h), nominal")
    parser.add_argument("--hours", type=float, help=f"default {HOURS:g}")
    parser.add_argument("--pause", type=float, nargs=2, metavar=("FROM_H", "TO_H"))
    parser.add_argument("--name", default="ur_heat", help="the results file's name")
    parser.add_argument("--only", help="run only the scenarios whose name contains this")
    parser.add_argument(
        "--bending", action="store_true", help="arm.bending on (the share identified too)"
    )
    args = parser.parse_args()
    BENDING[0] = args.bending
    hours = args.hours or (2.0 if args.quick else HOURS)
    pause_h = tuple(args.pause) if args.pause else ((0.75, 1.25) if args.quick else PAUSE_H)
    load_before = os.getloadavg()[0]
    results: dict[str, Any] = {
        "hours": hours,
        "pause_h": list(pause_h),
        "bending": args.bending,
        "runs": [],
    }
    table = []
    for name, seed, truth in scenarios(args.quick):
        if args.only and args.only not in name:
            continue
        r = one(name, seed, truth, hours, (pause_h[0], pause_h[1]))
        results["runs"].append(r)
        for row, v in r["rows"].items():
            table.append(
                [
                    name,
                    row,
                    v["uncompensated_rms_um"],
                    v["rms_um"],
                    f"{100 * v['removed']:.1f} %",
                    v["rms_um"] / r["sigma_um"],
                    v["max_um"],
                ]
            )
        heat = {
            label: {k: round(v[0], 3) for k, v in values.items() if k.startswith("heat:")}
            for label, values in r["identified"].items()
        }
        print(
            f"{name}: truth heat factors {[round(v, 3) for v in r['truth_heat_scales']]}; "
            f"identified on the measured heat {heat.get('measured')}, on the duty cycle's "
            f"{heat.get('duty-cycle')}; record CPU {r['record_cpu_s']:.0f} s, replay CPU "
            f"{r['replay_cpu_s']:.0f} s",
            file=sys.stderr,
        )
    results["load_1min"] = [load_before, os.getloadavg()[0]]
    print(
        f"{hours:g} h of the UR5e program paused from {pause_h[0]:g} h to {pause_h[1]:g} h; "
        f"model: config/ur5e-sim.toml (bending {'on' if args.bending else 'off'}, room sim)"
    )
    print_table(
        ["scenario", "prediction", "uncomp rms um", "rms um", "removed", "x sigma", "max um"],
        table,
    )
    print(f"load (1 min) before/after: {results['load_1min']}")
    write_results(args.name, results)


if __name__ == "__main__":
    main()
