"""Control-core benchmarks (issue 15), on the simulated bench (C500C emulator on a pty, real
clock, loopback):

1. Hold latency: from sending ``POST /api/v1/robot/stop`` to the instant the robot driver
   refuses motion ("no motion command can be written": its ``stop()`` was entered, and
   returned), and to the answer; p50/p99 over 200 holds during a 20 ms loop (in-process server,
   so one clock measures both sides; the client runs in its own thread).
2. Step lateness at a 100 ms step without and with heavy readers: 6 clients exporting a
   50,000-step run as JSON, page after page (the server caps a page), back to back, and a
   ``/state`` poller at 100 Hz (a separate
   server process); target: the loaded p99 within 2 ms of the unloaded one, both measured in
   the same benchmark run, alternated.

Usage: ``.venv/bin/python benchmarks/bench_control_core.py [--quick]``.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import os
import sqlite3
import sys
import tempfile
import time
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import uvicorn

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from api.app import create_app
from benchmarks.bench_api import HEADERS, TOKEN, free_port, start_server
from benchmarks.common import print_table, write_results
from config import Settings
from daemon.service import Daemon
from daemon.storage.recorder import DATABASE_NAME, STEP_COLUMNS, Recorder, StepRecord

EXPORT_STEPS = 50_000
EXPORT_CLIENTS = 6
POLL_HZ = 100.0


# --- 1. hold latency -------------------------------------------------------------------------


async def hold_latency(holds: int) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as folder:
        settings = Settings.model_validate(
            {
                "bench": {"clock": "real"},
                "scheduler": {"step_s": 0.02, "duration_s": 3600.0},
                "storage": {"data_dir": folder, "report_at_end": False},
                "api": {
                    "control_token": TOKEN,
                    "control_burst": 10_000,
                    "control_rate_per_s": 1e4,
                },
            }
        )
        app = create_app(settings, service_factory=Daemon)
        server = uvicorn.Server(
            uvicorn.Config(app, host="127.0.0.1", port=0, log_config=None, lifespan="on")
        )
        serving = asyncio.create_task(server.serve())
        while not server.started:  # noqa: ASYNC110 -- uvicorn offers no event for it
            await asyncio.sleep(0.01)
        port = server.servers[0].sockets[0].getsockname()[1]
        daemon: Daemon = app.state.context.service
        robot = daemon.devices.robot
        original_stop = robot.stop
        entered: list[float] = []
        returned: list[float] = []

        async def timed_stop() -> None:
            entered.append(time.perf_counter())
            await original_stop()
            returned.append(time.perf_counter())

        robot.stop = timed_stop  # type: ignore[method-assign]
        try:
            results = await asyncio.to_thread(_hold_client, port, daemon, holds, entered, returned)
        finally:
            robot.stop = original_stop  # type: ignore[method-assign]
            server.should_exit = True
            await serving
    return results


def _hold_client(
    port: int, daemon: Daemon, holds: int, entered: list[float], returned: list[float]
) -> dict[str, Any]:
    base = f"http://127.0.0.1:{port}/api/v1"
    to_flag, to_return, to_answer = [], [], []
    with httpx.Client(base_url=base, headers=HEADERS, timeout=30) as client:
        run_id = client.post("/runs", json={}).raise_for_status().json()["id"]
        _wait_steps(daemon, 3)
        for _ in range(holds):
            step = daemon.run.step if daemon.run else 0
            _wait_steps(daemon, step + 2)  # the loop is running: moves every 20 ms
            before = len(entered)
            sent = time.perf_counter()
            answer = client.post("/robot/stop")
            answered = time.perf_counter()
            answer.raise_for_status()
            # the daemon's first stop() call of this hold is the one the API waited for
            to_flag.append(entered[before] - sent)
            to_return.append(returned[before] - sent)
            to_answer.append(answered - sent)
            client.post(f"/runs/{run_id}/resume").raise_for_status()
        client.post(f"/runs/{run_id}/stop").raise_for_status()
    return {
        "holds": holds,
        "step_s": 0.02,
        "to_refusing_ms": _ms_percentiles(to_flag),
        "to_stop_returned_ms": _ms_percentiles(to_return),
        "to_answer_ms": _ms_percentiles(to_answer),
    }


def _wait_steps(daemon: Daemon, step: int, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while daemon.run is None or daemon.run.step < step:
        if time.monotonic() > deadline:
            raise SystemExit(f"no step {step} within {timeout_s} s")
        time.sleep(0.002)


def _ms_percentiles(values_s: list[float]) -> dict[str, float]:
    data = np.asarray(values_s) * 1e3
    return {
        "p50": float(np.percentile(data, 50)),
        "p99": float(np.percentile(data, 99)),
        "max": float(data.max()),
    }


# --- 2. lateness under heavy reads ---------------------------------------------------------------


def write_long_run(data_dir: Path, steps: int) -> int:
    """A finished run of ``steps`` steps, written in one transaction (a stand-in for an hour at
    a 72 ms step), for the exporters to read."""
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run({"duration_s": steps * 0.1, "step_s": 0.1}, {}, None, "bench")
    template = StepRecord(run_id=run_id, step=0, scheduled_s=0.0, actual_s=0.0, lateness_s=0.0)
    rows = [
        dataclasses.astuple(
            dataclasses.replace(
                template,
                step=k,
                scheduled_s=0.1 * k,
                actual_s=0.1 * k,
                predicted_x_um=float(k % 997),
                residual_um=0.5,
                model_temperatures_json='{"1": 22.5, "2": 23.0}',
            )
        )
        for k in range(steps)
    ]
    with sqlite3.connect(data_dir / DATABASE_NAME) as db:
        placeholders = ",".join("?" * len(STEP_COLUMNS))
        db.executemany(
            f"INSERT INTO steps ({','.join(STEP_COLUMNS)}) VALUES ({placeholders})", rows
        )
        db.execute(
            "UPDATE runs SET state = 'finished', ended_at = ? WHERE id = ?", (time.time(), run_id)
        )
    return run_id


async def lateness_run(
    client: httpx.AsyncClient, seconds: float, load: Callable[[], Coroutine[Any, Any, None]] | None
) -> dict[str, Any]:
    loader = asyncio.create_task(load()) if load is not None else None
    try:
        response = await client.post(
            "/api/v1/runs", json={"duration_s": seconds, "step_s": 0.1}, headers=HEADERS
        )
        response.raise_for_status()
        run_id = response.json()["id"]
        active = ("starting", "running")
        while (await client.get(f"/api/v1/runs/{run_id}")).json()["state"] in active:  # noqa: ASYNC110 -- polling the server is the point
            await asyncio.sleep(0.5)
    finally:
        if loader is not None:
            loader.cancel()
            await asyncio.gather(loader, return_exceptions=True)
    steps = (await client.get(f"/api/v1/runs/{run_id}/steps?limit=100000")).json()["steps"]
    run = (await client.get(f"/api/v1/runs/{run_id}")).json()
    lateness_ms = np.array([s["lateness_s"] for s in steps[1:]]) * 1e3  # step 0 teaches
    flags = sorted({f for s in steps for f in (s["flags"] or "").split(",") if f})
    return {
        "loaded": load is not None,
        "steps": len(steps),
        "lateness_ms": lateness_ms.tolist(),
        "p50_ms": float(np.percentile(lateness_ms, 50)),
        "p99_ms": float(np.percentile(lateness_ms, 99)),
        "max_ms": float(lateness_ms.max()),
        "overruns": (run["summary"] or {}).get("overruns"),
        "flags": flags,
    }


def next_from(page: bytes) -> int | None:
    """A page's ``next_from`` from its last bytes (the server writes it last): the readers
    here stand in for clients on other machines, so they do not parse 4 MB of JSON per page
    on the two cores the daemon runs on."""
    tail = page[-40:].rsplit(b'"next_from":', 1)[1].rstrip(b"}")
    return None if tail == b"null" else int(tail)


def heavy_readers(
    port: int, export_run: int, counts: dict[str, int]
) -> Callable[[], Coroutine[Any, Any, None]]:
    async def exporter(client: httpx.AsyncClient) -> None:
        """The whole run, page after page (``next_from``), again and again."""
        while True:
            start: int | None = 0
            while start is not None:
                answer = await client.get(
                    f"/api/v1/runs/{export_run}/steps?format=json&from={start}&limit={EXPORT_STEPS}"
                )
                counts["export_bytes"] += len(answer.content)
                start = next_from(answer.content)
            counts["exports"] += 1

    async def poller(client: httpx.AsyncClient) -> None:
        period = 1.0 / POLL_HZ
        next_at = time.perf_counter()
        while True:
            await client.get("/api/v1/state")
            counts["polls"] += 1
            next_at += period
            await asyncio.sleep(max(next_at - time.perf_counter(), 0.0))

    async def load() -> None:
        clients = [
            httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", timeout=120)
            for _ in range(EXPORT_CLIENTS + 1)
        ]
        try:
            await asyncio.gather(
                *(exporter(c) for c in clients[:EXPORT_CLIENTS]), poller(clients[-1])
            )
        finally:
            for client in clients:
                await client.aclose()

    return load


async def lateness_under_reads(seconds: float, repeats: int) -> dict[str, Any]:
    port = free_port()
    counts = {"exports": 0, "export_bytes": 0, "polls": 0}
    with tempfile.TemporaryDirectory() as folder:
        data_dir = Path(folder) / "data"
        export_run = write_long_run(data_dir, EXPORT_STEPS)
        server = start_server(data_dir, port)
        try:
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", timeout=120) as c:
                load = heavy_readers(port, export_run, counts)
                runs = [
                    await lateness_run(c, seconds, loaded)
                    for _ in range(repeats)
                    for loaded in (None, load)
                ]
        finally:
            server.terminate()
            server.wait(timeout=30)
    pooled = {}
    for loaded in (False, True):
        data = np.concatenate([r["lateness_ms"] for r in runs if r["loaded"] is loaded])
        pooled["loaded" if loaded else "unloaded"] = float(np.percentile(data, 99))
    return {
        "runs": runs,
        "seconds": seconds,
        "p99_pooled_ms": pooled,
        "p99_worse_ms": pooled["loaded"] - pooled["unloaded"],
        "load": counts,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer holds, shorter runs")
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    holds = asyncio.run(hold_latency(50 if args.quick else 200))
    reads = asyncio.run(lateness_under_reads(10.0 if args.quick else 30.0, 1 if args.quick else 2))
    print(f"hold latency, {holds['holds']} holds during a {holds['step_s'] * 1e3:.0f} ms loop")
    print_table(
        ["from POST /robot/stop to", "p50 ms", "p99 ms", "max ms"],
        [
            [label, v["p50"], v["p99"], v["max"]]
            for label, v in (
                ("driver refusing motion", holds["to_refusing_ms"]),
                ("driver stop() returned", holds["to_stop_returned_ms"]),
                ("answer received", holds["to_answer_ms"]),
            )
        ],
    )
    print(
        f"\nstep lateness at a 100 ms step ({reads['seconds']:.0f} s runs, step 0 excluded), "
        f"without and with {EXPORT_CLIENTS} clients exporting a {EXPORT_STEPS}-step run as "
        f"JSON pages and a {POLL_HZ:.0f} Hz /state poller"
    )
    print_table(
        ["load", "steps", "p50 ms", "p99 ms", "max ms", "overruns", "flags"],
        [
            [
                "heavy reads" if r["loaded"] else "none",
                r["steps"],
                r["p50_ms"],
                r["p99_ms"],
                r["max_ms"],
                r["overruns"],
                ",".join(r["flags"]) or "-",
            ]
            for r in reads["runs"]
        ],
    )
    pooled = reads["p99_pooled_ms"]
    print(
        f"\np99 pooled: {pooled['unloaded']:.3f} ms without, {pooled['loaded']:.3f} ms with "
        f"the readers: {reads['p99_worse_ms']:+.3f} ms (target <= 2 ms); readers made "
        f"{reads['load']['exports']} whole-run exports "
        f"({reads['load']['export_bytes'] / 1e6:.0f} MB) "
        f"and {reads['load']['polls']} polls"
    )
    print(f"machine load average (1 min) before: {load_before:.2f} on {os.cpu_count()} CPUs")
    write_results("bench_control_core", {"hold": holds, "reads": reads})
    return 0


if __name__ == "__main__":
    sys.exit(main())
