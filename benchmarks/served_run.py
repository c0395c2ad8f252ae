"""One run at a 20 ms step on a real ``thermocomp serve``, for the benchmarks that measure the
whole daemon (benchmarks/bench_loop_isolation.py, benchmarks/bench_gc_pauses.py): the server
(``python -m api serve --config config/sim.toml``, real clock, ``robot.driver =
"c500c-server"``: the simulated bench's paced emulator of the fast path's program on a pty) in a
temporary data directory, a dashboard-like client reading it (WebSockets on the steps,
``GET /state`` every POLL_S), and the machine loaded by busy processes when asked.

``ServedLoad`` adds what a busy lab daemon serves besides the run (issue 30's "100 ms with 6
exporters and 50 WebSocket clients"): more WebSocket clients on the steps, and exporters that
each fetch a finished 24-h run at 1 s (86,401 steps, filled into the data directory before the
server starts, as benchmarks/bench_exports.py does) over and over for the whole run, half as
the streamed CSV, half as every JSON page.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
from websockets.asyncio.client import connect

from benchmarks.bench_api import HEADERS, SERVER_START_S, TOKEN, free_port, wait_until_healthy
from benchmarks.bench_exports import fill_run, next_page

ROOT = Path(__file__).resolve().parent.parent
STEP_S = 0.020
ENDED = ("finished", "aborted", "fault", "interrupted", "stopped")
POLL_S = 0.5
BUSY = "while 1: pass"
#: The finished run the exporters fetch: 24 h at 1 s (benchmarks/bench_exports.py's).
EXPORT_STEPS = 86_401
#: A JSON page of the exporters' walk (the API's own page size limit is larger).
EXPORT_PAGE_STEPS = 5000
#: An export's HTTP time-out (s): a 76 MB CSV on a loaded machine, with five others.
EXPORT_TIMEOUT_S = 600.0


@dataclass(frozen=True)
class ServedLoad:
    """What the server serves while the run steps: the run's step, WebSocket clients on its
    steps, and exporters of a finished 24-h run (none: the dashboard-like client alone)."""

    step_s: float = STEP_S
    ws_clients: int = 1
    exporters: int = 0


@dataclass
class ExportCounts:
    """The exporters' work while the run stepped: exports read to their end, their bytes,
    and the errors (an export that failed is counted, and the exporter starts another)."""

    completed: int = 0
    megabytes: float = 0.0
    errors: list[str] = field(default_factory=list)


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


def start_server(
    tree: Path,
    data_dir: Path,
    port: int,
    env_extra: dict[str, str],
    prefix: tuple[str, ...] = (),
) -> Any:
    """``thermocomp serve`` from ``tree`` (this checkout, or a baseline's ``git archive``),
    started through ``prefix`` (e.g. ``chrt``) if given, answering its health check;
    SystemExit when it does not within SERVER_START_S."""
    env = {
        **os.environ,
        "PYTHONPATH": str(tree),
        "THERMOCOMP_API__CONTROL_TOKEN": TOKEN,
        "THERMOCOMP_STORAGE__DATA_DIR": str(data_dir),
        "THERMOCOMP_BENCH__CLOCK": "real",
        "THERMOCOMP_ROBOT__DRIVER": "c500c-server",
        **env_extra,
    }
    command = [*prefix, sys.executable, "-m", "api", "--log-level", "WARNING", "serve"]
    command += ["--config", "config/sim.toml", "--host", "127.0.0.1", "--port", str(port)]
    process = subprocess.Popen(command, cwd=tree, env=env)
    return wait_until_healthy(process, port, SERVER_START_S, f"the server in {tree}")


async def _reader(
    port: int, counts: list[int], stages: list[dict[str, float]] | None = None
) -> None:
    """One WebSocket client on the steps; ``stages`` (one reader's) gathers each step event's
    stage times (``stage_s``, wall seconds), to say which stage a late step spent its time in."""
    async with connect(f"ws://127.0.0.1:{port}/api/v1/ws?topics=steps") as ws:
        async for message in ws:
            counts[0] += 1
            if stages is not None:
                event = json.loads(message)
                data = event.get("data") or {}
                if event.get("type") == "step" and "stage_s" in data:
                    stages.append(data["stage_s"])


async def _export_csv(client: httpx.AsyncClient, run_id: int) -> int:
    size = 0
    url = f"/api/v1/runs/{run_id}/steps"
    async with client.stream("GET", url, params={"format": "csv"}) as answer:
        answer.raise_for_status()
        async for part in answer.aiter_raw():
            size += len(part)
    return size


async def _export_json(client: httpx.AsyncClient, run_id: int) -> int:
    """Every JSON page to the run's end (``next_from`` parsed, the rest only counted: what
    the server pays is the point, as in benchmarks/bench_exports.py)."""
    size, start = 0, 0
    while True:
        answer = await client.get(
            f"/api/v1/runs/{run_id}/steps", params={"from": start, "limit": EXPORT_PAGE_STEPS}
        )
        answer.raise_for_status()
        size += len(answer.content)
        following = next_page(answer.content, start)
        if following is None:
            return size
        start = following


async def _exporter(port: int, run_id: int, as_csv: bool, counts: ExportCounts) -> None:
    """One exporter: the finished run, again and again, until cancelled."""
    fetch = _export_csv if as_csv else _export_json
    async with httpx.AsyncClient(
        base_url=f"http://127.0.0.1:{port}", timeout=EXPORT_TIMEOUT_S
    ) as client:
        while True:
            try:
                size = await fetch(client, run_id)
            except httpx.HTTPError as err:
                counts.errors.append(f"{type(err).__name__}: {err}")
                await asyncio.sleep(1.0)
                continue
            counts.completed += 1
            counts.megabytes += size / 1e6


#: The stages a step does before the next deadline; the rest may overlap the next step's move.
MOVING_STAGES = ("model", "check", "move", "frame")


@dataclass
class ServedRun:
    """The server (its process), a client of its API, the run started, and the WebSocket
    messages read so far (``ws_messages[0]``)."""

    server: Any
    client: httpx.AsyncClient
    run_id: int
    ws_messages: list[int]
    exports: ExportCounts = field(default_factory=ExportCounts)
    #: every step event's stage times (s), in the order received
    stages: list[dict[str, float]] = field(default_factory=list)

    def long_steps(self, period_s: float) -> dict[str, Any]:
        """The steps whose stages took longer than the period: how many, per stage the
        longest it took in one of them (ms), and how many of them overran on the period's
        own stages (model to frame; a two-link step's centroid, IR and record overlap the next
        step's move, daemon/run/step.py MeasuringStep) or in that overlapped part alone."""
        long = [s for s in self.stages if sum(s.values()) > period_s]
        names = sorted({name for s in long for name in s})
        return {
            "count": len(long),
            "moving_over_period": sum(
                sum(s.get(n, 0.0) for n in MOVING_STAGES) > period_s for s in long
            ),
            "measuring_over_period": sum(
                sum(v for n, v in s.items() if n not in MOVING_STAGES) > period_s for s in long
            ),
            "stage_max_ms": {n: round(1e3 * max(s.get(n, 0.0) for s in long), 2) for n in names},
        }

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
    tree: Path,
    seconds: float,
    env_extra: dict[str, str],
    load: ServedLoad | None = None,
    prefix: tuple[str, ...] = (),
) -> AsyncIterator[ServedRun]:
    """A server from ``tree`` with ``env_extra``, its WebSocket readers and exporters
    (``load``; by default one reader and no exporter), and a run of ``seconds`` at the load's
    step started; the readers, the exporters and the server stopped on exit. The WebSocket
    messages counted are every reader's together."""
    load = load or ServedLoad()
    port = free_port()
    with tempfile.TemporaryDirectory() as folder:
        data_dir = Path(folder) / "data"
        export_run = None
        if load.exporters:
            data_dir.mkdir()
            export_run = await asyncio.to_thread(fill_run, data_dir, EXPORT_STEPS)
        server = start_server(tree, data_dir, port, env_extra, prefix)
        try:
            async with httpx.AsyncClient(base_url=f"http://127.0.0.1:{port}", timeout=60) as c:
                counts = [0]
                exports = ExportCounts()
                stages: list[dict[str, float]] = []
                tasks = [
                    asyncio.create_task(_reader(port, counts, stages if n == 0 else None))
                    for n in range(load.ws_clients)
                ]
                if export_run is not None:
                    tasks += [
                        asyncio.create_task(_exporter(port, export_run, n % 2 == 0, exports))
                        for n in range(load.exporters)
                    ]
                try:
                    await asyncio.sleep(0.5)
                    response = await c.post(
                        "/api/v1/runs",
                        json={
                            "duration_s": seconds,
                            "step_s": load.step_s,
                            "compensation": "absolute",
                        },
                        headers=HEADERS,
                    )
                    response.raise_for_status()
                    yield ServedRun(server, c, response.json()["id"], counts, exports, stages)
                finally:
                    for task in tasks:
                        task.cancel()
                    await asyncio.gather(*tasks, return_exceptions=True)
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
