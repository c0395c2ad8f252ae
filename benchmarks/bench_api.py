"""API benchmarks (issue 7), against a real ``thermocomp serve`` on the simulated bench, real
clock, on loopback:

1. ``GET /api/v1/state`` throughput with a run active (target: at least 1,000 requests/s),
   from a minimal keep-alive HTTP/1.1 client so that the client is not what is measured,
   against the ceiling of the same stack measured in the same run: a trivial FastAPI app
   under uvicorn returning a body of the same size (issue 16 target: ratio >= 0.7),
   alternated so that the machine's load hits both alike.
2. Step lateness (p50/p99/max) at a 100 ms step with no WebSocket client and with 50 clients
   subscribed to steps (target: p99 at most 1 ms worse with the clients), and with 8
   connections polling /state back to back (issue 16 target: p99 at most 2 ms worse).

Usage: ``.venv/bin/python benchmarks/bench_api.py [--quick]``.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from websockets.asyncio.client import connect

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.common import print_table, write_results

REPO = Path(__file__).resolve().parent.parent
#: How long a started server may take to answer its health check (s), on a loaded machine.
SERVER_START_S = 60.0
TOKEN = "benchmark-control-token"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def start_server(data_dir: Path, port: int) -> subprocess.Popen[bytes]:
    env = {
        **os.environ,
        "THERMOCOMP_API__CONTROL_TOKEN": TOKEN,
        "THERMOCOMP_STORAGE__DATA_DIR": str(data_dir),
        "THERMOCOMP_BENCH__CLOCK": "real",
    }
    command = [
        sys.executable,
        "-m",
        "api",
        "--log-level",
        "WARNING",
        "serve",
        "--config",
        "config/sim.toml",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
    ]
    process = subprocess.Popen(command, cwd=REPO, env=env)
    return wait_until_healthy(process, port, SERVER_START_S, "the server")


def wait_until_healthy(
    process: subprocess.Popen[bytes], port: int, timeout_s: float, what: str
) -> subprocess.Popen[bytes]:
    """``process`` once the server on ``port`` answers ``GET /health``; killed and
    SystemExit when it does not within ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=1).status_code == 200:
                return process
        except httpx.TransportError:
            time.sleep(0.1)
    process.kill()
    raise SystemExit(f"{what} did not start")


#: The reference: the same stack (FastAPI on uvicorn, its default HTTP and loop
#: implementations) with nothing but a route returning a fixed body of /state's size.
TRIVIAL_APP = """
import sys, uvicorn
from fastapi import FastAPI, Response
body = b'{"pad":"' + b"x" * (int(sys.argv[2]) - 10) + b'"}'
app = FastAPI()
@app.get("/api/v1/state")
async def state() -> Response:
    return Response(body, media_type="application/json")
uvicorn.run(app, host="127.0.0.1", port=int(sys.argv[1]), log_level="warning",
            access_log=False)
"""


def start_trivial_server(port: int, body_bytes: int) -> subprocess.Popen[bytes]:
    command = [sys.executable, "-c", TRIVIAL_APP, str(port), str(body_bytes)]
    process = subprocess.Popen(command, cwd=REPO)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            httpx.get(f"http://127.0.0.1:{port}/api/v1/state", timeout=1)
            return process
        except httpx.TransportError:
            time.sleep(0.1)
    process.kill()
    raise SystemExit("the trivial server did not start")


