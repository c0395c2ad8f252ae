"""Garbage collection pauses inside a run's steps: CPython's own thresholds against full
collections deferred to the slack between steps (daemon/run/gc_policy.py), in one benchmark
run, idle and on a busy machine.

Each measurement is a real ``thermocomp serve`` (``python -m api serve --config
config/sim.toml``, real clock, ``robot.driver = "c500c-server"``: the paced emulator of the
fast path's program on a pty) running one run at a 20 ms step while a dashboard-like client
reads it (a WebSocket on the steps, ``GET /state`` every 0.5 s, ``GET /metrics`` every 2 s).
A second scenario, written to make full collections happen, adds ``--churn`` requests a
second that the API's thread answers with garbage of its own (a 404, the state, the metrics).
The two settings alternate (A B A B): ``scheduler.gc_between_steps`` false (CPython's
thresholds: the reference), then true. At the run's end ``/metrics`` gives every collection
the process made (``gc.callbacks``): how many of each generation, how many while a step was
under way, their pause quantiles; the run's summary gives the overruns and the lateness p99;
/proc gives the server's resident and locked memory (the deferral's cost in memory).

The load is ``--busy`` busy loops (``python -c 'while 1: pass'`` at normal priority) started
before and stopped after each measurement; the 1-minute load average is printed beside each.

Run: .venv/bin/python benchmarks/bench_gc_pauses.py [--seconds 60] [--busy 0 2]
     [--repeats 2] [--churn 0 200]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
from pathlib import Path
from typing import Any

import httpx
from prometheus_client.parser import text_string_to_metric_families

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, proc_status_mib, write_results
from benchmarks.served_run import POLL_S, ROOT, STEP_S, busy_processes, run_figures, served_run

METRICS_EVERY_S = 2.0
VARIANTS = (
    ("CPython thresholds (reference)", {"THERMOCOMP_SCHEDULER__GC_BETWEEN_STEPS": "false"}),
    ("full collections between steps", {"THERMOCOMP_SCHEDULER__GC_BETWEEN_STEPS": "true"}),
)


def _gc_figures(text: str) -> dict[str, Any]:
    figures: dict[str, Any] = {"collections": {}, "in_step": {}, "pause_ms": {}}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            generation = sample.labels.get("generation")
            if sample.name == "thermocomp_gc_collections_total":
                figures["collections"][generation] = int(sample.value)
            elif sample.name == "thermocomp_gc_collections_in_step_total":
                figures["in_step"][generation] = int(sample.value)
            elif sample.name == "thermocomp_gc_pause_seconds":
                key = f"{generation}@{sample.labels['quantile']}"
                figures["pause_ms"][key] = 1e3 * sample.value
            elif sample.name in (
                "thermocomp_gc_full_between_steps_total",
                "thermocomp_gc_full_forced_total",
            ):
                figures[sample.name.removeprefix("thermocomp_gc_").removesuffix("_total")] = int(
                    sample.value
                )
    return figures


async def _churn(client: httpx.AsyncClient, per_s: float, counts: list[int]) -> None:
    """Requests the API's thread answers with garbage of its own: a refused run (404: an
    exception and its traceback, reference cycles the collector must find), the state and
    the metrics, ``per_s`` a second."""
    paths = ("/api/v1/runs/999999", "/api/v1/state", "/api/v1/runs/999999/steps", "/metrics")
    while True:
        for path in paths:
            await client.get(path)
            counts[0] += 1
            await asyncio.sleep(1.0 / per_s)


async def measured_run(
    seconds: float, env_extra: dict[str, str], churn_per_s: float
) -> dict[str, Any]:
    async with served_run(ROOT, seconds, env_extra) as served:
        c = served.client
        churned = [0]
        churn = asyncio.create_task(_churn(c, churn_per_s, churned)) if churn_per_s else None

        async def metrics_now_and_then(polls: int) -> None:
            if polls % round(METRICS_EVERY_S / POLL_S) == 0:
                await c.get("/metrics")

        run = await served.wait_ended(metrics_now_and_then)
        if churn is not None:
            churn.cancel()
            await asyncio.gather(churn, return_exceptions=True)
        metrics = _gc_figures((await c.get("/metrics")).text)
        rss = proc_status_mib("VmRSS", served.server.pid)
        locked = proc_status_mib("VmLck", served.server.pid)
    return {
        **run_figures(run),
        "rss_mib": rss,
        "locked_mib": locked,
        "churn_requests": churned[0],
        **metrics,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--busy", type=int, nargs="+", default=[0, 2])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument(
        "--churn",
        type=float,
        nargs="+",
        default=[0.0, 200.0],
        help="scenarios: extra API requests a second (404s, state, metrics) during the run",
    )
    args = parser.parse_args()
    rows: list[dict[str, Any]] = []
    for busy in args.busy:
        for churn in args.churn:
            for _ in range(args.repeats):
                for name, env_extra in VARIANTS:
                    with busy_processes(busy):
                        load_before = os.getloadavg()[0]
                        result = asyncio.run(measured_run(args.seconds, env_extra, churn))
                        load_after = os.getloadavg()[0]
                    row = {
                        "variant": name,
                        "busy": busy,
                        "churn": churn,
                        "load": [load_before, load_after],
                        **result,
                    }
                    rows.append(row)
                    print(
                        f"  {name:32s} busy {busy} churn {churn:g}/s load {load_before:5.2f}->"
                        f"{load_after:5.2f} full {row['collections'].get('2')} (in a step "
                        f"{row['in_step'].get('2')})",
                        flush=True,
                    )

    def pause(row: dict[str, Any], generation: str, quantile: str) -> str:
        value = row["pause_ms"].get(f"{generation}@{quantile}")
        return "-" if value is None else f"{value:.2f}"

    def young_max(row: dict[str, Any]) -> str:
        values = [row["pause_ms"].get(f"{g}@1") for g in ("0", "1")]
        known = [v for v in values if v is not None]
        return f"{max(known):.2f}" if known else "-"

    print()
    print_table(
        [
            "variant",
            "busy",
            "churn/s",
            "load",
            "steps",
            "overruns",
            "late p99 ms",
            "gen2",
            "gen2 in step",
            "gen2 p99 ms",
            "gen2 max ms",
            "gen0/1 in step",
            "gen0/1 max ms",
            "between/forced",
            "RSS MiB",
            "locked MiB",
        ],
        [
            [
                r["variant"],
                r["busy"],
                r["churn"],
                f"{r['load'][0]:.1f}-{r['load'][1]:.1f}",
                r["steps"],
                r["overruns"],
                "-" if r["lateness_p99_ms"] is None else f"{r['lateness_p99_ms']:.2f}",
                r["collections"].get("2"),
                r["in_step"].get("2"),
                pause(r, "2", "0.99"),
                pause(r, "2", "1"),
                r["in_step"].get("0", 0) + r["in_step"].get("1", 0),
                young_max(r),
                f"{r.get('full_between_steps', '-')}/{r.get('full_forced', '-')}",
                f"{r['rss_mib']:.0f}",
                f"{r['locked_mib']:.0f}",
            ]
            for r in rows
        ],
    )
    print(f"\n{args.seconds:.0f} s runs at a {STEP_S * 1e3:.0f} ms step, {os.cpu_count()} CPUs")
    write_results("gc_pauses", {"seconds": args.seconds, "step_s": STEP_S, "runs": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
