"""The fast path (controller/PROTOCOL.md): the server driver against the emulated program paced
at 115200 baud over a real pty.

1. Bytes per step and the step period of back-to-back absolute moves, against the wire limit
   (bytes x 0.0868 ms + move time; issue 17 target: period <= 1.2 x the limit).
2. Hold-to-halt latency: a long move in progress, then ``stop()``; the time from the call to
   the emulated controller halting the arm, and to the host holding the move's 044 reply.
3. A 20 ms step on absolute deadlines for 60 s (``--minutes 10``: issue 17's ten minutes):
   overruns (a step still running at the next deadline; as the daemon's scheduler, the
   missed deadlines are then skipped and counted), step time p99/max, lateness, and the
   garbage collector's pauses (gc.callbacks) with how many fell inside a step.

The emulated controller runs in its own process (``thermocomp emulate c500c --server``) for 1
and 3, as the controller is another machine: in the benchmark's process its work and its
collections would land in the host's step. Hold-to-halt needs the emulator's own events
(when the arm stops), so 2 keeps it in-process. ``--emulator inline`` puts it back in-process
for 1 and 3, ``--no-freeze`` skips freezing the host's start-up heap (daemon/heap.py, as
``thermocomp serve`` does): the two causes of issue 17's overruns, to reproduce them.

Run: .venv/bin/python benchmarks/bench_fast_path.py [--quick] [--minutes M]
     [--emulator process|inline] [--no-freeze]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import logging
import math
import os
import signal
import statistics
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, write_results
from config.settings import RobotSettings
from daemon.heap import freeze_startup_heap
from drivers.c500c import server_protocol as proto
from drivers.c500c.server import C500CServerRobot
from drivers.errors import DeviceReportedError
from drivers.sim.emulator import BITS_PER_CHARACTER
from drivers.sim.server_emulator import C500CServerEmulator, server_emulator_config

BAUD = 115200
MOVE_MS = 5.0
STEP_S = 0.020
TARGET_RATIO = 1.2
LONG_MOVE_MS = 60_000.0
SETTINGS = RobotSettings(driver="c500c-server", command_timeout_s=5.0, move_timeout_s=120.0)
ROOT = Path(__file__).resolve().parent.parent
#: How long the emulator process may take to start and print its device path (s).
EMULATOR_START_S = 60.0


def _emulator(move_ms: float) -> C500CServerEmulator:
    return C500CServerEmulator(server_emulator_config(baudrate=BAUD, paced=True, move_ms=move_ms))


def _ms(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) * 1000.0


@contextlib.asynccontextmanager
async def _emulator_process(move_ms: float) -> AsyncIterator[str]:
    """``thermocomp emulate c500c --server`` in its own process; yields its pty's path."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    command = ["-m", "api", "emulate", "c500c", "--server", "--baud", str(BAUD)]
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        *command,
        "--move-ms",
        f"{move_ms:g}",
        stdout=asyncio.subprocess.PIPE,
        env=env,
        cwd=ROOT,
    )
    try:
        assert process.stdout is not None
        line = await asyncio.wait_for(process.stdout.readline(), EMULATOR_START_S)
        if not line:
            raise RuntimeError(f"the emulator exited with {await process.wait()}")
        yield line.decode().strip()
    finally:
        if process.returncode is None:
            process.send_signal(signal.SIGTERM)
        await process.wait()


@contextlib.asynccontextmanager
async def _robot(move_ms: float, inline: bool) -> AsyncIterator[C500CServerRobot]:
    """The host driver connected to the emulated program (own process unless ``inline``)."""
    async with contextlib.AsyncExitStack() as stack:
        if inline:
            port = (await stack.enter_async_context(_emulator(move_ms))).device_path
        else:
            port = await stack.enter_async_context(_emulator_process(move_ms))
        yield await stack.enter_async_context(C500CServerRobot(SETTINGS, port=port))


