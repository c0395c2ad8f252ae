"""Holds and stops measured from outside a real server (issue 26): ``thermocomp serve`` (real
uvicorn, the production code path) on the simulated bench, with a spy on the robot links'
serial writers (benchmarks/spied_serve.py), driven by HTTP clients in this process.

Scenarios, each printed with the load (``os.getloadavg``) and the idle reference measured in the
same run (a ratio):
1. hold latency (sent -> answer) on an idle daemon: the reference;
2. hold latency during a start's build (a start, then a hold 0-300 ms later), and whether any
   motion command followed the hold's answer;
3. hold latency during an arm run playing its duty cycle (hold, resume, again);
4. 500 random control requests (start, pause, resume, stop, hold) from 5 clients: holds answered
   ``held`` that were followed by motion not preceded by a later start or resume (must be 0);
5. the stop of a 24-h run at 20 ms (4.32 M steps written into its database while it is paused):
   SIGTERM -> exit, against systemd's TimeoutStopSec = 30 s, and what the database then says
   (the summary deferred); then the next start: ready when, holds while it computes the
   deferred summary (against holds once it is recorded, same server), recorded when.

Usage: ``.venv/bin/python benchmarks/bench_stop.py [--quick] [--day-steps N] [--day-only]``.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import closing, contextmanager
from pathlib import Path
from typing import Any

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.common import print_table, write_results
from benchmarks.run_database import DAY_STEPS, add_steps
from daemon.storage.recorder import DATABASE_NAME
from drivers.c500c import protocol as console_proto
from drivers.c500c import server_protocol as server_proto

ROOT = Path(__file__).resolve().parent.parent
TOKEN = "bench-stop-control-token"
HEADERS = {"Authorization": f"Bearer {TOKEN}"}
SYSTEMD_STOP_S = 30.0  # deploy/thermocomp.service TimeoutStopSec
_SERVER_MOTION = {server_proto.RequestType.MOVE_GOAL, server_proto.RequestType.MOVE_RELATIVE}


def _config(folder: Path, *, arm: bool) -> Path:
    lines = [
        "[storage]",
        f'data_dir = "{folder / "data"}"',
        "report_at_end = false",
        "[api]",
        f'control_token = "{TOKEN}"',
        "control_burst = 10000",
        "control_rate_per_s = 10000.0",
        "[scheduler]",
        "duration_s = 86400.0",
        "step_s = 0.02" if not arm else "step_s = 20.0",
    ]
    if arm:
        lines += [
            "[bench]",
            'clock = "virtual"',
            "seed = 7",
            "[robot]",
            'driver = "sim"',
            "[ir]",
            'driver = "sim"',
            "[arm]",
            "enabled = true",
            'duty_cycle = "a465-pick-and-place"',
            "play_duty_cycle = true",
        ]
    else:
        lines += ["[bench]", 'clock = "real"']
    path = folder / ("arm.toml" if arm else "bench.toml")
    path.write_text("\n".join(lines) + "\n")
    return path


@contextmanager
def server(folder: Path, *, arm: bool = False) -> Iterator[tuple[httpx.Client, Path, Any]]:
    log = folder / "serial.log"
    log.write_text("")
    port = _free_port()
    command = [sys.executable, str(ROOT / "benchmarks" / "spied_serve.py"), str(log), "serve"]
    config = str(_config(folder, arm=arm))
    process = subprocess.Popen(
        [*command, "--config", config, "--host", "127.0.0.1", "--port", str(port)],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=(folder / "server.err").open("w"),
    )
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}/api/v1", headers=HEADERS, timeout=120)
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                if client.get("/health").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if process.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"the server did not start: {(folder / 'server.err').read_text()}")
            time.sleep(0.1)
        yield client, log, process
    finally:
        client.close()
        if process.poll() is None:
            process.send_signal(signal.SIGTERM)
            process.wait(120)


def _free_port() -> int:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def motions(log: Path) -> list[float]:
    """When each motion command went out (monotonic s), from the spy's log."""
    found: list[float] = []
    for line in log.read_text().splitlines():
        at, link, data = line.split(" ", 2)
        raw = bytes.fromhex(data)
        if link == "console":
            text = raw.decode("ascii", errors="replace").splitlines()
            found += [float(at)] * sum(1 for t in text if console_proto.is_motion_command(t))
        else:
            for event in server_proto.FrameDecoder().feed(raw):
                if isinstance(event, server_proto.Frame) and event.type in _SERVER_MOTION:
                    found.append(float(at))
    return found


