"""Step exports of a 24-h run at 1 s (86,401 steps) against the storage's own speed (issue 30).

A data directory holds one finished run of 86,401 steps filled as a two-link bench run fills
them (every measured column, the IR regions, the model's 17 node temperatures, the stage
times). A real ``thermocomp serve`` (config/sim.toml, loopback) serves it, and one client
fetches, alternately in the same run (A B C D A B C D ...):

- the reference: ``sqlite3 -csv -header`` (SQLite's own CSV output, its CLI) of the same
  columns in the same order, to /dev/null; and Python's ``csv`` module writing the same
  cursor to /dev/null (a second reference);
- ``GET /api/v1/runs/{id}/steps?format=csv``: the whole run streamed (target: <= 2x the
  sqlite3 CLI's time, i.e. >= 50 % of its speed);
- the JSON: every page of ``GET /api/v1/runs/{id}/steps?limit=5000`` from ``from=0`` to
  ``next_from`` null (target as CSV's; the client reads ``next_from`` from each page's end
  and does not parse the rest, as the CSV's client parses nothing).

Each export's body is read to the end and counted; beside its wall time the CPU time it cost
every process involved (the sqlite3 CLI; the server, its export process and this client) is
reported, the figure that a loaded machine disturbs least. The server's resident memory (VmRSS of
it and its export process) is sampled every 20 ms while it runs, and its peak over the
idle level is reported (memory bounded: it must not grow with the run). The load average is
printed before and after. Usage::

    .venv/bin/python benchmarks/bench_exports.py            # 3 rounds
    .venv/bin/python benchmarks/bench_exports.py --rounds 1 --steps 20000   # a smoke run
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import re
import resource
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.bench_api import free_port, start_server
from benchmarks.common import print_table, proc_status_mib, write_results
from daemon.storage.recorder import DATABASE_NAME, STEP_COLUMNS, Recorder

DAY_STEPS = 86_401
RSS_SAMPLE_S = 0.02
NODES = 17
TARGET_RATIO = 2.0  # issue 30: at most 2x the time of SQLite's own CSV output


def fill_run(data_dir: Path, steps: int) -> int:
    """A finished run of ``steps`` one-second steps with a bench run's columns filled."""
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run({"step_s": 1.0}, {}, None, "bench")
        recorder.finish_run(run_id, "completed", {"steps": steps}, None)
    columns = ",".join(STEP_COLUMNS)
    marks = ",".join("?" * len(STEP_COLUMNS))
    with contextlib.closing(sqlite3.connect(data_dir / DATABASE_NAME)) as db, db:
        db.executemany(
            f"INSERT INTO steps ({columns}) VALUES ({marks})",
            (_step(run_id, step) for step in range(steps)),
        )
    return run_id


def _step(run_id: int, step: int) -> tuple[Any, ...]:
    t = float(step)
    warm = 1.0 - 2.718281828 ** (-t / 7200.0)
    values: dict[str, Any] = dict.fromkeys(STEP_COLUMNS)
    values.update(
        run_id=run_id,
        step=step,
        scheduled_s=t,
        actual_s=t + 0.0003141 * (1 + step % 7),
        lateness_s=0.0003141 * (1 + step % 7),
        model_time_s=t,
        predicted_x_um=41.73 * warm,
        predicted_y_um=0.0,
        predicted_z_um=-3.217 * warm,
        offset_x_mm=-0.04173 * warm,
        offset_y_mm=0.0,
        offset_z_mm=0.003217 * warm,
        pose_x_mm=457.2 - 0.04173 * warm,
        pose_y_mm=0.0,
        pose_z_mm=250.0 + 0.003217 * warm,
        centroid_x_px=375.5 + 0.1234567 * (step % 13),
        centroid_y_px=290.5 - 0.0765432 * (step % 11),
        centroid_x_um=(375.5 + 0.1234567 * (step % 13)) * 8.6,
        centroid_y_um=(290.5 - 0.0765432 * (step % 11)) * 8.3,
        drift_x_um=0.1234567 * (step % 13) * 8.6,
        drift_y_um=-0.0765432 * (step % 11) * 8.3,
        residual_um=0.1234567 * (step % 13) * 8.6 - 0.05,
        ir_json=json.dumps(
            {
                name: {"mean_c": 20.0 + 15.0 * warm + 0.01 * i, "max_c": 21.0 + 15.0 * warm}
                for i, name in enumerate(("link1", "link2", "joint", "base"))
            }
        ),
        flags="late" if step % 997 == 0 else "",
        error="",
        deformation_scale=1.0,
        model_temperatures_json=json.dumps(
            {f"n{i}": 20.0 + 15.0 * warm * (i + 1) / NODES for i in range(NODES)}
        ),
        stage_ms_json=json.dumps(
            {"model": 0.123, "check": 0.0456, "move": 10.92, "frame": 3.21, "ir": 1.07}
        ),
        deformation_sigma_um=0.8123 * warm,
        innovation_nis=1.0 + 0.001 * (step % 100),
    )
    return tuple(values[name] for name in STEP_COLUMNS)


