"""Why a controller misses on a truth: issue 29's method. The controller's model is given the
truth's factors one at a time (each joint's heat, the expansion, the convection, the joints'
capacity, the bending share) and then all together, on one scenario x task, and the share of
the drift removed is printed for each: the factor whose true value closes the gap is the cause.

    .venv/bin/python benchmarks/bench_arm_factors.py --scenario corner-low --task B \
        [--base preset+room+ir] [--hours 8] [--every 240] [--cache DIR]

The base is a controller of benchmarks/bench_arm_scenarios.py (``preset+room+ir``,
``preset+room``, ``identified+room``, ``other-cycle+room``); its model's factors (the preset's
1.0 or the identified ones) are replaced by the truth's. The truth's heat factors are the
ratios of the true motors' heat to the controller's motor model for the task (the truth scales
winding resistance and friction, so the ratio is close to the truth's factor, not equal).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pickle
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.arm_replay import (
    SimulatedRun,
    bench_settings,
    calibrate,
    calibration_program,
    plan_for,
    replay,
    residual_figures,
    simulate,
)
from benchmarks.bench_arm_scenarios import NOISE, TASKS
from config.arm_truth import TRUTHS_DIR, load_arm_truth
from daemon.arm.arm_model import ArmModel, arm_model_toml, new_arm_model_path

FACTORS = ("heat", "expansion", "convection", "capacity", "share")


def cached_run(
    cache: Path, settings: Any, label: str, cycle: str, seed: int, *, hours: float, every: float
) -> SimulatedRun:
    path = cache / f"{label}-{seed}-{hours:g}-{every:g}.pickle"
    if path.exists():
        run: SimulatedRun = pickle.loads(path.read_bytes())
        return run
    run = simulate(settings, cycle, seed, hours * 3600.0, every)
    path.write_bytes(pickle.dumps(run))
    return run


def true_factors(truth: Any, settings: Any) -> dict[str, Any]:
    """The truth's factors in the controller's terms (module docstring)."""
    from daemon.arm.controller import ArmModelOptions
    from daemon.arm.controller_loading import load_controller
    from daemon.run.arm.setup import arm_file
    from drivers.sim.arm_devices import bench_config  # lazy: a benchmark's own tool

    options = ArmModelOptions(bending=True, motor_side_share=settings.arm.motor_side_share)
    controller = load_controller(arm_file(settings), settings.arm.duty_cycle, options)
    config = bench_config(settings, controller.arm, controller.duty, settings.bench.seed)
    heats = config.heat_scales
    if heats is None:  # drawn from the truth's seed as the bench draws them
        from drivers.sim.arm_bench import ArmBench  # lazy: as above

        heats = tuple(float(h) for h in ArmBench(config, arm=controller.arm).heat_scales)
    return {
        "heat": tuple(float(h) for h in heats),
        "expansion": config.alpha_scale,
        "convection": config.convection_scale,
        "capacity": config.capacity_scale,
        "share": config.plus_share,
    }


def with_factors(base: ArmModel, truth: dict[str, Any], names: Sequence[str]) -> ArmModel:
    changes: dict[str, Any] = {}
    joints = len(base.heat_scales)
    for name in names:
        if name == "heat":
            changes["heat_scales"] = truth["heat"]
        elif name == "expansion":
            changes["alpha_scale"] = truth["expansion"]
        elif name == "convection":
            changes["convection_scale"] = truth["convection"]
        elif name == "capacity":
            changes["capacity_scale"] = truth["capacity"]
        elif name == "share":
            changes["bending_shares"] = (truth["share"],) * joints
    return dataclasses.replace(base, **changes)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", required=True)
    parser.add_argument("--task", default="B", choices=tuple(TASKS))
    parser.add_argument("--base", default="preset+room+ir")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--hours", type=float, default=8.0)
    parser.add_argument("--every", type=float, default=240.0)
    parser.add_argument("--cache", default=None, help="folder keeping the simulated runs")
    parser.add_argument("--base-only", action="store_true", help="the base controller alone")
    args = parser.parse_args(argv)
    truth_path = (
        args.scenario if "/" in args.scenario else str(TRUTHS_DIR / f"{args.scenario}.toml")
    )
    load_arm_truth(truth_path)
    cache = Path(args.cache or tempfile.mkdtemp(prefix="arm-factors-")) / Path(truth_path).stem
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="bench-arm-factors-") as folder:
        data_dir = Path(folder)
        settings = bench_settings(truth_path, TASKS[args.task], args.seed, data_dir)
        seed = args.seed  # the noise seeds as bench_arm_scenarios.py draws them
        run = cached_run(
            cache, settings, args.task, TASKS[args.task], seed + NOISE[args.task],
            hours=args.hours, every=args.every,
        )  # fmt: skip
        truth = true_factors(load_arm_truth(truth_path), settings)
        ir = args.base.endswith("+ir")
        room = "+room" in args.base
        if args.base.startswith("identified") or args.base.startswith("other"):
            label = "program" if args.base.startswith("identified") else (
                "B" if args.task == "A" else "A"
            )  # fmt: skip
            cycle = (
                calibration_program(settings, TASKS["A"], data_dir)
                if label == "program"
                else TASKS[label]
            )
            source = cached_run(
                cache,
                settings,
                label,
                cycle,
                seed + NOISE[label],
                hours=args.hours,
                every=args.every,
            )
            base, _ = calibrate(settings, source, "base")
        else:
            base = ArmModel("base", run.arm, (1.0,) * 6)
            if not base.bending_shares:
                base = dataclasses.replace(
                    base, bending_shares=(settings.arm.motor_side_share,) * 6
                )
        print(f"{args.scenario} task {args.task}, base {args.base}; truth {truth}")
        print(
            f"base model: heats {np.round(base.heat_scales, 3).tolist()} alpha "
            f"{base.alpha_scale:.3f} conv {base.convection_scale:.3f} capacity "
            f"{base.capacity_scale:.3f} shares {np.round(base.bending_shares, 3).tolist()}"
        )
        variants: list[tuple[str, list[str]]] = [("base", [])]
        variants += [(f"true {f}", [f]) for f in FACTORS]
        variants += [(f"all true but {f}", [g for g in FACTORS if g != f]) for f in FACTORS]
        variants += [("all true", list(FACTORS))]
        if args.base_only:
            variants = variants[:1]
        for k, (label, names) in enumerate(variants):
            model = with_factors(base, truth, names)
            name = f"variant-{k}"
            path = new_arm_model_path(name, settings.storage.data_dir)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(arm_model_toml(dataclasses.replace(model, name=name)), "utf-8")
            plan = plan_for(settings, TASKS[args.task], arm_model=name, ir=ir, adapt=False)
            played = replay(plan, run, room=room)
            f = residual_figures(run, played["predicted_mm"])
            print(
                f"  {label:28s} {f['rms_3d_um']:7.1f} um {100 * f['removed']:6.1f} % "
                f"{f['rms_over_sigma']:5.2f} sigma (drift {f['drift_rms_3d_um']:.1f} um)"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