async def keep_alive_client(port: int, path: str, until: float) -> int:
    """One connection sending GETs back to back; returns the number of 200 answers."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    request = f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode()
    done = 0
    try:
        while time.perf_counter() < until:
            writer.write(request)
            head = await reader.readuntil(b"\r\n\r\n")
            length = 0
            for line in head.split(b"\r\n"):
                if line.lower().startswith(b"content-length:"):
                    length = int(line.split(b":", 1)[1])
            await reader.readexactly(length)
            if head.startswith(b"HTTP/1.1 200"):
                done += 1
    finally:
        writer.close()
        await writer.wait_closed()
    return done


async def state_throughput(port: int, seconds: float, connections: int) -> dict[str, Any]:
    until = time.perf_counter() + seconds
    started = time.perf_counter()
    counts = await asyncio.gather(
        *(keep_alive_client(port, "/api/v1/state", until) for _ in range(connections))
    )
    elapsed = time.perf_counter() - started
    return {
        "requests": sum(counts),
        "seconds": elapsed,
        "per_s": sum(counts) / elapsed,
        "connections": connections,
    }


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


async def run_and_measure(
    client: httpx.AsyncClient,
    port: int,
    server_pid: int,
    seconds: float,
    ws_clients: int,
    *,
    state_load: bool = False,
) -> dict[str, Any]:
    """A run at a 100 ms step while ``ws_clients`` clients read every step; its lateness and
    the CPU time the server and the clients spent per step."""
    received = [0] * ws_clients
    pollers: list[asyncio.Task[dict[str, Any]]] = []

    async def reader(index: int) -> None:
        async with connect(f"ws://127.0.0.1:{port}/api/v1/ws?topics=steps") as ws:
            async for _ in ws:
                received[index] += 1

    readers = [asyncio.create_task(reader(i)) for i in range(ws_clients)]
    await asyncio.sleep(0.5 if ws_clients else 0)  # let them connect
    server_cpu, own_cpu = cpu_seconds(server_pid), cpu_seconds(os.getpid())
    response = await client.post(
        "/api/v1/runs",
        json={"duration_s": seconds, "step_s": 0.1, "compensation": "absolute"},
        headers=HEADERS,
    )
    response.raise_for_status()
    run_id = response.json()["id"]
    if state_load:  # /state polled back to back for the whole run
        pollers.append(asyncio.create_task(state_throughput(port, seconds, connections=8)))
    ended = ("finished", "aborted", "fault")
    while True:
        if (await client.get(f"/api/v1/runs/{run_id}")).json()["state"] in ended:
            break
        await asyncio.sleep(0.5)
    await asyncio.sleep(0.5)  # let the readers get the last steps
    server_cpu = cpu_seconds(server_pid) - server_cpu
    own_cpu = cpu_seconds(os.getpid()) - own_cpu
    for task in readers:
        task.cancel()
    await asyncio.gather(*readers, return_exceptions=True)
    polled = await asyncio.gather(*pollers)
    steps = (await client.get(f"/api/v1/runs/{run_id}/steps")).json()["steps"]
    run = (await client.get(f"/api/v1/runs/{run_id}")).json()
    # step 0 is excluded: it also teaches the operational goal (a few serial round trips)
    lateness_ms = np.array([s["lateness_s"] for s in steps[1:]]) * 1e3
    return {
        "ws_clients": ws_clients,
        "state_load": state_load,
        "state_per_s": polled[0]["per_s"] if polled else None,
        "steps": len(steps),
        "lateness_ms": lateness_ms.tolist(),
        "server_cpu_ms_per_step": 1e3 * server_cpu / len(steps),
        "client_cpu_ms_per_step": 1e3 * own_cpu / len(steps),
        "lateness_p50_ms": float(np.percentile(lateness_ms, 50)),
        "lateness_p99_ms": float(np.percentile(lateness_ms, 99)),
        "lateness_max_ms": float(lateness_ms.max()),
        "overruns": run["summary"].get("overruns") if run["summary"] else None,
        "messages_per_client_min": min(received) if received else 0,
    }


async def main_async(quick: bool) -> dict[str, Any]:
    throughput_s = 5.0 if quick else 10.0
    run_s = 10.0 if quick else 30.0
    port = free_port()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as folder:
        server = start_server(Path(folder) / "data", port)
        try:
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", timeout=60) as c:
                # 1. GET /state while a run is active
                started = await c.post(
                    "/api/v1/runs", json={"duration_s": 3600, "step_s": 0.1}, headers=HEADERS
                )
                started.raise_for_status()
                run_id = started.json()["id"]
                await asyncio.sleep(1.0)
                body_bytes = len((await c.get("/api/v1/state")).content)
                trivial_port = free_port()
                trivial = start_trivial_server(trivial_port, body_bytes)
                try:
                    measured: dict[str, list[dict[str, Any]]] = {"state": [], "trivial": []}
                    for _ in range(2):
                        measured["state"].append(
                            await state_throughput(port, throughput_s / 2, connections=8)
                        )
                        measured["trivial"].append(
                            await state_throughput(trivial_port, throughput_s / 2, connections=8)
                        )
                finally:
                    trivial.terminate()
                    trivial.wait(timeout=30)
                throughput = _pooled(measured["state"])
                ceiling = _pooled(measured["trivial"])
                throughput["body_bytes"] = body_bytes
                await c.post(f"/api/v1/runs/{run_id}/stop", headers=HEADERS)
                # 2. lateness without and with 50 WebSocket clients
                # alternated, so slow changes of the machine's load hit both alike
                runs = [
                    await run_and_measure(c, port, server.pid, run_s, ws_clients=clients)
                    for _ in range(2)
                    for clients in (0, 50)
                ]
                # 3. lateness with and without /state polled back to back, alternated
                polled = [
                    await run_and_measure(c, port, server.pid, run_s, ws_clients=0, state_load=load)
                    for _ in range(2)
                    for load in (False, True)
                ]
        finally:
            server.terminate()
            server.wait(timeout=30)
    return {
        "state_throughput": throughput,
        "same_stack_ceiling": ceiling,
        "state_ratio": throughput["per_s"] / ceiling["per_s"],
        "lateness": runs,
        "lateness_state_load": polled,
        "run_seconds": run_s,
        "load_average_1min": [load_before[0], os.getloadavg()[0]],
    }


def _pooled(parts: list[dict[str, Any]]) -> dict[str, Any]:
    requests = sum(part["requests"] for part in parts)
    seconds = sum(part["seconds"] for part in parts)
    return {
        "requests": requests,
        "seconds": seconds,
        "per_s": requests / seconds,
        "connections": parts[0]["connections"],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs (about 40 s)")
    args = parser.parse_args()
    results = asyncio.run(main_async(args.quick))
    throughput = results["state_throughput"]
    ceiling = results["same_stack_ceiling"]
    print(
        "GET /api/v1/state with a run active (100 ms step), keep-alive, loopback, against a "
        f"trivial FastAPI/uvicorn app returning {throughput['body_bytes']} bytes"
    )
    print_table(
        ["server", "connections", "requests", "seconds", "requests/s", "target"],
        [
            [
                "thermocomp /state",
                throughput["connections"],
                throughput["requests"],
                throughput["seconds"],
                throughput["per_s"],
                ">= 1000",
            ],
            [
                "trivial app",
                ceiling["connections"],
                ceiling["requests"],
                ceiling["seconds"],
                ceiling["per_s"],
                "",
            ],
        ],
    )
    print(f"ratio /state / same-stack ceiling: {results['state_ratio']:.2f} (target >= 0.7)")
    print(
        f"\nstep lateness at a 100 ms step, {results['run_seconds']:.0f} s runs (step 0 excluded)"
    )
    headers = [
        "ws clients",
        "steps",
        "p50 ms",
        "p99 ms",
        "max ms",
        "overruns",
        "msgs/client (min)",
        "server CPU ms/step",
        "client CPU ms/step",
    ]
    rows = [
        [
            r["ws_clients"],
            r["steps"],
            r["lateness_p50_ms"],
            r["lateness_p99_ms"],
            r["lateness_max_ms"],
            r["overruns"],
            r["messages_per_client_min"],
            r["server_cpu_ms_per_step"],
            r["client_cpu_ms_per_step"],
        ]
        for r in results["lateness"]
    ]
    pooled = {}
    for clients in (0, 50):
        lateness = np.concatenate(
            [r["lateness_ms"] for r in results["lateness"] if r["ws_clients"] == clients]
        )
        pooled[clients] = float(np.percentile(lateness, 99))
        rows.append(
            [
                f"{clients} (pooled)",
                lateness.size,
                float(np.percentile(lateness, 50)),
                pooled[clients],
                float(lateness.max()),
                "",
                "",
                "",
                "",
            ]
        )
    print_table(headers, rows)
    worse = pooled[50] - pooled[0]
    results["p99_pooled_ms"] = pooled
    results["p99_worse_ms"] = worse
    print(f"\np99 (pooled) with 50 clients minus without: {worse:+.3f} ms (target <= 1 ms)")
    loaded = {}
    for load in (False, True):
        lateness = np.concatenate(
            [r["lateness_ms"] for r in results["lateness_state_load"] if r["state_load"] is load]
        )
        loaded[load] = float(np.percentile(lateness, 99))
    rate = [r["state_per_s"] for r in results["lateness_state_load"] if r["state_load"]]
    results["p99_state_load_worse_ms"] = loaded[True] - loaded[False]
    print(
        f"p99 (pooled) with /state polled back to back ({np.mean(rate):.0f} requests/s) minus "
        f"without: {loaded[True] - loaded[False]:+.3f} ms (target <= 2 ms; "
        f"{loaded[False]:.3f} -> {loaded[True]:.3f} ms)"
    )
    before, after = results["load_average_1min"]
    print(
        f"machine load average (1 min) before/after: {before:.2f} / {after:.2f} "
        f"on {os.cpu_count()} CPUs (other work on the machine skews the lateness)"
    )
    write_results("bench_api", results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
