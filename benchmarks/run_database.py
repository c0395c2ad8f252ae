"""A long run's steps written straight into a run database, fast (issue 26): a 24-h run at a
20 ms step is 4.32 million steps. One ``executemany`` over a generator (nothing held in memory)
of rows shaped like the daemon's -- the JSON columns as one constant string each (their size,
not their values, is what the end of a run pays for) and the numeric columns varying.
Used by benchmarks/bench_stop.py and the tests of a long run's end."""

from __future__ import annotations

import json
import math
import sqlite3
from collections.abc import Iterator
from contextlib import closing
from pathlib import Path
from typing import Any

from daemon.storage.recorder import DATABASE_NAME, STEP_COLUMNS

#: 24 h at 20 ms.
DAY_STEPS = 4_320_000
STEP_S = 0.02
_TEMPERATURES = json.dumps({str(n): 22.0 + n / 10 for n in range(1, 18)})
_IR = json.dumps({r: {"mean_c": 27.0, "max_c": 27.5} for r in ("node-2", "node-9", "node-13")})
_STAGES = json.dumps({"model": 0.05, "move": 6.1, "frame": 3.2, "centroid": 1.1, "ir": 0.4})


def _rows(run_id: int, first_step: int, count: int) -> Iterator[tuple[Any, ...]]:
    index = {name: i for i, name in enumerate(STEP_COLUMNS)}
    template: list[Any] = [None] * len(STEP_COLUMNS)
    constants = {
        "run_id": run_id,
        "ir_json": _IR,
        "model_temperatures_json": _TEMPERATURES,
        "stage_ms_json": _STAGES,
        "flags": "",
        "error": "",
        "deformation_scale": 1.0,
        "predicted_y_um": 0.0,
        "predicted_z_um": 0.0,
        "offset_y_mm": 0.0,
        "offset_z_mm": 0.0,
        "pose_y_mm": 0.0,
        "pose_z_mm": 300.0,
    }
    for name, value in constants.items():
        template[index[name]] = value
    step_i, scheduled_i, actual_i = index["step"], index["scheduled_s"], index["actual_s"]
    varying = [index[n] for n in ("predicted_x_um", "drift_x_um", "residual_um", "centroid_x_um")]
    for k in range(first_step, first_step + count):
        t = k * STEP_S
        row = list(template)
        row[step_i] = k
        row[scheduled_i] = t
        row[actual_i] = t + 1e-5
        value = 40.0 * (1.0 - math.exp(-t / 900.0))
        for i in varying:
            row[i] = value
        yield tuple(row)


def add_steps(data_dir: Path, run_id: int, count: int, first_step: int = 0) -> None:
    """``count`` steps of run ``run_id`` from step ``first_step``, in one transaction."""
    names = ",".join(STEP_COLUMNS)
    marks = ",".join("?" * len(STEP_COLUMNS))
    with closing(sqlite3.connect(data_dir / DATABASE_NAME, timeout=60.0)) as db, db:
        db.executemany(
            f"INSERT INTO steps ({names}) VALUES ({marks})", _rows(run_id, first_step, count)
        )
