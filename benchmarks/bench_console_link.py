"""C500C console link (issue 17): bytes per step and step period against the wire limit, and the
connect handshake under load.

1. Back-to-back absolute-move steps through the real driver and the emulator paced at the baud
   rate (10 bit times per byte both ways, the firmware's `w2` layout), at `robot.readback_every`
   1 (the default: a read-back every step) and 5: bytes per step, the step period (median and
   p95), and the wire limit = bytes per step x 10 / baud + the emulated move time. Issue 17's
   target: period <= 1.3 x the wire limit.
2. Handshake stress: open the emulator and connect the driver (synchronise on a probe line,
   `new cur`, `online on`), teach and make one move, N times in a row, with every core kept
   busy by spinning processes (``--saturate``): the number of failures (target: zero).

Run: .venv/bin/python benchmarks/bench_console_link.py [--quick] [--handshakes N] [--saturate]
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, write_results
from config.settings import RobotSettings
from drivers.c500c.robot import C500CRobot
from drivers.errors import DeviceError
from drivers.sim.emulator import BITS_PER_CHARACTER, C500CEmulator, EmulatorConfig

MOVE_MS = 5.0
TARGET_RATIO = 1.3


async def steps(baudrate: int, readback_every: int, count: int) -> dict[str, Any]:
    config = EmulatorConfig(baudrate=baudrate, paced=True, move_ms=MOVE_MS, seed=1)
    settings = RobotSettings(baudrate=baudrate, readback_every=readback_every)
    emulator = C500CEmulator(config)
    async with emulator, C500CRobot(settings, port=emulator.device_path) as robot:
        await robot.teach_goal()
        periods, byte_counts, writes = [], [], []
        for step in range(count):
            started = time.perf_counter()
            result = await robot.move_absolute((0.001 * (step % 7), 0.0, 0.0))
            periods.append(time.perf_counter() - started)
            byte_counts.append(result.bytes_sent + result.bytes_received)
            writes.append(len(result.round_trips_s))
    # per step, averaged over whole read-back cycles (a step without read-back is shorter)
    cycle = readback_every * max(count // readback_every, 1)
    mean_bytes = float(np.mean(byte_counts[:cycle]))
    mean_period_s = float(np.mean(periods[:cycle]))
    wire_s = mean_bytes * BITS_PER_CHARACTER / baudrate + MOVE_MS / 1000.0
    return {
        "baud": baudrate,
        "readback_every": readback_every,
        "steps": count,
        "writes_per_step": float(np.mean(writes[:cycle])),
        "bytes_per_step": mean_bytes,
        "mean_period_ms": mean_period_s * 1000.0,
        "median_period_ms": statistics.median(periods) * 1000.0,
        "p95_period_ms": float(np.percentile(periods, 95)) * 1000.0,
        "wire_limit_ms": wire_s * 1000.0,
        "ratio": mean_period_s / wire_s,
        "target_met": mean_period_s / wire_s <= TARGET_RATIO,
    }


def _spin() -> None:  # a process that keeps one core busy until terminated
    while True:
        pass


async def handshakes(count: int, baudrate: int) -> dict[str, Any]:
    failures: list[str] = []
    durations = []
    for attempt in range(count):
        config = EmulatorConfig(baudrate=baudrate, paced=True, move_ms=MOVE_MS, seed=attempt)
        started = time.perf_counter()
        try:
            emulator = C500CEmulator(config)
            async with emulator, C500CRobot(RobotSettings(), port=emulator.device_path) as robot:
                await robot.teach_goal()
                await robot.move_absolute((0.001, 0.0, 0.0))
        except DeviceError as err:
            failures.append(f"{attempt}: {err}")
        durations.append(time.perf_counter() - started)
    return {
        "baud": baudrate,
        "starts": count,
        "failures": len(failures),
        "failure_messages": failures[:10],
        "median_start_ms": statistics.median(durations) * 1000.0,
        "max_start_ms": max(durations) * 1000.0,
    }


async def main(quick: bool, handshake_count: int, saturate: bool) -> None:
    count = 20 if quick else 100
    rows = [
        await steps(57600, 1, count),
        await steps(57600, 5, count),
        await steps(115200, 1, count),
    ]
    print(
        f"Absolute-move steps over a paced pty (real driver, emulated C500C, move {MOVE_MS} ms):\n"
    )
    print_table(list(rows[0]), [list(row.values()) for row in rows])

    burners: list[multiprocessing.Process] = []
    if saturate:
        burners = [
            multiprocessing.Process(target=_spin, daemon=True) for _ in range(os.cpu_count() or 2)
        ]
        for burner in burners:
            burner.start()
    try:
        stress = await handshakes(handshake_count, 57600)
    finally:
        for burner in burners:
            burner.terminate()
            burner.join()
    stress["cores_saturated"] = len(burners)
    print(f"\nBench starts (emulator, connect, teach, one move); {len(burners)} busy cores\n")
    table = {k: v for k, v in stress.items() if k != "failure_messages"}
    print_table(list(table), [list(table.values())])
    for message in stress["failure_messages"]:
        print("  failure:", message)
    write_results("console_link", {"steps": rows, "handshake_stress": stress})


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="20 steps per configuration")
    parser.add_argument("--handshakes", type=int, default=200, help="bench starts (default 200)")
    parser.add_argument(
        "--saturate", action="store_true", help="keep every core busy during the starts"
    )
    options = parser.parse_args()
    asyncio.run(main(options.quick, options.handshakes, options.saturate))