def _state(client: httpx.Client) -> dict[str, Any]:
    state: dict[str, Any] = client.get("/state").json()
    return state


def _idle(client: httpx.Client) -> None:
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        state = _state(client)
        if state["state"] == "idle":
            return
        run = state.get("run") or {}
        if run.get("id") is not None and state["state"] not in ("stopping",):
            client.post(f"/runs/{run['id']}/stop")
        time.sleep(0.05)
    raise SystemExit("the daemon did not become idle")


def _until_running(client: httpx.Client, timeout_s: float = 300.0) -> None:
    deadline = time.monotonic() + timeout_s
    while (state := _state(client))["state"] != "running":
        if state["state"] == "idle" and state.get("run") and time.monotonic() > deadline - 290:
            raise SystemExit(f"the run ended before it ran: {state['run'].get('reason')}")
        if time.monotonic() > deadline:
            raise SystemExit("the run did not start")
        time.sleep(0.05)


def _hold(client: httpx.Client) -> tuple[float, float]:
    sent = time.monotonic()
    answer = client.post("/robot/stop")
    answered = time.monotonic()
    assert answer.status_code == 200 and answer.json()["held"], answer.text
    return sent, answered


def _ms(values: list[float]) -> dict[str, float]:
    ordered = sorted(values)
    pick = lambda q: 1e3 * ordered[min(len(ordered) - 1, int(q * len(ordered)))]  # noqa: E731
    return {
        "p50_ms": pick(0.5),
        "p99_ms": pick(0.99),
        "max_ms": 1e3 * ordered[-1],
        "n": len(values),
    }


def idle_holds(client: httpx.Client, count: int) -> list[float]:
    return [answered - sent for sent, answered in (_hold(client) for _ in range(count))]


def holds_during_builds(client: httpx.Client, log: Path, trials: int) -> dict[str, Any]:
    latencies: list[float] = []
    followed = 0
    for _ in range(trials):
        _idle(client)
        starter = threading.Thread(target=lambda: client.post("/runs", json={}))
        starter.start()
        time.sleep(random.uniform(0.0, 0.3))
        sent, answered = _hold(client)
        latencies.append(answered - sent)
        starter.join()
        time.sleep(0.5)
        followed += any(at > answered for at in motions(log))
        _idle(client)
    return {"latency": _ms(latencies), "holds_followed_by_motion": followed, "trials": trials}


def holds_during_play(client: httpx.Client, log: Path, trials: int) -> dict[str, Any]:
    _idle(client)
    run_id = client.post("/runs", json={}).raise_for_status().json()["id"]
    _until_running(client)
    latencies: list[float] = []
    followed = 0
    for _ in range(trials):
        time.sleep(random.uniform(0.2, 1.0))  # the cycle plays meanwhile
        sent, answered = _hold(client)
        latencies.append(answered - sent)
        time.sleep(0.3)
        followed += any(answered < at for at in motions(log))  # before the resume below
        client.post(f"/runs/{run_id}/resume")
        time.sleep(0.3)
        log.write_text("")  # what the resumed cycle moves is not this hold's business
    client.post(f"/runs/{run_id}/stop")
    return {"latency": _ms(latencies), "holds_followed_by_motion": followed, "trials": trials}