def _select(run_id: int) -> str:
    return f"SELECT {','.join(STEP_COLUMNS)} FROM steps WHERE run_id = {run_id} ORDER BY step"


def sqlite_cli_csv(database: Path, run_id: int) -> int:
    """SQLite's own CSV output (the CLI) to /dev/null; the bytes it wrote."""
    done = subprocess.run(
        ["sqlite3", "-readonly", "-csv", "-header", str(database), _select(run_id)],
        stdout=subprocess.PIPE,
        check=True,
    )
    return len(done.stdout)


def python_csv(database: Path, run_id: int) -> int:
    """Python's csv module on the same cursor, to /dev/null."""

    class Count:
        size = 0

        def write(self, text: str) -> None:
            Count.size += len(text)

    with contextlib.closing(sqlite3.connect(f"file:{database}?mode=ro", uri=True)) as db:
        writer = csv.writer(Count(), lineterminator="\n")
        writer.writerow(STEP_COLUMNS)
        writer.writerows(db.execute(_select(run_id)))
    return Count.size


def api_csv(client: httpx.Client, run_id: int) -> int:
    size = 0
    with client.stream("GET", f"/api/v1/runs/{run_id}/steps", params={"format": "csv"}) as r:
        r.raise_for_status()
        for part in r.iter_raw():
            size += len(part)
    return size


#: the end of a JSON page: ``..."next_from":N}`` (N null at the run's end)
NEXT_FROM = re.compile(rb'"next_from":(null|\d+)\}\s*$')


def next_page(page: bytes, start: int) -> int | None:
    """The ``from`` of the page after ``page`` (the one from ``start``), None at the run's end,
    read from the page's last bytes."""
    end = NEXT_FROM.search(page[-64:])
    if end is None:
        raise RuntimeError(f"page from {start} does not end in next_from")
    return None if end.group(1) == b"null" else int(end.group(1))


def api_json(client: httpx.Client, run_id: int) -> int:
    """Every page, each read to its end; the next page's ``from`` is taken from the page's
    last bytes (parsing 190 MB of JSON in this client cost as much CPU as the export itself:
    that is the consumer's cost, not the export's; tests/test_exports.py checks the JSON)."""
    size, start = 0, 0
    while True:
        answer = client.get(f"/api/v1/runs/{run_id}/steps", params={"from": start, "limit": 5000})
        answer.raise_for_status()
        size += len(answer.content)
        following = next_page(answer.content, start)
        if following is None:
            return size
        start = following


def _children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(child) for child in text.split()]


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process (/proc/PID/stat, clock ticks)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def cpu_now(server: int) -> float:
    """CPU seconds so far of this process, its finished children (the sqlite3 CLI) and the
    server with its children (the export process)."""
    own = time.process_time()
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    total = own + children.ru_utime + children.ru_stime
    for process in (server, *_children(server)):
        with contextlib.suppress(OSError):
            total += _cpu_s(process)
    return total


def _rss_mib(pid: int) -> float:
    """Resident memory of the server and its (export) children."""
    total = 0.0
    for process in (pid, *_children(pid)):
        with contextlib.suppress(OSError, RuntimeError):
            total += proc_status_mib("VmRSS", process)
    return total