class _GcPauses:
    """Every collection's start (perf_counter) and pause (s), through gc.callbacks."""

    def __init__(self) -> None:
        self.pauses: list[tuple[float, float, int]] = []  # (start, pause, generation)
        self._started = 0.0

    def __call__(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._started = time.perf_counter()
        else:
            self.pauses.append(
                (self._started, time.perf_counter() - self._started, info["generation"])
            )

    def __enter__(self) -> _GcPauses:
        gc.callbacks.append(self)
        return self

    def __exit__(self, *_: object) -> None:
        gc.callbacks.remove(self)


async def step_period(steps: int, inline: bool) -> dict[str, Any]:
    async with _robot(MOVE_MS, inline) as robot:
        await robot.teach_goal()
        durations, byte_counts = [], []
        for step in range(steps):
            started = time.perf_counter()
            result = await robot.move_absolute((0.0001 * (step % 7), 0.0, 0.0))
            durations.append(time.perf_counter() - started)
            byte_counts.append(result.bytes_sent + result.bytes_received)
    byte_count = statistics.median(byte_counts)
    wire_ms = byte_count * BITS_PER_CHARACTER / BAUD * 1000.0
    limit_ms = wire_ms + MOVE_MS
    median_ms = statistics.median(durations) * 1000.0
    return {
        "baud": BAUD,
        "steps": steps,
        "bytes_per_step": byte_count,
        "wire_ms": wire_ms,
        "move_ms": MOVE_MS,
        "limit_ms": limit_ms,
        "median_ms": median_ms,
        "p99_ms": _ms(durations, 99),
        "ratio": median_ms / limit_ms,
        "target": TARGET_RATIO,
    }


async def hold_latency(trials: int) -> dict[str, Any]:
    emulator = _emulator(LONG_MOVE_MS)
    to_halt, to_reply = [], []
    async with emulator, C500CServerRobot(SETTINGS, port=emulator.device_path) as robot:
        await robot.teach_goal()
        for trial in range(trials):
            emulator.motion_started.clear()  # set by the previous trial's move
            emulator.motion_halted.clear()
            move = asyncio.create_task(robot.move_absolute((0.001 * (trial % 5), 0.0, 0.0)))
            await asyncio.wait_for(emulator.motion_started.wait(), 5.0)
            started = time.perf_counter()
            stop = asyncio.create_task(robot.stop())
            await asyncio.wait_for(emulator.motion_halted.wait(), 5.0)  # the arm stops
            to_halt.append(time.perf_counter() - started)
            try:
                await move
            except DeviceReportedError as err:
                assert err.code == proto.Status.HALTED, err
            to_reply.append(time.perf_counter() - started)
            await stop
            await robot.resume()
    return {
        "trials": trials,
        "halt_p50_ms": _ms(to_halt, 50),
        "halt_p99_ms": _ms(to_halt, 99),
        "halt_max_ms": max(to_halt) * 1000.0,
        "reply_p50_ms": _ms(to_reply, 50),
        "reply_p99_ms": _ms(to_reply, 99),
    }


async def fixed_step(
    duration_s: float, inline: bool, freeze: bool, step_s: float = STEP_S
) -> dict[str, Any]:
    loop = asyncio.get_running_loop()
    lateness, durations, began_at, byte_counts = [], [], [], []
    overruns = 0
    load_before = os.getloadavg()[0]
    async with _robot(MOVE_MS, inline) as robot:
        await robot.teach_goal()
        if freeze:
            freeze_startup_heap()  # what `thermocomp serve` does once the daemon is up
        deadlines = round(duration_s / step_s)
        skipped = 0
        cpu0 = time.process_time()
        with _GcPauses() as collections:
            start = loop.time() + step_s
            slot = 0
            while slot < deadlines:
                deadline = start + slot * step_s
                await asyncio.sleep(max(deadline - loop.time(), 0.0))
                began = loop.time()
                began_at.append(time.perf_counter())
                lateness.append(began - deadline)
                result = await robot.move_absolute((0.0001 * (slot % 11), 0.0, 0.0))
                ended = loop.time()
                durations.append(ended - began)
                byte_counts.append(result.bytes_sent + result.bytes_received)
                slot += 1
                if ended > start + slot * step_s:
                    # An overrun: as the daemon's scheduler (daemon/run/scheduler.py), count it
                    # once and go on at the first deadline still in the future.
                    overruns += 1
                    first_future = math.floor((ended - start) / step_s) + 1
                    skipped += first_future - slot
                    slot = first_future
        steps = len(durations)
        heartbeats = robot.heartbeats
        flags = robot.status().extra["controller_flags"]  # of the latest reply
        silence_halted = bool(flags) and bool(int(flags) & proto.Flag.SILENCE_HALTED)
        cpu_ms = (time.process_time() - cpu0) / steps * 1000.0
    # A collection inside a step: it started between that step's start and its end.
    in_step = [
        pause
        for started, pause, _ in collections.pauses
        if _inside_a_step(began_at, durations, started)
    ]
    byte_count = statistics.median(byte_counts)
    limit_ms = byte_count * BITS_PER_CHARACTER / BAUD * 1000.0 + MOVE_MS
    return {
        "emulator": "inline" if inline else "process",
        "heap_frozen": freeze,
        "step_ms": step_s * 1000.0,
        "duration_s": duration_s,
        "steps": steps,
        "overruns": overruns,
        "skipped": skipped,  # deadlines given up after overruns
        "bytes_per_step": byte_count,
        "limit_ms": limit_ms,
        # the fixed step against the wire limit (bytes x 0.0868 ms + move time)
        "step_to_limit": step_s * 1000.0 / limit_ms,
        "step_p50_ms": _ms(durations, 50),
        "step_p99_ms": _ms(durations, 99),
        "step_max_ms": max(durations) * 1000.0,
        "late_p50_ms": _ms(lateness, 50),
        "late_p99_ms": _ms(lateness, 99),
        "late_max_ms": max(lateness) * 1000.0,
        "gc_collections": len(collections.pauses),
        "gc_full": sum(generation == 2 for _, _, generation in collections.pauses),
        "gc_max_ms": max((p for _, p, _ in collections.pauses), default=0.0) * 1000.0,
        "gc_in_step_max_ms": max(in_step, default=0.0) * 1000.0,
        "heartbeats": heartbeats,
        "silence_halted": silence_halted,
        # CPU per step of this process (the driver; the emulator too when inline): far below
        # the step, so overruns are waits for a core or a pause, not work.
        "cpu_ms_per_step": cpu_ms,
        # Overruns on a loaded machine are the machine's: the target is for an idle one.
        "load_1min": max(load_before, os.getloadavg()[0]),
        "cpus": os.cpu_count(),
    }


def _inside_a_step(began_at: list[float], durations: list[float], when: float) -> bool:
    """Whether ``when`` falls inside a step (the latest step begun at or before it)."""
    index = int(np.searchsorted(began_at, when, side="right")) - 1
    return index >= 0 and when <= began_at[index] + durations[index]


async def main(quick: bool, minutes: float | None, inline: bool, freeze: bool) -> None:
    logging.getLogger("drivers").setLevel(logging.ERROR)  # every hold logs a warning
    where = "in-process" if inline else "own process"
    period = await step_period(50 if quick else 300, inline)
    print(f"Step period, back-to-back absolute moves (paced emulator in its {where}, ")
    print(f"{BAUD} baud, move {MOVE_MS:g} ms):\n")
    print_table(list(period), [list(period.values())])
    latency = await hold_latency(10 if quick else 50)
    print("\nHold-to-halt latency (stop() during a move; halt: the arm stops; reply: 044 back):\n")
    print_table(list(latency), [list(latency.values())])
    duration_s = minutes * 60.0 if minutes is not None else (10.0 if quick else 60.0)
    steady = await fixed_step(duration_s, inline, freeze)
    print(f"\n{STEP_S * 1000:g} ms step on absolute deadlines for {duration_s:g} s:\n")
    print_table(list(steady), [list(steady.values())])
    print(
        f"\nissue 17: {steady['overruns']} overruns ({steady['skipped']} deadlines skipped) in "
        f"{steady['steps']} steps of "
        f"{STEP_S * 1000:g} ms (step p99 {steady['step_p99_ms']:.2f} ms, max "
        f"{steady['step_max_ms']:.2f} ms; load {steady['load_1min']:.2f}); "
        f"{period['bytes_per_step']:g} bytes per step, period {period['median_ms']:.2f} ms = "
        f"{period['ratio']:.3f} x the wire limit {period['limit_ms']:.2f} ms "
        f"(target <= {TARGET_RATIO}); hold-to-halt p99 {latency['halt_p99_ms']:.2f} ms"
    )
    write_results("fast_path", {"step_period": period, "hold": latency, "fixed_step": steady})


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="fewer steps, a 10 s fixed-step run")
    parser.add_argument(
        "--minutes", type=float, default=None, help="fixed-step run length (issue 17: 10)"
    )
    parser.add_argument(
        "--emulator",
        choices=["process", "inline"],
        default="process",
        help="the emulated controller in its own process (default) or in this one",
    )
    parser.add_argument(
        "--no-freeze", action="store_true", help="leave the start-up heap to the collector"
    )
    args = parser.parse_args()
    asyncio.run(main(args.quick, args.minutes, args.emulator == "inline", not args.no_freeze))