def random_control(base: str, log: Path, requests: int, clients: int) -> dict[str, Any]:
    """``requests`` random control requests from ``clients`` threads; every request's send and
    answer times. A hold answered ``held`` is violated by a motion after its answer with no
    start or resume SENT after the hold was sent (such a request may legitimately undo it)."""
    events: list[tuple[str, float, float, int]] = []  # kind, sent, answered, status
    lock = threading.Lock()

    def client_loop(seed: int) -> None:
        rng = random.Random(seed)
        with httpx.Client(base_url=base, headers=HEADERS, timeout=120) as client:
            for _ in range(requests // clients):
                kind = rng.choice(["start", "hold", "hold", "pause", "resume", "stop"])
                run = (_state(client).get("run") or {}).get("id", 0)
                path = {
                    "start": "/runs",
                    "hold": "/robot/stop",
                    "pause": f"/runs/{run}/pause",
                    "resume": f"/runs/{run}/resume",
                    "stop": f"/runs/{run}/stop",
                }[kind]
                sent = time.monotonic()
                status = client.post(path, json={} if kind == "start" else None).status_code
                with lock:
                    events.append((kind, sent, time.monotonic(), status))
                time.sleep(rng.uniform(0.0, 0.2))

    threads = [threading.Thread(target=client_loop, args=(k,)) for k in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    time.sleep(1.0)
    moved = motions(log)
    releases = sorted(sent for kind, sent, _, _ in events if kind in ("start", "resume"))
    holds = [(sent, answered) for kind, sent, answered, status in events if kind == "hold"]
    violated = 0
    for sent, answered in holds:
        excuse = next((r for r in releases if r > sent), float("inf"))
        violated += any(answered < at < excuse for at in moved)
    return {"requests": len(events), "holds": len(holds), "holds_followed_by_motion": violated}


def day_run_stop(folder: Path, steps: int) -> dict[str, Any]:
    with server(folder) as (client, _log, process):
        run_id = client.post("/runs", json={}).raise_for_status().json()["id"]
        _until_running(client)
        client.post(f"/runs/{run_id}/pause").raise_for_status()
        began = time.monotonic()
        add_steps(folder / "data", run_id, steps, first_step=10_000_000)
        built_s = time.monotonic() - began
        client.post(f"/runs/{run_id}/resume").raise_for_status()
        time.sleep(1.0)
        sent = time.monotonic()
        process.send_signal(signal.SIGTERM)
        code = process.wait(300)
        exit_s = time.monotonic() - sent
    with closing(sqlite3.connect(folder / "data" / DATABASE_NAME)) as db:
        state, reason, summary = db.execute(
            "SELECT state, reason, summary_json FROM runs WHERE id = ?", (run_id,)
        ).fetchone()
        pending = db.execute(
            "SELECT COUNT(*) FROM pending_summaries WHERE run_id = ?", (run_id,)
        ).fetchone()[0]
    return {
        "steps": steps,
        "build_s": built_s,
        "sigterm_to_exit_s": exit_s,
        "exit_code": code,
        "within_timeout_stop_s": exit_s < SYSTEMD_STOP_S,
        "state": state,
        "reason": reason,
        "summary_recorded": summary is not None,
        "summary_deferred": bool(pending),
        "next_start": deferred_summary_at_start(folder, run_id),
    }


def deferred_summary_at_start(folder: Path, run_id: int) -> dict[str, Any]:
    """The next start: how soon the daemon is ready, holds while the deferred summary is
    computed (the reference: holds once it is recorded, same server), and when it is."""
    began = time.monotonic()
    with server(folder) as (client, _log, _process):
        ready_s = time.monotonic() - began
        info = client.get(f"/runs/{run_id}").raise_for_status().json()
        pending_at_ready = info["summary_pending"]
        during: list[float] = []
        while info["summary"] is None and time.monotonic() - began < 600:
            sent, answered = _hold(client)
            during.append(answered - sent)
            time.sleep(0.2)
            info = client.get(f"/runs/{run_id}").raise_for_status().json()
        recorded_s = time.monotonic() - began
        after = [answered - sent for sent, answered in (_hold(client) for _ in range(20))]
    return {
        "ready_s": ready_s,
        "summary_pending_at_ready": pending_at_ready,
        "summary_recorded_s": recorded_s,
        "summary_recorded": info["summary"] is not None,
        "summary_steps": (info["summary"] or {}).get("steps"),
        "holds_during": _ms(during) if during else None,
        "holds_after": _ms(after),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer trials")
    parser.add_argument("--day-steps", type=int, default=DAY_STEPS)
    parser.add_argument("--requests", type=int, default=500)
    parser.add_argument("--day-only", action="store_true", help="scenario 5 only")
    args = parser.parse_args()
    if args.day_only:
        day_only(args.day_steps)
        return
    trials = 8 if args.quick else 25
    random.seed(26)
    results: dict[str, Any] = {"load_before": os.getloadavg()}
    with tempfile.TemporaryDirectory() as root:
        folder = Path(root) / "bench"
        folder.mkdir()
        with server(folder) as (client, log, _):
            results["idle"] = _ms(idle_holds(client, 3 * trials))
            results["build"] = holds_during_builds(client, log, trials)
            log.write_text("")
            results["random"] = random_control(str(client.base_url), log, args.requests, 5)
        arm = Path(root) / "arm"
        arm.mkdir()
        with server(arm, arm=True) as (client, log, _):
            results["play"] = holds_during_play(client, log, trials)
        day = Path(root) / "day"
        day.mkdir()
        results["day"] = day_run_stop(day, args.day_steps)
    results["load_after"] = os.getloadavg()
    idle_p50 = results["idle"]["p50_ms"]
    rows: list[list[Any]] = [
        ["idle (reference)", results["idle"]["p50_ms"], results["idle"]["p99_ms"], 1.0, "-"]
    ]
    for name, key in (("during a start's build", "build"), ("during an arm play", "play")):
        latency = results[key]["latency"]
        rows.append(
            [
                name,
                latency["p50_ms"],
                latency["p99_ms"],
                latency["p50_ms"] / idle_p50,
                results[key]["holds_followed_by_motion"],
            ]
        )
    print(f"load {results['load_before']} -> {results['load_after']}")
    print_table(["hold", "p50 (ms)", "p99 (ms)", "p50 / idle", "followed by motion"], rows)
    random_result = results["random"]
    print(
        f"\n{random_result['requests']} random control requests, 5 clients: "
        f"{random_result['holds']} holds, {random_result['holds_followed_by_motion']} followed "
        "by motion"
    )
    _print_day(results["day"])
    write_results("bench_stop", results)


def _print_day(day_result: dict[str, Any]) -> None:
    print(
        f"\n24-h run ({day_result['steps']} steps): SIGTERM -> exit "
        f"{day_result['sigterm_to_exit_s']:.1f} s (TimeoutStopSec {SYSTEMD_STOP_S:.0f} s), "
        f"state {day_result['state']!r}, summary recorded: {day_result['summary_recorded']}, "
        f"deferred: {day_result['summary_deferred']}"
    )
    start = day_result["next_start"]
    during, after = start["holds_during"], start["holds_after"]
    print(
        f"next start: ready {start['ready_s']:.1f} s (pending then: "
        f"{start['summary_pending_at_ready']}), summary recorded {start['summary_recorded_s']:.1f}"
        f" s after the start ({start['summary_steps']} steps)"
    )
    if during is not None:
        print(
            f"holds while computing it: p50 {during['p50_ms']:.1f} ms, max {during['max_ms']:.1f}"
            f" ms (n {during['n']}); after: p50 {after['p50_ms']:.1f} ms, max "
            f"{after['max_ms']:.1f} ms; p50 ratio {during['p50_ms'] / after['p50_ms']:.2f}"
        )


def day_only(steps: int) -> None:
    results: dict[str, Any] = {"load_before": os.getloadavg()}
    with tempfile.TemporaryDirectory() as root:
        day = Path(root) / "day"
        day.mkdir()
        results["day"] = day_run_stop(day, steps)
    results["load_after"] = os.getloadavg()
    print(f"load {results['load_before']} -> {results['load_after']}")
    _print_day(results["day"])
    write_results("bench_stop_day", results)


if __name__ == "__main__":
    main()
