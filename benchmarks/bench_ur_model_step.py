"""The CPU of one followed UR step's model work (issue 31: arm.bending on must cost at most
3x the step without it).

One followed step's model work is FollowedKind._predict's: the room's reading to the model,
the model advanced 0.1 s (the shipped config's scheduler.step_s), the six joint temperatures
fused by the Kalman filter, the tool error at the robot's joints (daemon/run/followed/
setup.py's model, from config/ur5e-sim.toml). Measured per step as process CPU time
(``time.process_time``: every thread of the process, so a BLAS helper thread's spinning
counts) and wall time, over ``--steps`` steps after a warm-up, with the links' bending off
and on, in the same run, four ways:

- ``shipped``: the code as it is (the filter's products on one BLAS thread, its covariance
  stepped by its structure: daemon/model/blas.py, daemon/model/covariance.py);
- ``dense, BLAS threads``: the reference, what the code did before (the dense covariance
  formulas, BLAS on as many threads as it likes);
- ``dense, one thread`` and ``structured, BLAS threads``: each half of the change alone.

The readings are the model's own joint temperatures plus a sensor's noise (the filter's
work does not depend on their values). Load before and after is printed: the threaded BLAS
reference depends on it (its helper thread waits for a core).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import daemon.model.observer as observer_module
from benchmarks.common import print_table, write_results
from config.settings import load_settings
from daemon.run.followed.setup import JOINT_SENSOR_NOISE_C, followed_model
from daemon.run.states import RunParameters
from tests.test_arm_bending_fast import dense_joseph, dense_propagate  # the oracles

CONFIG = Path(__file__).resolve().parent.parent / "config" / "ur5e-sim.toml"
WARM_UP_STEPS = 20
Q = np.radians([20.0, -80.0, 90.0, -100.0, -90.0, 10.0])


def variant(dense: bool, threaded: bool) -> contextlib.AbstractContextManager[Any]:
    """The observer's module with the dense formulas and/or without the one-thread limit."""
    replaced: dict[str, Any] = {}
    if dense:
        replaced |= {"propagate_nodes": dense_propagate, "joseph_update": dense_joseph}
    if threaded:
        replaced["one_blas_thread"] = contextlib.nullcontext
    return (
        mock.patch.multiple(observer_module, **replaced) if replaced else contextlib.nullcontext()
    )


def measure(bending: bool, dense: bool, threaded: bool, steps: int) -> dict[str, Any]:
    settings = load_settings(CONFIG)
    settings = settings.model_copy(
        update={"arm": settings.arm.model_copy(update={"bending": bending})}
    )
    parameters = RunParameters.from_settings(settings)
    model = followed_model(settings, parameters)
    rng = np.random.default_rng(0)
    step_s = parameters.step_s * parameters.time_scale
    room_c = settings.model.ambient_c

    def run(first: int, count: int) -> None:
        for k in range(first, first + count):
            model.follow_room(room_c + 1e-4 * k)
            model.advance_to((k + 1) * step_s)
            joints = model.temperatures_c()
            reading = np.array(list(joints.values())) + rng.normal(0, JOINT_SENSOR_NOISE_C, 6)
            model.observe(reading.tolist())
            model.tool_error(Q)

    with variant(dense, threaded):
        run(0, WARM_UP_STEPS)
        cpu, wall = time.process_time(), time.perf_counter()
        run(WARM_UP_STEPS, steps)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    observer = model.controller.observer
    return {
        "bending": bending,
        "dense": dense,
        "threaded_blas": threaded,
        "nodes": model.controller.thermal.network.node_count,
        "filter_states": None if observer is None else int(observer._p.shape[0]),
        "steps": steps,
        "cpu_ms_per_step": 1e3 * cpu / steps,
        "wall_ms_per_step": 1e3 * wall / steps,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=600, help="measured steps per case")
    parser.add_argument("--name", default="ur_model_step", help="the results file's name")
    args = parser.parse_args()
    cases = [
        ("shipped", False, False),
        ("dense, BLAS threads (before)", True, True),
        ("dense, one thread", True, False),
        ("structured, BLAS threads", False, True),
    ]
    load_before = os.getloadavg()[0]
    runs = []
    for label, dense, threaded in cases:
        for bending in (False, True):
            result = measure(bending, dense, threaded, args.steps)
            result["case"] = label
            runs.append(result)
    load_after = os.getloadavg()[0]
    table = []
    for label, *_ in cases:
        off, on = (
            next(r for r in runs if r["case"] == label and r["bending"] is b) for b in (False, True)
        )
        table.append(
            [
                label,
                off["cpu_ms_per_step"],
                on["cpu_ms_per_step"],
                on["cpu_ms_per_step"] / off["cpu_ms_per_step"],
                off["wall_ms_per_step"],
                on["wall_ms_per_step"],
            ]
        )
    print(
        f"one followed step's model work (config/ur5e-sim.toml, 0.1 s steps), {args.steps} "
        f"steps per case; filter states: {runs[0]['filter_states']} without bending, "
        f"{runs[1]['filter_states']} with"
    )
    print_table(["case", "CPU ms off", "CPU ms on", "on/off", "wall ms off", "wall ms on"], table)
    shipped = table[0]
    print(
        f"target bending on <= 3x off: shipped {shipped[3]:.2f}x "
        f"({shipped[2]:.2f} ms against {shipped[1]:.2f} ms); before: {table[1][3]:.2f}x "
        f"({table[1][2]:.2f} ms)"
    )
    print(f"load (1 min) before/after: {load_before:.2f} / {load_after:.2f}")
    write_results(
        args.name, {"steps": args.steps, "runs": runs, "load_1min": [load_before, load_after]}
    )


if __name__ == "__main__":
    main()