@contextlib.contextmanager
def peak_rss(pid: int) -> Iterator[dict[str, float]]:
    sample = {"idle": _rss_mib(pid), "peak": 0.0}
    stop = threading.Event()

    def watch() -> None:
        while not stop.wait(RSS_SAMPLE_S):
            sample["peak"] = max(sample["peak"], _rss_mib(pid))

    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        yield sample
    finally:
        stop.set()
        watcher.join()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=3, help="A B C D rounds (3)")
    parser.add_argument("--steps", type=int, default=DAY_STEPS, help="steps in the run")
    args = parser.parse_args()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as folder:
        data_dir = Path(folder) / "data"
        data_dir.mkdir()
        started = time.perf_counter()
        run_id = fill_run(data_dir, args.steps)
        database = data_dir / DATABASE_NAME
        print(
            f"{args.steps} steps written in {time.perf_counter() - started:.1f} s, "
            f"database {database.stat().st_size / 1e6:.0f} MB"
        )
        port = free_port()
        server = start_server(data_dir, port)
        try:
            client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=300)
            ways: dict[str, Callable[[], int]] = {
                "sqlite3 -csv (reference)": lambda: sqlite_cli_csv(database, run_id),
                "python csv (reference)": lambda: python_csv(database, run_id),
                "API CSV": lambda: api_csv(client, run_id),
                "API JSON (all pages)": lambda: api_json(client, run_id),
            }
            api_csv(client, run_id)  # warm: the export process starts on first use
            results: dict[str, list[dict[str, float]]] = {name: [] for name in ways}
            for _ in range(args.rounds):
                for name, way in ways.items():
                    with peak_rss(server.pid) as memory:
                        begun, begun_cpu = time.perf_counter(), cpu_now(server.pid)
                        size = way()
                        seconds = time.perf_counter() - begun
                        cpu = cpu_now(server.pid) - begun_cpu
                    results[name].append(
                        {
                            "seconds": seconds,
                            "cpu_s": cpu,
                            "mb": size / 1e6,
                            "rss_growth_mib": max(0.0, memory["peak"] - memory["idle"]),
                            "rss_idle_mib": memory["idle"],
                        }
                    )
        finally:
            server.terminate()
            server.wait(timeout=30)
    load_after = os.getloadavg()
    reference = min(r["seconds"] for r in results["sqlite3 -csv (reference)"])
    reference_cpu = min(r["cpu_s"] for r in results["sqlite3 -csv (reference)"])
    rows, summary = [], {}
    for name, runs in results.items():
        best = min(r["seconds"] for r in runs)
        worst = max(r["seconds"] for r in runs)
        ratio = best / reference
        cpu = min(r["cpu_s"] for r in runs)
        growth = max(r["rss_growth_mib"] for r in runs)
        api = name.startswith("API")
        rows.append(
            [
                name,
                runs[0]["mb"],
                best,
                worst,
                runs[0]["mb"] / best,
                ratio,
                cpu,
                cpu / reference_cpu,
                f"<= {TARGET_RATIO}" if api else "-",
                (ratio <= TARGET_RATIO) if api else "-",
                growth if api else "-",
            ]
        )
        summary[name] = {
            "runs": runs,
            "best_s": best,
            "ratio_to_sqlite_cli": ratio,
            "cpu_s": cpu,
            "cpu_ratio_to_sqlite_cli": cpu / reference_cpu,
        }
    print(f"\n{args.steps} steps, {args.rounds} rounds alternated; best and worst of the rounds\n")
    print_table(
        [
            "export",
            "MB",
            "best s",
            "worst s",
            "MB/s",
            "best / sqlite3",
            "CPU s",
            "CPU / sqlite3",
            "target",
            "met",
            "server RSS growth MiB",
        ],
        rows,
    )
    print(
        f"\nload average {load_before[0]:.2f} before, {load_after[0]:.2f} after "
        f"({os.cpu_count()} CPUs)"
    )
    write_results(
        "exports",
        {
            "steps": args.steps,
            "rounds": args.rounds,
            "load_average": [load_before[0], load_after[0]],
            "exports": summary,
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
