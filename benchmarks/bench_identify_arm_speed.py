"""Issue 29: the arm's identification speed (old finite-difference method against the new one,
same run, same answers), and what the calibration program makes identifiable where the
pick-and-place cycle does not, and how a model transfers to the other cycle.

Each cycle is simulated for 8 hours on the arm bench's truth (drivers.sim.arm_bench, in
process, virtual time; the tool measured through rendered markers and three cameras per
station every ``--measure-every`` seconds, the IR regions of benchmarks/bench_arm.py). The
truth is the bench's default or, with ``--truth``, a varied one built through ArmBenchConfig's
own parameters (heat_scales, convection_scale, alpha_scale, capacity_scale, plus_share): the
lead can connect these to the truth file of the arm-truth branch.

Transfer: each identified model predicts the OTHER cycle's measured thermal displacement,
nothing refitted (daemon.arm.identify.evaluate_arm); "removed" is 1 - RMS(prediction error) /
RMS(displacement): what a compensation by that prediction would remove of the drift.

    .venv/bin/python benchmarks/bench_identify_arm_speed.py [--hours 8] [--truth default|varied]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.bench_arm import IDENTIFY_STEP_S, IR_REGIONS, Controller, region_nodes
from benchmarks.common import print_table, write_results
from daemon.arm.arm_network import describe_arm
from daemon.arm.calibration_program import program_for_task
from daemon.arm.duty import DutyCycle, load_duty_cycle
from daemon.arm.identify import (
    ArmModelSpec,
    ArmRunData,
    evaluate_arm,
    identify_arm,
    marker_sensitivity,
)
from daemon.arm.identify_final import identify_arm_final
from daemon.arm.identify_parameters import apply_values, parse_parameters
from daemon.arm.response import responses
from daemon.model.identify import LOSS, LOSS_SCALE, rms
from drivers.sim.arm_bench import ArmBench, ArmBenchConfig
from drivers.sim.arm_motion import DutyCycleMotion

TASK = "a465-pick-and-place"
#: The controller's belief of the bending share (config/arm-sim.toml motor_side_share).
BELIEVED_SHARE = 0.75
VARIED = {
    "heat_scales": (1.8, 0.6, 1.9, 0.7, 1.5, 0.6),
    "convection_scale": 1.35,
    "alpha_scale": 0.92,
    "capacity_scale": 0.75,
    "plus_share": 0.6,
}


def simulate(config: ArmBenchConfig, duty: DutyCycle, names: list[str], hours: float,
             every_s: float) -> tuple[ArmRunData, ArmModelSpec]:  # fmt: skip
    """An uncompensated run of ``duty`` measured at its stations (by name, ``names`` the
    task's order) every ``every_s`` at least."""
    motion = DutyCycleMotion(duty)
    bench = ArmBench(config, motion)
    station_of = {name: k for k, name in enumerate(names)}
    cold = [bench.measure_tool(s, q).points_mm for s, q in enumerate(bench.stations_q_rad)]
    controller = Controller(bench, motion)  # its motor model's heat
    steps = math.floor(hours * 3600.0 / IDENTIFY_STEP_S)
    heat = np.array([controller.energy.mean_power_w(k * IDENTIFY_STEP_S,
                                                    (k + 1) * IDENTIFY_STEP_S)
                     for k in range(steps)])  # fmt: skip
    arrivals = duty.arrival_times_s()
    visits = [
        (arrivals[k] + p.dwell_s / 2.0, p.name) for k, p in enumerate(duty.poses) if p.measure
    ]
    times, poses, markers = [], [], []
    regions: dict[str, list[float]] = {name: [] for name, _, _ in IR_REGIONS}
    last, cycle = -math.inf, 0
    while True:
        for offset, name in visits:
            t = cycle * duty.period_s + offset
            if t > (steps - 1) * IDENTIFY_STEP_S:
                break
            if t - last < every_s:
                continue
            last = t
            bench.advance_to(t)
            station = station_of[name]
            measured = bench.measure_tool(station, bench.stations_q_rad[station])
            reading = bench.ir_read()
            times.append(round(t / IDENTIFY_STEP_S) * IDENTIFY_STEP_S)
            poses.append(station)
            markers.append(measured.points_mm - cold[station])
            for region, values in regions.items():
                values.append(reading[region])
        else:
            cycle += 1
            continue
        break
    spec = ArmModelSpec(
        description=describe_arm(bench.nominal_arm, plus_share=BELIEVED_SHARE),
        node_spacing_mm=controller.model.node_spacing_mm,
        regions=region_nodes(controller.model, IR_REGIONS),
        sensitivities=[
            marker_sensitivity(bench.nominal_arm, q, bench.markers_tool_mm, True)
            for q in bench.stations_q_rad
        ],
        across_link=True,
    )
    run = ArmRunData(IDENTIFY_STEP_S, heat, np.full(steps, config.ambient_c), np.array(times),
                     np.array(poses, dtype=np.intp), np.array(markers),
                     {name: np.array(v) for name, v in regions.items()})  # fmt: skip
    return run, spec


def old_identify(run: ArmRunData, spec: ArmModelSpec, names: list[str]) -> tuple[np.ndarray, int]:
    """main's method (before issue 29): least_squares by finite differences of whole
    simulations (responses() at every new convection), two passes; the fitted vector and the
    number of simulations."""
    specs = parse_parameters(names, 6, spec.regions)
    regions = [r for r in spec.regions if r in run.region_c]
    cache: dict[float, Any] = {}
    sens = np.stack([spec.sensitivities[int(p)] for p in run.pose_index])
    measured = run.marker_displacement_mm.reshape(run.time_s.size, -1)
    alphas = np.array([link.alpha_per_c for link in spec.description.links])
    sigma = [0.005, 0.1]

    def residuals(values: np.ndarray) -> np.ndarray:
        scales = apply_values(specs, values, 6, regions)
        key = round(math.log(scales.convection), 12)
        if key not in cache:
            cache[key] = responses(spec.description, spec.node_spacing_mm, scales.convection,
                                   run, True)  # fmt: skip
        response = cache[key]
        temperatures = response.ambient + np.einsum("j,jkn->kn", scales.heat, response.per_joint)
        rise = temperatures - response.reference_c
        strains = rise @ response.link_rows.T * alphas * scales.alpha
        bends = (rise @ response.gradient_rows.T).reshape(rise.shape[0], -1, 2)
        strains = np.concatenate([strains[:, :, None], bends * alphas[None, :, None]
                                  * scales.alpha], axis=2).reshape(rise.shape[0], -1)  # fmt: skip
        markers = np.einsum("kml,kl->km", sens, strains) - measured
        ir = [temperatures[:, list(spec.regions[r])].mean(axis=1) + scales.offsets_c[r]
              - run.region_c[r] for r in regions]  # fmt: skip
        return np.concatenate([markers.ravel() / sigma[0], np.concatenate(ir) / sigma[1]])

    values = np.zeros(len(specs))
    bounds = ([s.bounds[0] for s in specs], [s.bounds[1] for s in specs])
    for _ in range(2):
        result = least_squares(residuals, values, bounds=bounds, loss=LOSS, f_scale=LOSS_SCALE,
                               x_scale=1.0, diff_step=1e-6, max_nfev=100 * len(specs))  # fmt: skip
        values = result.x
        r = residuals(values)
        markers = r[: measured.size] * sigma[0]
        sigma = [max(float(rms(markers) or 0.005), 1e-6),
                 max(float(rms(r[measured.size:] * sigma[1]) or 0.1), 1e-4)]  # fmt: skip
    return values, len(cache)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=8.0)
    parser.add_argument("--measure-every", type=float, default=120.0)
    parser.add_argument("--truth", choices=["default", "varied"], default="default")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    task = load_duty_cycle(TASK)
    arm = ArmBench(ArmBenchConfig(arm=task.arm)).nominal_arm
    program = program_for_task(arm, task, task.arm, "a465-calibration")
    names = [p.name for p in task.measured_poses()]
    config = ArmBenchConfig(
        seed=args.seed,
        noise_seed=args.seed + 1000,
        arm=task.arm,
        stations_q_rad=tuple(tuple(p.q_rad) for p in task.measured_poses()),
        ir_regions=IR_REGIONS,
        payload_kg=task.payload_kg,
        **(VARIED if args.truth == "varied" else {}),
    )  # type: ignore[arg-type]
    started = time.perf_counter()
    runs = {
        "pick-and-place": simulate(config, task, names, args.hours, args.measure_every),
        "program": simulate(config, program, names, args.hours, args.measure_every),
    }
    simulated_s = time.perf_counter() - started
    # 1. speed: old against new on the pick-and-place run, main's parameter list
    run, spec = runs["pick-and-place"]
    old_names = [*(f"heat:{j + 1}" for j in range(6)), "convection", "alpha",
                 *(f"offset:{r}" for r, _, _ in IR_REGIONS)]  # fmt: skip
    t0, c0 = time.perf_counter(), time.process_time()
    old_values, old_passes = old_identify(run, spec, old_names)
    old_wall, old_cpu = time.perf_counter() - t0, time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    new = identify_arm(run, spec, old_names)
    new_wall, new_cpu = time.perf_counter() - t0, time.process_time() - c0
    specs = parse_parameters(old_names, 6, spec.regions)
    agree = [
        (s.name, s.value(o), s.value(n))
        for s, o, n in zip(specs, old_values, new.values, strict=True)
    ]
    print(f"identification of {run.time_s.size} measurements, {args.hours:g} h, 12 parameters:")
    print_table(["method", "wall s", "CPU s", "network passes"],
                [["old (finite differences)", old_wall, old_cpu, old_passes],
                 ["new (analytic + projected)", new_wall, new_cpu, new.evaluations],
                 ["ratio old/new", old_wall / new_wall, old_cpu / new_cpu, ""]])  # fmt: skip
    print_table(["parameter", "old", "new"], [list(a) for a in agree])
    # 2. identifiability and 3. transfer, the full default parameter list (capacity, share)
    rows, document = [], {}
    for label, (cal_run, cal_spec) in runs.items():
        t0 = time.perf_counter()
        calibration = identify_arm_final(cal_run, cal_spec)
        wall = time.perf_counter() - t0
        full = calibration.full
        assert full is not None and calibration.final is not None
        index = {p.name: k for k, p in enumerate(full.parameters)}
        corr = abs(full.correlation[index["heat:2"], index["heat:3"]])
        other_label = "program" if label == "pick-and-place" else "pick-and-place"
        other_run, other_spec = runs[other_label]
        drift = rms(other_run.marker_displacement_mm.reshape(-1)) or math.nan
        transfer = evaluate_arm(calibration.final, other_run, other_spec).marker_rms_mm
        preset = evaluate_arm(None, other_run, other_spec).marker_rms_mm
        missing = ", ".join(calibration.not_identified) or "-"
        rows.append([label, wall, len(calibration.identified), missing,
                     max((p.relative_error or 0.0) for p in calibration.final.parameters),
                     corr, 1000 * drift, 1000 * (transfer or math.nan),
                     f"{100 * (1 - (transfer or math.nan) / drift):.1f} %",
                     f"{100 * (1 - (preset or math.nan) / drift):.1f} %"])  # fmt: skip
        document[label] = {"wall_s": wall, "not_identified": calibration.dropped,
                           "parameters": [dataclasses.asdict(p) for p in calibration.parameters()],
                           "corr_heat2_heat3_first_fit": corr,
                           "transfer_rms_um": 1000 * (transfer or math.nan),
                           "other_drift_rms_um": 1000 * drift,
                           "preset_rms_um": 1000 * (preset or math.nan)}  # fmt: skip
        print(f"\n{label}: final fit")
        print_table(["parameter", "value", "SE", "rel.", "identified", "why not"],
                    [[p.name, p.value, p.standard_error, p.relative_error, p.identifiable,
                      p.reason or "-"] for p in calibration.parameters()])  # fmt: skip
    print(f"\ntruth {args.truth}: {VARIED if args.truth == 'varied' else 'bench default'}")
    print_table(["calibrated on", "identify s", "identified", "not identified", "max rel. SE",
                 "|corr heat:2,3| first fit", "other cycle drift um", "its prediction err um",
                 "removed", "preset removed"], rows)  # fmt: skip
    load = os.getloadavg()
    print(f"simulation {simulated_s:.0f} s; load {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    write_results(f"bench_identify_arm_speed_{args.truth}", {
        "hours": args.hours, "speed": {"old_wall_s": old_wall, "old_cpu_s": old_cpu,
                                       "new_wall_s": new_wall, "new_cpu_s": new_cpu,
                                       "old_passes": old_passes, "new_passes": new.evaluations,
                                       "agreement": agree},
        "cycles": document, "load_average": list(load)})  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
