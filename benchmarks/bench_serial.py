"""C500C link: round trip of one absolute-move step over a paced pty, and the positioning spread.

1. The absolute-move sequence (`set`, `wshift`, `moves`, `finish`, `w2`) through the real driver
   and the emulator paced at each baud rate: measured step time against the wire time of its
   bytes (10 bit times per byte) plus the emulated move time.
2. 143 steps (the thesis's N) of absolute and of incremental commands at the default 0.9 um
   positioning noise: S_x of the true position error and of the `w2` read-back (0.001 mm
   resolution), to set beside Table 6.1 (absolute 0.921 um, incremental 2.107 um).

Run: .venv/bin/python benchmarks/bench_serial.py [--quick]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, write_results
from config.settings import RobotSettings
from drivers.c500c.robot import C500CRobot
from drivers.sim.emulator import BITS_PER_CHARACTER, C500CEmulator, EmulatorConfig

MOVE_MS = 5.0
N_THESIS = 143


async def round_trips(baudrate: int, steps: int) -> dict[str, float]:
    config = EmulatorConfig(baudrate=baudrate, paced=True, move_ms=MOVE_MS, seed=1)
    settings = RobotSettings(baudrate=baudrate, command_timeout_s=5.0)
    emulator = C500CEmulator(config)
    async with emulator, C500CRobot(settings, port=emulator.device_path) as robot:
        await robot.teach_goal()
        durations, wire = [], []
        for step in range(steps):
            started = time.perf_counter()
            result = await robot.move_absolute((0.001 * (step % 7), 0.0, 0.0))
            durations.append(time.perf_counter() - started)
            byte_count = result.bytes_sent + result.bytes_received
            wire.append(byte_count * BITS_PER_CHARACTER / baudrate)
    median_s = statistics.median(durations)
    expected_s = statistics.median(wire) + MOVE_MS / 1000.0
    return {
        "baud": baudrate,
        "steps": steps,
        "median_ms": median_s * 1000.0,
        "p95_ms": float(np.percentile(durations, 95)) * 1000.0,
        "wire_plus_move_ms": expected_s * 1000.0,
        "overhead_ms": (median_s - expected_s) * 1000.0,
    }


async def spread(mode: str, steps: int, seed: int) -> dict[str, float | str]:
    config = EmulatorConfig(paced=False, move_ms=0.0, seed=seed)
    emulator = C500CEmulator(config)
    async with emulator, C500CRobot(RobotSettings(), port=emulator.device_path) as robot:
        goal = await robot.teach_goal()
        true_errors, read_errors = [], []
        previous = 0.0
        for step in range(steps):
            target = 0.040 * (1.0 - np.exp(-step / 30.0))  # a warm-up-like ramp (mm)
            if mode == "absolute":
                result = await robot.move_absolute((target, 0.0, 0.0))
                commanded = result.commanded_mm[0]
            else:
                result = await robot.move_incremental((target - previous, 0.0, 0.0))
                commanded = previous + result.commanded_mm[0]
            previous = commanded
            true_x = emulator.state.actual[0]
            true_errors.append((true_x - goal.x - commanded) * 1000.0)
            read_errors.append((result.actual.x - goal.x - commanded) * 1000.0)
    return {
        "mode": mode,
        "N": steps,
        "true_mean_um": float(np.mean(true_errors)),
        "true_S_x_um": float(np.std(true_errors, ddof=1)),
        "read_back_S_x_um": float(np.std(read_errors, ddof=1)),
    }


async def main(quick: bool) -> None:
    steps = 10 if quick else 50
    trips = [await round_trips(baud, steps) for baud in (19200, 57600, 115200)]
    print("Absolute-move step over a paced pty (real driver, emulated C500C, move 5 ms):\n")
    print_table(list(trips[0]), [list(row.values()) for row in trips])
    spreads = [await spread(mode, N_THESIS, seed=1) for mode in ("absolute", "incremental")]
    print("\nPositioning spread at 0.9 um noise (Table 6.1: absolute 0.921, incremental 2.107):\n")
    print_table(list(spreads[0]), [list(row.values()) for row in spreads])
    write_results("serial", {"round_trips": trips, "spread": spreads})


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="10 steps per baud rate")
    asyncio.run(main(parser.parse_args().quick))
