"""Time per model step: the 17-node Table 5.1 preset and 1,000- and 10,000-node chains.

Each step is one ``advance_to(t + dt)`` call, as the daemon makes it at every control step.
Targets (issue 3): at most 10 us per 17-node exact step, at most 1 ms per 10,000-node step.

    .venv/bin/python benchmarks/bench_model.py [--quick]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, write_results
from daemon.model import (
    Segment,
    Stepper,
    ThermalModel,
    ThermalNetwork,
    build_geometry_network,
    load_network,
    material,
    positivity_bound_s,
)

TARGET_17_EXACT_US = 10.0
TARGET_10000_US = 1000.0


def chain(nodes: int) -> ThermalNetwork:
    """A 635 mm aluminium bar (the two-link system's length) cut into ``nodes`` nodes."""
    segment = Segment(635.0, 25.4, 6.35, material("6061-T6"), 635.0 / (nodes - 1), 2.5)
    return build_geometry_network(f"chain-{nodes}", [segment])


def time_steps(
    network: ThermalNetwork, stepper: Stepper, dt_s: float, steps: int, repeats: int
) -> dict[str, Any]:
    started = time.perf_counter()
    model = ThermalModel(network, stepper, dt_s)
    setup_s = time.perf_counter() - started
    model.set_heat({network.heater_nodes[0] if network.heater_nodes else "1": 1.0})
    model.advance_to(dt_s)  # warm caches
    per_step = []
    for _ in range(repeats):
        start_t = model.time_s
        started = time.perf_counter()
        for k in range(1, steps + 1):
            model.advance_to(start_t + k * dt_s)
        per_step.append((time.perf_counter() - started) / steps)
    return {
        "network": network.name,
        "nodes": network.node_count,
        "stepper": stepper,
        "dt_s": dt_s,
        "setup_ms": setup_s * 1e3,
        "us_per_step": statistics.median(per_step) * 1e6,
        "best_us_per_step": min(per_step) * 1e6,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps and repeats")
    args = parser.parse_args()
    scale = 0.1 if args.quick else 1.0
    repeats = 3 if args.quick else 5

    preset = load_network("thesis-two-link")
    chain_1000, chain_10000 = chain(1000), chain(10000)
    cases: list[tuple[ThermalNetwork, Stepper, float, int, float | None]] = [
        (preset, "exact", 1.0, 20000, TARGET_17_EXACT_US),
        (preset, "explicit", 1.0, 20000, None),
        (preset, "implicit", 1.0, 20000, None),
        (chain_1000, "exact", 1.0, 2000, None),
        (chain_1000, "explicit", positivity_bound_s(chain_1000), 2000, None),
        (chain_1000, "implicit", 1.0, 2000, None),
        (chain_10000, "implicit", 1.0, 1000, TARGET_10000_US),
        (chain_10000, "explicit", positivity_bound_s(chain_10000), 1000, TARGET_10000_US),
    ]
    results = []
    for network, stepper, dt_s, steps, target in cases:
        result = time_steps(network, stepper, dt_s, max(10, int(steps * scale)), repeats)
        result["target_us"] = target
        result["meets_target"] = None if target is None else result["us_per_step"] <= target
        results.append(result)

    print_table(
        ["network", "nodes", "stepper", "dt (s)", "setup (ms)", "us/step", "best", "target"],
        [
            [
                r["network"],
                r["nodes"],
                r["stepper"],
                r["dt_s"],
                r["setup_ms"],
                r["us_per_step"],
                r["best_us_per_step"],
                "-"
                if r["target_us"] is None
                else f"<= {r['target_us']:g} " + ("ok" if r["meets_target"] else "MISSED"),
            ]
            for r in results
        ],
    )
    write_results("bench_model", {"quick": args.quick, "cases": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
