"""The hold through connection floods (issue 26), against a real ``thermocomp serve`` on the
simulated bench, on loopback.

For each scenario a flood runs in a process of its own (tests/flood.py: bounded, stops by
itself) while this process sends ``POST /api/v1/robot/stop`` with the control token, each on a
new connection, one every ``--gap`` seconds; each hold's time is measured from connect() to
the whole answer. Reference: the same holds with no flood, in the same run (the ratio).

Scenarios (the last two written to break the guard):

- ``none``: no flood (the reference);
- ``held-300``: 300 silent sockets kept open, each one the server closes opened again
  (issue 26: 0 of 75 holds got through);
- ``held-3000``: the same with 3,000, more than the guard keeps pending (PENDING_MAX): the
  oldest are closed and reopened all the time;
- ``connect-close``: connect and close back to back (issue 26: 5 of 26 holds dropped);
- ``cap-full``: ``api.max_connections`` (256) connections kept served with a request every
  second each, plus ordinary requests beyond them (which must get 503);
- ``churn-300``: new silent connections back to back from two processes, 300 of each open at
  any time: the pending pool turns over as fast as the machine can connect.

Usage: ``.venv/bin/python benchmarks/bench_flood.py [--holds 75] [--gap 0.05]``.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.bench_api import TOKEN, free_port, start_server
from benchmarks.common import print_table, write_results
from tests.flood import ConnectStorm, HeldSockets, exchange, request, send_hold

#: Seconds a flood runs before the first hold (its sockets are open, its rate steady).
WARM_UP_S = 2.0
#: The server's api.max_connections (the default).
MAX_CONNECTIONS = 256


def _kept_served(port: int, count: int, until: float, stats: dict[str, int]) -> None:
    """``count`` connections each sending a request every second (never idle long enough for
    the keep-alive timeout): they hold every slot of the cap."""
    payload = b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    sockets: list[socket.socket] = []
    try:
        while len(sockets) < count and time.monotonic() < until:
            sock = socket.create_connection(("127.0.0.1", port), timeout=10)
            sock.sendall(payload)
            sock.recv(65536)
            sockets.append(sock)
        stats["kept"] = len(sockets)
        while time.monotonic() < until:
            for sock in sockets:
                try:
                    sock.sendall(payload)
                    if not sock.recv(65536):
                        stats["lost"] = stats.get("lost", 0) + 1
                except OSError:
                    stats["lost"] = stats.get("lost", 0) + 1
            time.sleep(max(0.0, 1.0 - 0.001 * count))
    finally:
        for sock in sockets:
            sock.close()


def flood(kind: str, port: int, seconds: float, results: Any) -> None:
    """One flood process: runs ``kind`` for ``seconds``, puts its counts on ``results``."""
    stats: dict[str, int] = {}
    until = time.monotonic() + seconds
    if kind.startswith("held-"):
        with HeldSockets(port, int(kind.split("-")[1]), limit_s=seconds) as held:
            time.sleep(seconds)
        stats = {"opened": held.opened, "closed_by_server": held.closed_by_server}
    elif kind == "churn-300":
        with HeldSockets(port, 300, limit_s=seconds, churn=True) as held:
            time.sleep(seconds)
        stats = {"opened": held.opened, "closed_by_server": held.closed_by_server}
    elif kind == "connect-close":
        with ConnectStorm(port, limit_s=seconds) as storm:
            time.sleep(seconds)
        stats = {"opened": storm.opened, "failed": storm.failed}
    elif kind == "cap-full":
        keeper = threading.Thread(
            target=_kept_served, args=(port, MAX_CONNECTIONS, until, stats), daemon=True
        )
        keeper.start()
        time.sleep(WARM_UP_S)
        ordinary = {"served": 0, "503": 0, "other": 0}
        payload = request("GET", "/api/v1/health")
        while time.monotonic() < until - 0.5:
            answer = exchange(port, payload, timeout_s=5.0)
            key = "served" if answer.status == 200 else "503" if answer.status == 503 else "other"
            ordinary[key] += 1
            time.sleep(0.05)
        keeper.join()
        stats.update({f"ordinary_{k}": v for k, v in ordinary.items()})
    results.put(stats)


def run_scenario(kind: str, port: int, holds: int, gap_s: float, processes: int) -> dict[str, Any]:
    seconds = WARM_UP_S + holds * (gap_s + 0.05) + 10.0
    context = multiprocessing.get_context("spawn")
    results = context.Queue()
    floods = [
        context.Process(target=flood, args=(kind, port, seconds, results), daemon=True)
        for _ in range(processes if kind != "none" else 0)
    ]
    load_before = os.getloadavg()[0]
    for process in floods:
        process.start()
    time.sleep(WARM_UP_S if floods else 0.0)
    if kind == "cap-full":
        time.sleep(WARM_UP_S)  # its 256 connections are open
    answers = []
    for _ in range(holds):
        answers.append(send_hold(port, TOKEN, timeout_s=30.0))
        time.sleep(gap_s)
    flood_stats = [results.get(timeout=seconds + 60) for _ in floods]
    for process in floods:
        process.join(timeout=30)
    through = [a for a in answers if a.status == 200]
    latencies_ms = np.array([a.seconds * 1000 for a in through]) if through else np.array([np.nan])
    totals: dict[str, int] = {}
    for stats in flood_stats:
        for key, value in stats.items():
            totals[key] = totals.get(key, 0) + value
    return {
        "flood": kind,
        "flood_processes": len(floods),
        "holds_sent": holds,
        "holds_through": len(through),
        "failures": [
            f"{a.status} {a.kind or a.error} after {a.seconds:.3f} s"
            for a in answers
            if a.status != 200
        ],
        "p50_ms": float(np.percentile(latencies_ms, 50)),
        "p99_ms": float(np.percentile(latencies_ms, 99)),
        "max_ms": float(np.max(latencies_ms)),
        "flood_counts": totals,
        "connections_per_s": totals.get("opened", 0) / seconds,
        "load_average_1min": [load_before, os.getloadavg()[0]],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--holds", type=int, default=75, help="holds per scenario")
    parser.add_argument("--gap", type=float, default=0.05, help="seconds between holds")
    args = parser.parse_args()
    port = free_port()
    scenarios = [
        ("none", 0),
        ("held-300", 1),
        ("held-3000", 1),
        ("connect-close", 1),
        ("cap-full", 1),
        ("churn-300", 2),
    ]
    rows = []
    with tempfile.TemporaryDirectory() as data:
        server = start_server(Path(data), port)
        try:
            for kind, processes in scenarios:
                rows.append(run_scenario(kind, port, args.holds, args.gap, processes))
                print(f"{kind}: {rows[-1]['holds_through']}/{args.holds}", flush=True)
            alive = send_hold(port, TOKEN)
        finally:
            server.terminate()
            server.wait(timeout=60)
    reference = rows[0]["p50_ms"]
    print(
        f"\nPOST /api/v1/robot/stop with the control token on a new connection, real "
        f"`thermocomp serve` (sim bench), {args.holds} holds per scenario, {args.gap * 1000:.0f}"
        " ms apart; latency from connect() to the whole answer"
    )
    print_table(
        [
            "flood",
            "procs",
            "conn/s",
            "holds through",
            "p50 ms",
            "p99 ms",
            "max ms",
            "p50 / none",
            "load 1 min",
        ],
        [
            [
                r["flood"],
                r["flood_processes"],
                round(r["connections_per_s"]),
                f"{r['holds_through']}/{r['holds_sent']}",
                r["p50_ms"],
                r["p99_ms"],
                r["max_ms"],
                r["p50_ms"] / reference,
                "{:.1f}-{:.1f}".format(*r["load_average_1min"]),
            ]
            for r in rows
        ],
    )
    for r in rows:
        if r["failures"] or r["flood_counts"]:
            print(f"{r['flood']}: failures {r['failures']}, flood {r['flood_counts']}")
    print(f"after every flood, a hold: {alive.status}")
    write_results(
        "bench_flood",
        {"holds": args.holds, "gap_s": args.gap, "scenarios": rows, "after": alive.status},
    )
    worst = min(r["holds_through"] / r["holds_sent"] for r in rows)
    return 0 if worst == 1.0 and alive.status == 200 else 1


if __name__ == "__main__":
    sys.exit(main())
