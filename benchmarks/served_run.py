"""One run at a 20 ms step on a real ``thermocomp serve``, for the benchmarks that measure the
whole daemon (benchmarks/bench_loop_isolation.py, benchmarks/bench_gc_pauses.py): the server
(``python -m api serve --config config/sim.toml``, real clock, ``robot.driver =
"c500c-server"``: the simulated bench's paced emulator of the fast path's program on a pty) in a
temporary data directory, a dashboard-like client reading it (one WebSocket on the steps,
``GET /state`` every POLL_S), and the machine loaded by busy processes when asked.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
from websockets.asyncio.client import connect

from benchmarks.bench_api import HEADERS, SERVER_START_S, TOKEN, free_port, wait_until_healthy

ROOT = Path(__file__).resolve().parent.parent
STEP_S = 0.020
ENDED = ("finished", "aborted", "fault", "interrupted", "stopped")
POLL_S = 0.5
BUSY = "while 1: pass"


@contextlib.contextmanager
def busy_processes(count: int) -> Iterator[None]:
    """``count`` busy loops at normal priority, for the measurement's duration."""
    processes = [
        subprocess.Popen(["nice", "-n", "0", sys.executable, "-c", BUSY]) for _ in range(count)
    ]
    try:
        time.sleep(2.0 if count else 0.0)  # let the scheduler see them
        yield
    finally:
        for process in processes:
            process.terminate()
        for process in processes:
            process.wait(timeout=30)


def start_server(tree: Path, data_dir: Path, port: int, env_extra: dict[str, str]) -> Any:
    """``thermocomp serve`` from ``tree`` (this checkout, or a baseline's ``git archive``),
    answering its health check; SystemExit when it does not within SERVER_START_S."""
    env = {
        **os.environ,
        "PYTHONPATH": str(tree),
        "THERMOCOMP_API__CONTROL_TOKEN": TOKEN,
        "THERMOCOMP_STORAGE__DATA_DIR": str(data_dir),
        "THERMOCOMP_BENCH__CLOCK": "real",
        "THERMOCOMP_ROBOT__DRIVER": "c500c-server",
        **env_extra,
    }
    command = [sys.executable, "-m", "api", "--log-level", "WARNING", "serve"]
    command += ["--config", "config/sim.toml", "--host", "127.0.0.1", "--port", str(port)]
    process = subprocess.Popen(command, cwd=tree, env=env)
    return wait_until_healthy(process, port, SERVER_START_S, f"the server in {tree}")


async def _reader(port: int, counts: list[int]) -> None:
    async with connect(f"ws://127.0.0.1:{port}/api/v1/ws?topics=steps") as ws:
        async for _ in ws:
            counts[0] += 1


@dataclass
class ServedRun:
    """The server (its process), a client of its API, the run started, and the WebSocket
    messages read so far (``ws_messages[0]``)."""

    server: Any
    client: httpx.AsyncClient
    run_id: int
    ws_messages: list[int]

    async def wait_ended(
        self, each_poll: Callable[[int], Awaitable[None]] | None = None
    ) -> dict[str, Any]:
        """Poll ``GET /state`` and the run every POLL_S (``each_poll(n)`` after the n-th state)
        until the run has ended; the run as the API gives it."""
        polls = 0
        while True:
            await self.client.get("/api/v1/state")
            polls += 1
            if each_poll is not None:
                await each_poll(polls)
            run: dict[str, Any] = (await self.client.get(f"/api/v1/runs/{self.run_id}")).json()
            if run["state"] in ENDED:
                return run
            await asyncio.sleep(POLL_S)


@contextlib.asynccontextmanager
async def served_run(
    tree: Path, seconds: float, env_extra: dict[str, str]
) -> AsyncIterator[ServedRun]:
    """A server from ``tree`` with ``env_extra``, its WebSocket reader, and a run of
    ``seconds`` at STEP_S started; the reader and the server stopped on exit."""
    port = free_port()
    with tempfile.TemporaryDirectory() as folder:
        server = start_server(tree, Path(folder) / "data", port, env_extra)
        try:
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", timeout=60) as c:
                counts = [0]
                reader = asyncio.create_task(_reader(port, counts))
                try:
                    await asyncio.sleep(0.5)
                    response = await c.post(
                        "/api/v1/runs",
                        json={"duration_s": seconds, "step_s": STEP_S, "compensation": "absolute"},
                        headers=HEADERS,
                    )
                    response.raise_for_status()
                    yield ServedRun(server, c, response.json()["id"], counts)
                finally:
                    reader.cancel()
                    await asyncio.gather(reader, return_exceptions=True)
        finally:
            server.terminate()
            server.wait(timeout=60)


def run_figures(run: dict[str, Any]) -> dict[str, Any]:
    """What both benchmarks report of an ended run: its state, steps, overruns and the p99 of
    the steps' lateness (ms)."""
    summary = run.get("summary") or {}
    lateness = (summary.get("timing") or {}).get("lateness_s") or {}
    return {
        "state": run["state"],
        "steps": summary.get("steps", run.get("steps_recorded")) or 0,
        "overruns": summary.get("overruns") or 0,
        "lateness_p99_ms": 1e3 * lateness["p99"] if "p99" in lateness else None,
    }
