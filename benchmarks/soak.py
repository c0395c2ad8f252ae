"""Soak (issue 10, ``make soak``; not in CI): one long run at a 20 ms step on the simulated
bench, real clock, against a real ``thermocomp serve`` on loopback, with a few WebSocket
clients reading every step and a client polling ``GET /api/v1/state``.

Reports the run's step lateness (p50/p99/max) and overruns, and the server's memory (RSS) and
open file descriptors at the start, every ``--sample`` seconds, and at the end: a leak shows as
a steady climb, not as one number.

Usage: ``.venv/bin/python benchmarks/soak.py [--duration S]`` (default: ``SOAK_S`` from the
environment, else one hour); ``make soak SOAK_S=300``.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
from websockets.asyncio.client import connect

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.bench_api import HEADERS, free_port, start_server
from benchmarks.common import print_table, proc_status_mib, write_results

DEFAULT_DURATION_S = 3600.0
STEP_S = 0.02
ENDED = ("finished", "aborted", "fault", "interrupted")
#: How long after the run's end the server's memory is sampled once more (s).
AFTER_END_S = 60.0


def rss_mib(pid: int) -> float:
    """Resident memory of a process, MiB."""
    return proc_status_mib("VmRSS", pid)


def open_files(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


async def websocket_reader(port: int, counts: list[int], index: int) -> None:
    """Reads every step message and counts them."""
    async with connect(f"ws://127.0.0.1:{port}/api/v1/ws?topics=steps") as ws:
        async for _ in ws:
            counts[index] += 1


async def state_poller(client: httpx.AsyncClient, period_s: float, errors: list[str]) -> int:
    polls = 0
    while True:
        response = await client.get("/api/v1/state")
        if response.status_code != 200:
            errors.append(f"GET /state: {response.status_code}")
        polls += 1
        await asyncio.sleep(period_s)


async def soak(
    duration_s: float, ws_clients: int, poll_s: float, sample_s: float
) -> dict[str, Any]:
    port = free_port()
    with tempfile.TemporaryDirectory() as folder:
        server = start_server(Path(folder) / "data", port)
        try:
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", timeout=60) as c:
                counts = [0] * ws_clients
                readers = [
                    asyncio.create_task(websocket_reader(port, counts, i))
                    for i in range(ws_clients)
                ]
                errors: list[str] = []
                poller = asyncio.create_task(state_poller(c, poll_s, errors))
                await asyncio.sleep(0.5)  # let the clients connect
                response = await c.post(
                    "/api/v1/runs",
                    json={"duration_s": duration_s, "step_s": STEP_S, "compensation": "absolute"},
                    headers=HEADERS,
                )
                response.raise_for_status()
                run_id = response.json()["id"]
                started = time.monotonic()
                samples = [(0.0, rss_mib(server.pid), open_files(server.pid))]
                next_sample = started + sample_s
                while True:
                    run = (await c.get(f"/api/v1/runs/{run_id}")).json()
                    now = time.monotonic()
                    if now >= next_sample:
                        samples.append((now - started, rss_mib(server.pid), open_files(server.pid)))
                        print(
                            f"  t={now - started:7.0f} s  steps {run['steps_recorded']:>7}  "
                            f"RSS {samples[-1][1]:6.1f} MiB  fds {samples[-1][2]}",
                            flush=True,
                        )
                        next_sample += sample_s
                    if run["state"] in ENDED:
                        break
                    await asyncio.sleep(1.0)
                samples.append(
                    (time.monotonic() - started, rss_mib(server.pid), open_files(server.pid))
                )
                # the end of a run reads it back for its summary and report: see whether that
                # memory is given back or kept (glibc keeps freed heap for reuse)
                await asyncio.sleep(AFTER_END_S)
                after_end = (
                    time.monotonic() - started,
                    rss_mib(server.pid),
                    open_files(server.pid),
                )
                poller.cancel()
                for task in readers:
                    task.cancel()
                await asyncio.gather(poller, *readers, return_exceptions=True)
        finally:
            server.terminate()
            server.wait(timeout=60)
    summary = run.get("summary") or {}
    timing = summary.get("timing") or {}
    lateness = timing.get("lateness_s") or {}
    return {
        "duration_s": duration_s,
        "step_s": STEP_S,
        "ws_clients": ws_clients,
        "poll_s": poll_s,
        "state": run["state"],
        "reason": run.get("reason"),
        "steps": summary.get("steps", run.get("steps_recorded")),
        "overruns": summary.get("overruns"),
        "skipped_deadlines": summary.get("skipped_deadlines"),
        "lateness_p50_ms": 1e3 * lateness["p50"] if "p50" in lateness else None,
        "lateness_p99_ms": 1e3 * lateness["p99"] if "p99" in lateness else None,
        "lateness_max_ms": 1e3 * lateness["max"] if "max" in lateness else None,
        "messages_per_client_min": min(counts) if counts else 0,
        "state_errors": errors[:10],
        "samples": [{"t_s": t, "rss_mib": r, "open_files": f} for t, r, f in samples],
        "after_end": {"t_s": after_end[0], "rss_mib": after_end[1], "open_files": after_end[2]},
        "stages_ms": {
            name: {k: 1e3 * v for k, v in values.items()}
            for name, values in (timing.get("stages_s") or {}).items()
        },
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--duration",
        type=float,
        default=float(os.environ.get("SOAK_S", DEFAULT_DURATION_S)),
        help="run length in seconds (default: $SOAK_S, else 3600)",
    )
    parser.add_argument("--ws-clients", type=int, default=4, help="WebSocket clients (4)")
    parser.add_argument("--poll", type=float, default=0.1, help="GET /state period, s (0.1)")
    parser.add_argument("--sample", type=float, default=60.0, help="RSS/fd sample period, s")
    args = parser.parse_args()
    print(
        f"soak: {args.duration:.0f} s at a {STEP_S * 1e3:.0f} ms step, "
        f"{args.ws_clients} WebSocket clients, /state every {args.poll} s"
    )
    results = asyncio.run(soak(args.duration, args.ws_clients, args.poll, args.sample))
    first, last = results["samples"][0], results["samples"][-1]
    print_table(
        ["quantity", "value"],
        [
            ["final state", results["state"]],
            ["steps", results["steps"]],
            ["overruns", results["overruns"]],
            ["lateness p50 (ms)", results["lateness_p50_ms"]],
            ["lateness p99 (ms)", results["lateness_p99_ms"]],
            ["lateness max (ms)", results["lateness_max_ms"]],
            ["steps received per WS client (min)", results["messages_per_client_min"]],
            ["/state errors", len(results["state_errors"])],
            ["RSS start / end (MiB)", f"{first['rss_mib']:.1f} / {last['rss_mib']:.1f}"],
            ["open files start / end", f"{first['open_files']} / {last['open_files']}"],
            [
                f"RSS / open files {AFTER_END_S:.0f} s after the end",
                f"{results['after_end']['rss_mib']:.1f} / {results['after_end']['open_files']}",
            ],
        ],
    )
    print_table(
        ["stage (recent steps)", "p50 (ms)", "p99 (ms)", "max (ms)"],
        [
            [name, values["p50"], values["p99"], values["max"]]
            for name, values in results["stages_ms"].items()
        ],
    )
    write_results("soak", results)


if __name__ == "__main__":
    main()
