"""What the end of a long run costs (issue 10 soak): the daemon's run summary and the run
report over a recorded run of N steps, in time and memory.

A one-hour run at a 20 ms step records 180,000 steps. The end of the run reads them all back
twice: for the summary the daemon stores with the run, and for the report (figures, tables).
The steps are written straight into a real run database (the recorder's schema), shaped like
the daemon's: a 17-node model temperature map, three IR regions and the stage timings as JSON.
Each case runs in a fresh child process, so its peak resident memory is its own and not the
previous case's.

Usage: ``.venv/bin/python benchmarks/bench_run_end.py [--steps N ...]``.
"""

from __future__ import annotations

import argparse
import json
import sqlite3
import subprocess
import sys
import tempfile
import time
from contextlib import closing
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.common import print_table, proc_status_mib, write_results
from daemon.storage.recorder import DATABASE_NAME, STEP_COLUMNS, Recorder

DEFAULT_STEPS = (18_000, 180_000)  # 6 min and 1 h at a 20 ms step
STEP_S = 0.02
NODES = tuple(str(n) for n in range(1, 18))
REGIONS = ("node-2", "node-9", "node-13")


def build_database(data_dir: Path, steps: int, seed: int = 1) -> int:
    """A finished run of ``steps`` steps in ``data_dir``'s run database; returns its id."""
    rng = np.random.default_rng(seed)
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run({"step_s": STEP_S}, {}, None, "bench")
    t = np.arange(steps) * STEP_S
    warm = 1.0 - np.exp(-t / 900.0)
    rows = []
    for k in range(steps):
        temperatures = {
            n: round(22.0 + 8.0 * warm[k] * (1 + i / 17), 4) for i, n in enumerate(NODES)
        }
        regions = {
            r: {"mean_c": 22.0 + 7.0 * warm[k], "max_c": 22.5 + 7.0 * warm[k]} for r in REGIONS
        }
        stages = {"model": 0.05, "move": 6.1, "frame": 3.2, "centroid": 1.1, "ir": 0.4}
        record = {
            "run_id": run_id,
            "step": k,
            "scheduled_s": t[k],
            "actual_s": t[k] + 1e-5,
            "lateness_s": abs(rng.normal(0, 1e-4)),
            "model_time_s": t[k],
            "predicted_x_um": 40.0 * warm[k],
            "predicted_y_um": 0.0,
            "predicted_z_um": 0.0,
            "offset_x_mm": -0.04 * warm[k],
            "offset_y_mm": 0.0,
            "offset_z_mm": 0.0,
            "pose_x_mm": 500.0 - 0.04 * warm[k],
            "pose_y_mm": 0.0,
            "pose_z_mm": 300.0,
            "centroid_x_px": 376.0 + rng.normal(0, 0.05),
            "centroid_y_px": 291.0 + rng.normal(0, 0.05),
            "centroid_x_um": 3842.0 + rng.normal(0, 0.5),
            "centroid_y_um": 2828.0 + rng.normal(0, 0.5),
            "drift_x_um": rng.normal(0, 0.5),
            "drift_y_um": rng.normal(0, 0.5),
            "residual_um": rng.normal(0, 0.5),
            "ir_json": json.dumps(regions),
            "flags": "",
            "error": "",
            "deformation_scale": 1.0,
            "model_temperatures_json": json.dumps(temperatures),
            "stage_ms_json": json.dumps(stages),
        }
        rows.append(tuple(record.get(c) for c in STEP_COLUMNS))
    with closing(sqlite3.connect(data_dir / DATABASE_NAME)) as db, db:
        db.executemany(
            f"INSERT INTO steps ({','.join(STEP_COLUMNS)}) "
            f"VALUES ({','.join('?' * len(STEP_COLUMNS))})",
            rows,
        )
    return run_id


def measure(case: str, data_dir: Path, run_id: int) -> dict[str, float]:
    """In this (child) process: run ``case`` once; its wall time and peak RSS."""
    from daemon.analysis import summarize_run
    from daemon.run.scheduler import percentiles
    from daemon.run.summary import SUMMARY_COLUMNS
    from daemon.storage.reports import write_run_report

    started = time.perf_counter()
    if case == "summary":  # what Daemon._summary reads and computes at the end of a run
        with Recorder(data_dir) as recorder:
            steps = recorder.run_steps(run_id, SUMMARY_COLUMNS)
            summarize_run(steps)
            percentiles(steps.column("lateness_s"))
    else:
        write_run_report(data_dir, run_id)
    seconds = time.perf_counter() - started
    # VmHWM, not ru_maxrss: a child would inherit its parent's ru_maxrss across exec
    return {"seconds": seconds, "peak_rss_mib": proc_status_mib("VmHWM")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, nargs="+", default=list(DEFAULT_STEPS))
    parser.add_argument(
        "--child", nargs=3, metavar=("CASE", "DATA_DIR", "RUN_ID"), help=argparse.SUPPRESS
    )
    args = parser.parse_args()
    if args.child:
        case, data_dir, run_id = args.child
        print(json.dumps(measure(case, Path(data_dir), int(run_id))))
        return
    results: list[dict[str, Any]] = []
    for steps in args.steps:
        with tempfile.TemporaryDirectory() as folder:
            data_dir = Path(folder)
            run_id = build_database(data_dir, steps)
            size_mib = (data_dir / DATABASE_NAME).stat().st_size / 2**20
            for case in ("summary", "report"):
                output = subprocess.run(
                    [sys.executable, __file__, "--child", case, str(data_dir), str(run_id)],
                    check=True,
                    capture_output=True,
                    text=True,
                ).stdout
                measured = json.loads(output.strip().splitlines()[-1])
                results.append({"steps": steps, "database_mib": size_mib, "case": case, **measured})
    print_table(
        ["steps", "database (MiB)", "case", "time (s)", "peak RSS (MiB)"],
        [
            [r["steps"], r["database_mib"], r["case"], r["seconds"], r["peak_rss_mib"]]
            for r in results
        ],
    )
    write_results("run_end", {"cases": results})


if __name__ == "__main__":
    main()
