"""The whole daemon's 20 ms step on the fast path, idle and on a busy machine: one event loop
for everything (a ``git archive`` of the baseline ref, by default ``main``) against the control
loop on its own thread (this tree, daemon/run/control_loop.py), with and without real-time
scheduling, beside a lean reference client, in one benchmark run.

Each measurement is a real ``thermocomp serve`` (``python -m api serve --config
config/sim.toml``, real clock, ``robot.driver = "c500c-server"``: the simulated bench's paced
emulator of the fast path's program on a pty) running one run at a 20 ms step while a dashboard
-like client reads it (one WebSocket on the steps, ``GET /state`` every 0.5 s). The reference is
the fast path's driver loop alone (benchmarks/bench_fast_path.py ``fixed_step``: the host driver
against ``thermocomp emulate c500c --server`` in its own process, absolute deadlines, nothing
else in the process), for as long, under the same load.

The load is ``--busy`` sets of busy processes (``nice -n 0 python -c 'while 1: pass'``) started
before and stopped after each measurement; the machine's 1-minute load average is printed
beside each figure (the machine may be shared: it is the load that counts, not the count).
An overrun is a step still running at the next deadline (daemon/run/scheduler.py).

Run: .venv/bin/python benchmarks/bench_loop_isolation.py [--seconds 30] [--busy 0 2 4]
     [--baseline main] [--repeats 1]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, write_results
from benchmarks.served_run import ROOT, STEP_S, busy_processes, run_figures, served_run

REFERENCE = (
    "import asyncio, json, sys; sys.path.insert(0, {root!r});"
    "from benchmarks.bench_fast_path import fixed_step;"
    "print(json.dumps(asyncio.run(fixed_step({seconds}, inline=False, freeze=True))))"
)


async def daemon_run(tree: Path, seconds: float, env_extra: dict[str, str]) -> dict[str, Any]:
    async with served_run(tree, seconds, env_extra) as served:
        run = await served.wait_ended()
    figures = run_figures(run)
    summary = run.get("summary") or {}
    steps, overruns = figures["steps"], figures["overruns"]
    return {
        **figures,
        "overrun_pct": 100.0 * overruns / steps if steps else None,
        "skipped": summary.get("skipped_deadlines"),
        "ws_messages": served.ws_messages[0],
        "stage_p99_ms": {
            name: round(1e3 * value["p99"], 2)
            for name, value in ((summary.get("timing") or {}).get("stages_s") or {}).items()
        },
    }


def reference_run(seconds: float) -> dict[str, Any]:
    code = REFERENCE.format(root=str(ROOT), seconds=seconds)
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True
    )
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    steps, overruns = result["steps"], result["overruns"]
    return {
        "state": "finished",
        "steps": steps,
        "overruns": overruns,
        "overrun_pct": 100.0 * overruns / steps if steps else None,
        "skipped": result["skipped"],
        "lateness_p99_ms": result.get("lateness_p99_ms"),
        "ws_messages": None,
    }


def baseline_tree(ref: str, folder: Path) -> Path:
    """The baseline as committed (``git archive``): no worktree, nothing left behind."""
    archive = subprocess.run(["git", "archive", ref], cwd=ROOT, capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive.stdout, check=True)
    return folder


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--busy", type=int, nargs="+", default=[0, 2, 4])
    parser.add_argument("--baseline", default="main")
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as folder:
        base = baseline_tree(args.baseline, Path(folder))
        variants: list[tuple[str, Path | None, dict[str, str]]] = [
            (f"one loop ({args.baseline})", base, {}),
            ("control thread, SCHED_FIFO", ROOT, {}),
            ("control thread, no RT", ROOT, {"THERMOCOMP_SCHEDULER__REALTIME_PRIORITY": "0"}),
            ("lean reference client", None, {}),
        ]
        for busy in args.busy:
            for _ in range(args.repeats):
                for name, tree, env_extra in variants:
                    with busy_processes(busy):
                        load_before = os.getloadavg()[0]
                        if tree is None:
                            result = reference_run(args.seconds)
                        else:
                            result = asyncio.run(daemon_run(tree, args.seconds, env_extra))
                        load_after = os.getloadavg()[0]
                    row = {
                        "variant": name,
                        "busy": busy,
                        "load_before": load_before,
                        "load_after": load_after,
                        **result,
                    }
                    rows.append(row)
                    print(
                        f"  {name:30s} busy {busy}  load {load_before:5.2f}->{load_after:5.2f}  "
                        f"{row['overruns']}/{row['steps']} overruns  "
                        f"stage p99 ms {row.get('stage_p99_ms')}",
                        flush=True,
                    )
    print()
    print_table(
        ["variant", "busy", "load", "steps", "overruns", "%", "skipped", "late p99 ms"],
        [
            [
                r["variant"],
                r["busy"],
                f"{r['load_before']:.1f}-{r['load_after']:.1f}",
                r["steps"],
                r["overruns"],
                "-" if r["overrun_pct"] is None else f"{r['overrun_pct']:.2f}",
                r["skipped"],
                "-" if r["lateness_p99_ms"] is None else f"{r['lateness_p99_ms']:.2f}",
            ]
            for r in rows
        ],
    )
    worst = max(
        (r for r in rows if r["variant"].startswith("control thread, SCHED") and r["busy"] > 0),
        key=lambda r: r["overrun_pct"] or 0.0,
        default=None,
    )
    if worst is not None:
        print(
            f"\nworst loaded control-thread (SCHED_FIFO) run: {worst['overrun_pct']:.2f} % "
            f"overruns at load {worst['load_before']:.1f}-{worst['load_after']:.1f} "
            "(target < 1 %)"
        )
    write_results(
        "loop_isolation",
        {"seconds": args.seconds, "step_s": STEP_S, "baseline": args.baseline, "runs": rows},
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
