"""The whole daemon's 20 ms step on the fast path, idle and on a busy machine: a baseline (a
``git archive`` of the baseline ref, by default ``main``) against this tree's control loop on
its own thread (daemon/run/control_loop.py) with real-time scheduling as the daemon asks for it,
with the whole process real-time (what the unit's ``CPUSchedulingPolicy=fifo`` would give) and
without, beside a lean reference client, in one benchmark run.

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

Issue 30's targets: ``--seconds 600 --busy 0 2 --variants fifo no-rt reference --emulator
process`` (20 ms, the paced emulator in its own process: ``bench.emulator = "process"``), and
the same at ``--step-ms 100 --ws-clients 50 --exporters 6`` (benchmarks/served_run.py
``ServedLoad``: 50 WebSocket clients on the steps, six exporters fetching a finished 24-h run
over and over); target <= 0.1 % overruns and lateness p99 <= 2 ms with SCHED_FIFO.

Run: .venv/bin/python benchmarks/bench_loop_isolation.py [--seconds 30] [--busy 0 2 4]
     [--baseline main] [--repeats 1] [--step-ms 20] [--ws-clients 1] [--exporters 0]
     [--variants baseline fifo fifo-all no-rt reference] [--emulator inline|process] [--name NAME]
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
from benchmarks.served_run import (
    ROOT,
    ServedLoad,
    busy_processes,
    run_figures,
    served_run,
)

REFERENCE = (
    "import asyncio, json, sys; sys.path.insert(0, {root!r});"
    "from benchmarks.bench_fast_path import fixed_step;"
    "print(json.dumps(asyncio.run(fixed_step({seconds}, inline=False, freeze=True,"
    " step_s={step_s}))))"
)
#: Issue 30's targets for the control thread with SCHED_FIFO.
TARGET_OVERRUN_PCT = 0.1
TARGET_LATE_P99_MS = 2.0
#: The variants by their command-line names: the label printed, whether it is the
#: baseline's tree ("base"), this tree ("this") or the lean reference client (None), the
#: daemon's extra environment, and what the server is started through.
VARIANTS: dict[str, tuple[str, str | None, dict[str, str], tuple[str, ...]]] = {
    "baseline": ("baseline ({baseline})", "base", {}, ()),
    "fifo": ("control thread, SCHED_FIFO", "this", {}, ()),
    # what the unit's CPUSchedulingPolicy=fifo would give: every thread of the daemon real-time
    # at priority 1, the control thread raising its own to scheduler.realtime_priority
    "fifo-all": ("whole daemon SCHED_FIFO", "this", {}, ("chrt", "--fifo", "1")),
    "no-rt": (
        "control thread, no RT",
        "this",
        {"THERMOCOMP_SCHEDULER__REALTIME_PRIORITY": "0"},
        (),
    ),
    "reference": ("lean reference client", None, {}, ()),
}


async def daemon_run(
    tree: Path,
    seconds: float,
    env_extra: dict[str, str],
    load: ServedLoad,
    prefix: tuple[str, ...] = (),
) -> dict[str, Any]:
    async with served_run(tree, seconds, env_extra, load, prefix) as served:
        run = await served.wait_ended()
    figures = run_figures(run)
    summary = run.get("summary") or {}
    steps, overruns = figures["steps"], figures["overruns"]
    return {
        **figures,
        "overrun_pct": 100.0 * overruns / steps if steps else None,
        "skipped": summary.get("skipped_deadlines"),
        "ws_messages": served.ws_messages[0],
        "exports_completed": served.exports.completed,
        "exports_mb": round(served.exports.megabytes, 1),
        "export_errors": served.exports.errors[:5],
        "long_steps": served.long_steps(load.step_s),
        "stage_p99_ms": {
            name: round(1e3 * value["p99"], 2)
            for name, value in ((summary.get("timing") or {}).get("stages_s") or {}).items()
        },
    }


def reference_run(seconds: float, step_s: float) -> dict[str, Any]:
    code = REFERENCE.format(root=str(ROOT), seconds=seconds, step_s=step_s)
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
        "lateness_p99_ms": result.get("late_p99_ms"),
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
    parser.add_argument("--step-ms", type=float, default=20.0, help="the run's step (ms)")
    parser.add_argument("--ws-clients", type=int, default=1, help="WebSocket clients")
    parser.add_argument("--exporters", type=int, default=0, help="exporters of a 24-h run")
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS))
    parser.add_argument(
        "--emulator",
        choices=["inline", "process"],
        default="inline",
        help="this tree's daemons: the bench's emulated controller in the daemon's process or "
        "its own (bench.emulator)",
    )
    parser.add_argument(
        "--baseline-emulator",
        choices=["inline", "process"],
        default="inline",
        help="the same for the baseline (process: a baseline that has bench.emulator)",
    )
    parser.add_argument("--name", default="loop_isolation", help="results/<name>.json")
    args = parser.parse_args()
    load = ServedLoad(
        step_s=args.step_ms / 1000.0, ws_clients=args.ws_clients, exporters=args.exporters
    )
    emulator_env = {
        which: {"THERMOCOMP_BENCH__EMULATOR": "process"} if choice == "process" else {}
        for which, choice in (("this", args.emulator), ("base", args.baseline_emulator))
    }
    print(
        f"step {args.step_ms:g} ms, {args.seconds:g} s per run, {load.ws_clients} WebSocket "
        f"clients, {load.exporters} exporters, emulator {args.emulator}",
        flush=True,
    )
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as folder:
        base = baseline_tree(args.baseline, Path(folder)) if "baseline" in args.variants else None
        for busy in args.busy:
            for _ in range(args.repeats):
                for key in args.variants:
                    label, which, env_extra, prefix = VARIANTS[key]
                    name = label.format(baseline=args.baseline)
                    with busy_processes(busy):
                        load_before = os.getloadavg()[0]
                        if which is None:
                            result = reference_run(args.seconds, load.step_s)
                        else:
                            tree = ROOT if which == "this" else base
                            assert tree is not None
                            env = {**env_extra, **emulator_env[which]}
                            result = asyncio.run(daemon_run(tree, args.seconds, env, load, prefix))
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
                        f"late p99 {row.get('lateness_p99_ms')} ms  "
                        f"exports {row.get('exports_completed')} ({row.get('exports_mb')} MB)  "
                        f"stage p99 ms {row.get('stage_p99_ms')}  "
                        f"steps longer than the period {row.get('long_steps')}",
                        flush=True,
                    )
    print()
    print_table(
        ["variant", "busy", "load", "steps", "overruns", "%", "skipped", "late p99 ms", "exports"],
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
                "-" if r.get("exports_completed") is None else r["exports_completed"],
            ]
            for r in rows
        ],
    )
    fifo = [r for r in rows if "SCHED_FIFO" in r["variant"]]
    if fifo:
        worst = max(fifo, key=lambda r: r["overrun_pct"] or 0.0)
        latest = max(fifo, key=lambda r: r["lateness_p99_ms"] or 0.0)
        print(
            f"\nworst SCHED_FIFO run: {worst['overrun_pct']:.3f} % overruns "
            f"(busy {worst['busy']}, load {worst['load_before']:.1f}-{worst['load_after']:.1f}; "
            f"target <= {TARGET_OVERRUN_PCT} %); worst lateness p99 "
            f"{latest['lateness_p99_ms']:.2f} ms (busy {latest['busy']}; target <= "
            f"{TARGET_LATE_P99_MS} ms)"
        )
    write_results(
        args.name,
        {
            "seconds": args.seconds,
            "step_s": load.step_s,
            "ws_clients": load.ws_clients,
            "exporters": load.exporters,
            "emulator": args.emulator,
            "baseline_emulator": args.baseline_emulator,
            "baseline": args.baseline,
            "runs": rows,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
