"""Where a controller given every true factor still misses: the truth's model and the
controller's compared piece by piece (issue 29, the cold-draughty-room B bias).

The truth (drivers/sim/arm_bench.py) is run once along the task, noise-free: at each
measurement time of benchmarks/arm_replay.py the true tool drift at the station (the true warm
arm against the true cold arm), the heat the truth's motors really gave over each of its steps,
and the air. Then a model is stepped along the same times, built from the truth's pieces, and
the pieces are swapped one at a time for the controller's (``--swap``):

- ``heat``: the controller's motor model for the task (times the truth's heat factors) instead
  of the truth's own heat per truth step;
- ``room``: the room thermometer's readings, held as the controller holds them (the mean of
  the readings at an advance's two ends), instead of the air itself;
- ``grid``: the controller's advances (one per measurement) instead of the truth's 2-s steps;
- ``spacing``: the controller's node spacing (50 mm) instead of the truth's 10 mm;
- ``geometry``: the nominal arm (kinematics and thermal description) instead of the true one;
- ``linearised``: the radiation linearised at the configured ambient (model.ambient_c), as
  the controller did before it linearised at the room the run starts in (ArmThermalModel
  ``start_at``), instead of at that room.

Last, the daemon's own controller (daemon/arm/controller.py) given the truth's factors and the
room thermometer, and with ``--meter`` the bench's meter (benchmarks/arm_replay.py
``simulate``, the scenario benchmark's noise seed) against the true drift: its 4-frame cold
reference's error stays in every later measurement of the pose.

The piece whose swap opens the gap is where the controller's model departs from the truth.

    .venv/bin/python benchmarks/bench_arm_bisect.py --scenario cold-draughty-room --task B
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from numpy.typing import ArrayLike

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.arm_replay import bench_settings, measurement_schedule, simulate
from benchmarks.bench_arm_scenarios import ARMS, NOISE, TASKS
from config.arm_truth import TRUTHS_DIR
from daemon.arm import kinematics
from daemon.arm.arm_model import ArmModel
from daemon.arm.controller import ArmModelOptions
from daemon.arm.controller_loading import load_controller
from daemon.arm.thermal import ArmThermalModel
from daemon.commands.arm_identify import IDENTIFY_STEP_S
from daemon.run.arm.setup import arm_file
from drivers.sim.arm_bench import ArmBench
from drivers.sim.arm_devices import bench_config
from drivers.sim.arm_motion import DutyCycleMotion
from drivers.sim.arm_physics import true_description

PIECES = ("heat", "room", "grid", "spacing", "geometry", "linearised")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="cold-draughty-room")
    parser.add_argument("--task", default="B", choices=tuple(TASKS))
    parser.add_argument("--arm", default="a465", choices=sorted(ARMS), help="the arm and its tasks")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--hours", type=float, default=8.0)
    parser.add_argument("--every", type=float, default=240.0)
    parser.add_argument(
        "--meter", action="store_true", help="and the meter's run (its noise) against the truth"
    )
    args = parser.parse_args(argv)
    truth_path = str(TRUTHS_DIR / f"{args.scenario}.toml")
    arm_name, cycles = ARMS[args.arm]
    cycle = cycles[args.task]
    with tempfile.TemporaryDirectory(prefix="bench-arm-bisect-") as folder:
        settings = bench_settings(truth_path, cycle, args.seed, Path(folder), arm=arm_name)
    options = ArmModelOptions(
        motion_dt_s=settings.arm.motion_dt_s,
        ambient_c=settings.model.ambient_c,
        bending=True,
        motor_side_share=settings.arm.motor_side_share,
        model_dt_s=IDENTIFY_STEP_S,
    )
    controller = load_controller(arm_file(settings), cycle, options)
    duty = controller.duty
    config = bench_config(settings, controller.arm, duty, settings.bench.seed)
    config = dataclasses.replace(config, payload_kg=duty.payload_kg)
    bench = ArmBench(config, DutyCycleMotion(duty), arm=controller.arm)
    station = {pose.name: k for k, pose in enumerate(duty.measured_poses())}

    # the truth, noise-free, its heat per truth step recorded
    steps: list[tuple[float, np.ndarray]] = []
    advance = bench.thermal.advance_to

    def recording(t_s: float, watts: ArrayLike | None = None) -> None:
        steps.append((t_s, np.asarray(watts, dtype=np.float64)))
        advance(t_s, watts)

    bench.thermal.advance_to = recording  # type: ignore[method-assign,assignment]
    schedule = measurement_schedule(duty, args.hours * 3600.0, args.every)
    room_start = bench.room_read()
    times, drift, rooms, qs = [], [], [], []
    for t, name in schedule:
        bench.advance_to(t)
        rooms.append(bench.room_read())
        q = bench.stations_q_rad[station[name]]
        drift.append(bench.tool_pose_true(q)[:3, 3] - bench.tool_pose_cold(q)[:3, 3])
        times.append(t)
        qs.append(q)
    drift_mm = np.array(drift)
    heat_truth_w = np.array([w for _, w in steps])
    heat_times = np.array([t for t, _ in steps])
    truth_step = config.truth_step_s
    scales = np.asarray(bench.heat_scales)
    ratio = heat_truth_w.sum(axis=0) / np.maximum(
        np.array([controller.mean_heat_w(t - truth_step, t) for t in heat_times]).sum(axis=0),
        1e-12,
    )
    print(
        f"{args.scenario} task {args.task}: drift RMS "
        f"{1000 * math.sqrt(float(np.mean(np.sum(drift_mm**2, axis=1)))):.1f} um; "
        f"truth heat / model heat {np.round(ratio, 3).tolist()}; truth factors "
        f"{np.round(scales, 3).tolist()}"
    )

    def play(swapped: frozenset[str]) -> np.ndarray:
        arm = controller.arm if "geometry" in swapped else bench.true_arm
        description = true_description(
            arm, config.alpha_scale, config.capacity_scale, config.plus_share
        )
        start_c = room_start if "room" in swapped else bench.ambient_c(0.0)
        linearised = "linearised" in swapped
        model = ArmThermalModel(
            description,
            node_spacing_mm=50.0 if "spacing" in swapped else config.node_spacing_mm,
            ambient_c=settings.model.ambient_c if linearised else start_c,
            dt_s=IDENTIFY_STEP_S if "grid" in swapped else truth_step,
            convection_scale=config.convection_scale,
            initial_c=start_c if linearised else None,
            reference_c=start_c if linearised else None,
            across_link=True,
        )
        if linearised:  # the controller before it linearised at the room (start_at)
            model.set_ambient(start_c)
        else:
            model.start_at(start_c)
        out = np.zeros_like(drift_mm)
        last_room = room_start
        k_heat = 0
        now = 0.0
        for m, t in enumerate(times):
            if "grid" in swapped:
                edges = [t]
            else:
                edges = []
                while k_heat < len(heat_times) and heat_times[k_heat] <= t + 1e-9:
                    edges.append(float(heat_times[k_heat]))
                    k_heat += 1
            room_hold = 0.5 * (last_room + rooms[m])
            for edge in edges:
                if edge <= now:
                    continue
                if "heat" in swapped:
                    watts = controller.mean_heat_w(now, edge) * scales
                elif "grid" in swapped:
                    sel = (heat_times > now + 1e-9) & (heat_times <= edge + 1e-9)
                    watts = heat_truth_w[sel].mean(axis=0) if sel.any() else np.zeros(6)
                else:
                    watts = heat_truth_w[np.searchsorted(heat_times, edge - 1e-9)]
                model.set_ambient(room_hold if "room" in swapped else bench.ambient_c(now))
                model.advance_to(edge, watts)
                now = edge
            last_room = rooms[m]
            states = model.link_states()
            out[m] = kinematics.tool_error(arm, qs[m], states, bending=True).translation_mm
        return out

    def daemon() -> np.ndarray:
        """The daemon's own controller given the truth's factors, following the room."""
        model = ArmModel(
            "truth", controller.arm.name, tuple(float(h) for h in scales),
            alpha_scale=config.alpha_scale, convection_scale=config.convection_scale,
            capacity_scale=config.capacity_scale,
            bending_shares=(config.plus_share,) * len(scales),
        )  # fmt: skip
        played = load_controller(arm_file(settings), cycle, options, model)
        played.follow_room(room_start)
        out = np.zeros_like(drift_mm)
        for m, t in enumerate(times):
            played.follow_room(rooms[m])
            played.advance_to(t)
            q = bench.stations_q_rad[station[schedule[m][1]]]
            out[m] = kinematics.tool_error(
                controller.arm, q, played.link_states(), bending=True
            ).translation_mm
        return out

    variants: list[tuple[str, frozenset[str]]] = [("truth's pieces", frozenset())]
    variants += [(f"controller's {p}", frozenset({p})) for p in PIECES]
    variants += [("all the controller's now", frozenset(PIECES) - {"linearised"})]
    variants += [("all the controller's before", frozenset(PIECES))]
    third = len(times) // 3
    for label, swapped in [*variants, ("the daemon's controller", frozenset({"daemon"}))]:
        residual = drift_mm - (daemon() if "daemon" in swapped else play(swapped))
        rms = 1000 * math.sqrt(float(np.mean(np.sum(residual**2, axis=1))))
        last = 1000 * residual[-third:].mean(axis=0)
        print(
            f"  {label:28s} residual RMS {rms:6.2f} um; mean over the last third "
            f"{np.round(last, 2).tolist()} um"
        )
    if args.meter:
        run = simulate(
            settings, cycle, args.seed + NOISE[args.task], args.hours * 3600.0,
            args.every,
        )  # fmt: skip
        if run.time_s.shape != np.asarray(times).shape or not np.allclose(run.time_s, times):
            raise SystemExit("the meter's run was measured at other times")
        error = run.displacement_mm - drift_mm
        rms = 1000 * math.sqrt(float(np.mean(np.sum(error**2, axis=1))))
        print(
            f"  the meter against the true drift: RMS {rms:.2f} um (its 1-sigma "
            f"{run.meter_sigma_um:.2f} um); mean {np.round(1000 * error.mean(axis=0), 2).tolist()}"
            f" um, over the first third {np.round(1000 * error[:third].mean(axis=0), 2).tolist()}"
            f", the last {np.round(1000 * error[-third:].mean(axis=0), 2).tolist()} um"
        )
        for s_index in sorted(set(run.pose_index.tolist())):
            rows = run.pose_index == s_index
            print(
                f"    pose {s_index}: {int(rows.sum())} measurements, mean error "
                f"{np.round(1000 * error[rows].mean(axis=0), 2).tolist()} um, scatter "
                f"{np.round(1000 * error[rows].std(axis=0), 2).tolist()} um"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
