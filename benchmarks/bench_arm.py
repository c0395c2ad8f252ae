"""Issue 20's targets on the simulated arm bench, in process and in virtual time (no daemon).

An A465 runs its pick-and-place duty cycle (config/duty/a465-pick-and-place.toml) for 8 hours
from a cold start; its motors heat its links; at each measured pose of the cycle (its stations)
three cameras measure the tool's four markers every ``--measure-every`` seconds, and an IR
camera reads regions on several links. The bench's truth (drivers.sim.arm_bench) is not the
controller's preset: its DH table (seeded errors of 0.2 mm / 0.2 mrad), a 10 mm thermal network
(the controller's: 50 mm), convection x0.8, alpha x1.05, joint heat capacities x1.1, each
motor's heat x[0.75, 1.25], IR offsets of 0.3 degC (1-sigma).

Three controllers watch the same 8-hour truth at the same instants (a paired comparison: the
corrections, micrometres, change the motors' torques and so their heat by far less than 1e-4),
each measured with its own camera noise:

(a) none: the taught poses as taught; the residual is the drift;
(b) the preset: the controller's ArmThermalModel fed with its motor model's heat for the
    commanded motion, ``kinematics.tool_error`` at each measured pose, the correction ``-error``
    applied to the commanded pose (one Gauss-Newton step of the nominal arm's inverse
    kinematics: exact to far below a nanometre for micrometre corrections);
(c) identified + observer: heat per motor, convection, alpha and the IR offsets identified
    (daemon.arm.identify) from a SEPARATE 4-hour calibration cycle without compensation (the
    same arm, other noise), then daemon.model.observer's Kalman filter on the identified
    model's nodes fusing the IR regions at every measurement.

Each residual is measured as the daemon would: markers rendered, centroids, triangulation,
the tool's pose fitted to them (daemon.vision.multiview), relative to the cold pose measured at
the start (ten frames averaged). The 3-D measurement noise is measured the same way on the
still, cold arm (100 frames). Also reported: the true residuals (the truth's own poses).

Targets (issue 20): (a) >= 100 um (3-D); (b) >= 80 % of (a) removed (RMS over the run);
(c) RMS <= 2x the 3-D measurement noise and >= 95 % removed; the rotation error the same way;
the 8-hour run in <= 5 min of wall time.

    .venv/bin/python benchmarks/bench_arm.py [--quick] [--seed N] [--measure-every S]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# One BLAS thread: the matrices here are tens of nodes, and on a loaded 2-core machine a
# threaded eigh of 38 x 38 took 30 ms instead of 0.2 ms. Set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.common import print_table, write_results
from daemon.arm import kinematics
from daemon.arm.description import Arm
from daemon.arm.duty import DutyCycle, load_duty_cycle
from daemon.arm.identify import (
    ArmIdentification,
    ArmModelSpec,
    ArmRunData,
    ArmScales,
    identify_arm,
    marker_sensitivity,
)
from daemon.arm.thermal import ArmThermalModel, describe_arm
from daemon.arm.types import FloatArray, Pose6
from daemon.model.observer import IrObserver
from daemon.vision.multiview import pose_difference, rigid_pose_from_markers
from drivers.sim.arm_bench import ArmBench, ArmBenchConfig
from drivers.sim.arm_motion import DutyCycleMotion, MotorEnergy
from drivers.sim.arm_physics import motion_power, motion_power_batch

DUTY = "a465-pick-and-place"
HOURS = 3600.0
#: Where the IR camera looks: (region, link, fraction along the link from its proximal joint).
IR_REGIONS = (
    ("turret", "turret", 0.5),
    ("upper-arm-root", "upper-arm", 0.2),
    ("upper-arm-tip", "upper-arm", 0.8),
    ("forearm", "forearm", 0.5),
)
#: The controllers' models resolve the temperature across each link and bend it, as the truth
#: (where each motor housing sits, ``plus_share``, is the arm's design: known to both).
ACROSS_LINK = True
#: The controllers' models advance on this grid with the mean motor heat over each step.
CONTROL_STEP_S = 5.0
#: The calibration cycle's heat record, for identification: mean heat over steps of this length
#: (the links' time constants are tens of minutes; a measurement's time is rounded to it).
IDENTIFY_STEP_S = 20.0
#: Frames averaged for the cold reference of each station; frames of the noise measurement.
REFERENCE_FRAMES = 10
NOISE_FRAMES = 100
#: The observer: IR noise it assumes (degC), the prior of the identified offsets (degC).
OBSERVER_IR_NOISE_C = 0.05
OBSERVER_OFFSET_SIGMA_C = 0.2


def commanded_q(arm: Arm, q: FloatArray, correction: Pose6) -> FloatArray:
    """The joints that move the nominal arm's tool by ``correction`` from its pose at ``q``."""
    jac = np.asarray(kinematics.jacobian(arm, q), dtype=np.float64)
    step, *_ = np.linalg.lstsq(jac, correction.as_array(), rcond=None)
    result: FloatArray = q + step
    return result


def region_nodes(
    model: ArmThermalModel, regions: Sequence[tuple[str, str, float]]
) -> dict[str, tuple[int, ...]]:
    """The controller's nodes nearest each IR region's point (both rows of a link modelled
    across its section: the region sees their mean)."""
    nodes: dict[str, tuple[int, ...]] = {}
    positions = model.network.positions_mm
    for name, link, fraction in regions:
        indices = np.asarray(model.link_node_indices(link), dtype=np.intp)
        along = positions[indices]
        point = along[0] + fraction * (along[-1] - along[0])
        distance = np.abs(along - point)
        nodes[name] = tuple(int(i) for i in indices[distance <= distance.min() + 1e-9])
    return nodes


class Controller:
    """The controller's arm model (preset or identified), fed with its own motor model's heat
    for the commanded motion, optionally corrected from the IR regions."""

    def __init__(
        self,
        bench: ArmBench,
        motion: DutyCycleMotion,
        scales: ArmScales | None = None,
        observe: bool = False,
    ) -> None:
        arm = bench.nominal_arm
        self.arm = arm
        self.scales = scales
        self.model = ArmThermalModel(
            describe_arm(arm, plus_share=bench.config.plus_share),
            ambient_c=bench.ambient_c,  # a room thermometer reads the air the arm is in
            dt_s=CONTROL_STEP_S,
            convection_scale=1.0 if scales is None else scales.convection,
            across_link=ACROSS_LINK,
        )
        self.heat = np.ones(arm.dof) if scales is None else scales.heat
        self.alpha = 1.0 if scales is None else scales.alpha
        self.energy = MotorEnergy(
            motion,
            motion_power(arm, bench.config.payload_kg),
            arm.dof,
            bench.config.motion_step_s,
            motion_power_batch(arm, bench.config.payload_kg),
        )
        self.observer: IrObserver | None = None
        if observe:
            nodes = region_nodes(self.model, IR_REGIONS)
            names = self.model.node_names
            self.observer = IrObserver(
                self.model.thermal_model,
                {region: tuple(names[i] for i in group) for region, group in nodes.items()},
                OBSERVER_IR_NOISE_C,
                offsets_c=None if scales is None else scales.offsets_c,
                offset_sigma_c=OBSERVER_OFFSET_SIGMA_C,
            )

    def advance_to(self, t_s: float) -> None:
        target = math.floor(t_s / CONTROL_STEP_S + 1e-9) * CONTROL_STEP_S
        while self.model.time_s < target - 1e-9:
            start = self.model.time_s
            watts = self.energy.mean_power_w(start, start + CONTROL_STEP_S) * self.heat
            self.model.advance_to(start + CONTROL_STEP_S, watts)
        if self.observer is not None:
            self.observer.predict(self.model.time_s)

    def update(self, reading: dict[str, float]) -> None:
        if self.observer is not None:
            self.observer.update(reading)

    def error(self, q: FloatArray) -> Pose6:
        states = [
            dataclasses.replace(state, alpha_per_c=state.alpha_per_c * self.alpha)
            for state in self.model.link_states()
        ]
        return kinematics.tool_error(self.arm, q, states, bending=ACROSS_LINK)


@dataclass
class Series:
    """What one controller measured: residual translation (mm) and rotation (rad) per
    measurement, measured and true."""

    name: str
    measured_mm: list[FloatArray] = field(default_factory=list)
    measured_rad: list[FloatArray] = field(default_factory=list)
    true_mm: list[FloatArray] = field(default_factory=list)
    true_rad: list[FloatArray] = field(default_factory=list)

    def summary(self) -> dict[str, float]:
        def rms(values: list[FloatArray]) -> float:
            return float(np.sqrt(np.mean(np.sum(np.square(values), axis=1))))

        def peak(values: list[FloatArray]) -> float:
            return float(np.max(np.linalg.norm(values, axis=1)))

        return {
            "rms_3d_um": 1000 * rms(self.measured_mm),
            "max_3d_um": 1000 * peak(self.measured_mm),
            "rms_rotation_urad": 1e6 * rms(self.measured_rad),
            "max_rotation_urad": 1e6 * peak(self.measured_rad),
            "true_rms_3d_um": 1000 * rms(self.true_mm),
            "true_max_3d_um": 1000 * peak(self.true_mm),
            "true_rms_rotation_urad": 1e6 * rms(self.true_rad),
        }


def measurement_times(
    duty: DutyCycle, duration_s: float, every_s: float
) -> list[tuple[float, int]]:
    """(time, station) of each measurement: in the first cycle after each multiple of
    ``every_s``, mid-dwell at each measured pose."""
    arrivals = duty.arrival_times_s()
    stations = [
        (arrivals[k] + pose.dwell_s / 2.0) for k, pose in enumerate(duty.poses) if pose.measure
    ]
    period = duty.period_s
    times: list[tuple[float, int]] = []
    k = 1
    while True:
        cycle = math.ceil(k * every_s / period)
        if cycle * period + max(stations) > duration_s:
            return times
        times.extend((cycle * period + offset, s) for s, offset in enumerate(stations))
        k += 1


@dataclass
class References:
    poses: list[FloatArray]
    markers: list[FloatArray]


def cold_references(bench: ArmBench) -> References:
    """Each station's cold pose: the markers averaged over REFERENCE_FRAMES frames."""
    poses, markers = [], []
    for station, q in enumerate(bench.stations_q_rad):
        frames = [bench.measure_tool(station, q).points_mm for _ in range(REFERENCE_FRAMES)]
        mean = np.nanmean(frames, axis=0)
        pose, _ = rigid_pose_from_markers(bench.markers_tool_mm, mean)
        poses.append(pose)
        markers.append(mean)
    return References(poses, markers)


def measurement_noise(bench: ArmBench) -> dict[str, float]:
    """3-D and rotation noise of one measurement of the still, cold arm at station 0."""
    q = bench.stations_q_rad[0]
    poses = [bench.measure_tool(0, q).pose for _ in range(NOISE_FRAMES)]
    translations = np.array([p[:3, 3] for p in poses])
    rotations = np.array([pose_difference(poses[0], p).rotation_rad for p in poses])
    t_dev = translations - translations.mean(axis=0)
    r_dev = rotations - rotations.mean(axis=0)
    dof = NOISE_FRAMES - 1
    return {
        "noise_3d_um": 1000 * math.sqrt(float(np.sum(t_dev**2)) / dof),
        "noise_rotation_urad": 1e6 * math.sqrt(float(np.sum(r_dev**2)) / dof),
    }


def calibration_cycle(
    config: ArmBenchConfig, duty: DutyCycle, duration_s: float, every_s: float
) -> tuple[ArmRunData, ArmModelSpec]:
    """An uncompensated cycle on the same arm (other noise) as identification sees it."""
    motion = DutyCycleMotion(duty)
    bench = ArmBench(config, motion)
    references = cold_references(bench)
    controller = Controller(bench, motion)  # only for its motor model's heat
    steps = math.floor(duration_s / IDENTIFY_STEP_S)
    heat = np.array(
        [
            controller.energy.mean_power_w(k * IDENTIFY_STEP_S, (k + 1) * IDENTIFY_STEP_S)
            for k in range(steps)
        ]
    )
    ambient = np.array([bench.ambient_c(k * IDENTIFY_STEP_S) for k in range(steps)])
    schedule = [(t, s) for t, s in measurement_times(duty, duration_s, every_s)]
    times, stations, displacements = [], [], []
    regions: dict[str, list[float]] = {name: [] for name, _, _ in IR_REGIONS}
    for t_s, station in schedule:
        bench.advance_to(t_s)
        q = bench.stations_q_rad[station]
        measured = bench.measure_tool(station, q)
        reading = bench.ir_read()
        times.append(min(round(t_s / IDENTIFY_STEP_S), steps) * IDENTIFY_STEP_S)
        stations.append(station)
        displacements.append(measured.points_mm - references.markers[station])
        for name, values in regions.items():
            values.append(reading[name])
    nodes = region_nodes(controller.model, IR_REGIONS)
    spec = ArmModelSpec(
        description=describe_arm(bench.nominal_arm, plus_share=config.plus_share),
        node_spacing_mm=controller.model.node_spacing_mm,
        regions=nodes,
        sensitivities=[
            marker_sensitivity(bench.nominal_arm, q, bench.markers_tool_mm, ACROSS_LINK)
            for q in bench.stations_q_rad
        ],
        across_link=ACROSS_LINK,
    )
    run = ArmRunData(
        heat_step_s=IDENTIFY_STEP_S,
        joint_heat_w=heat,
        ambient_c=ambient,
        time_s=np.array(times),
        pose_index=np.array(stations, dtype=np.intp),
        marker_displacement_mm=np.array(displacements),
        region_c={name: np.array(values) for name, values in regions.items()},
    )
    return run, spec


def evaluation_run(
    config: ArmBenchConfig,
    duty: DutyCycle,
    duration_s: float,
    every_s: float,
    identified: ArmIdentification,
) -> tuple[dict[str, Series], dict[str, float], float]:
    """The 8-hour run with the three controllers; returns their series, the measurement noise
    and the run's wall time (s)."""
    started = time.perf_counter()
    motion = DutyCycleMotion(duty)
    bench = ArmBench(config, motion)
    noise = measurement_noise(bench)
    references = cold_references(bench)
    controllers: dict[str, Controller | None] = {
        "none": None,
        "preset": Controller(bench, motion),
        "identified+observer": Controller(bench, motion, identified.scales, observe=True),
    }
    series = {name: Series(name) for name in controllers}
    for t_s, station in measurement_times(duty, duration_s, every_s):
        bench.advance_to(t_s)
        q = bench.stations_q_rad[station]
        reading = bench.ir_read()
        cold_true = bench.tool_pose_cold(q)
        for name, controller in controllers.items():
            if controller is None:
                command = q
            else:
                controller.advance_to(t_s)
                controller.update(reading)
                command = commanded_q(bench.nominal_arm, q, -controller.error(q))
            measured = bench.measure_tool(station, command)
            residual = pose_difference(references.poses[station], measured.pose)
            truth = pose_difference(cold_true, bench.tool_pose_true(command))
            record = series[name]
            record.measured_mm.append(residual.translation_mm)
            record.measured_rad.append(residual.rotation_rad)
            record.true_mm.append(truth.translation_mm)
            record.true_rad.append(truth.rotation_rad)
    return series, noise, time.perf_counter() - started


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a 2-hour run, 1-hour calibration")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--measure-every", type=float, default=120.0, help="seconds")
    args = parser.parse_args(argv)
    hours = 2.0 if args.quick else 8.0
    calibration_hours = 1.0 if args.quick else 4.0
    started = time.perf_counter()
    duty = load_duty_cycle(DUTY)
    stations = tuple(tuple(pose.q_rad) for pose in duty.measured_poses())
    config = ArmBenchConfig(
        seed=args.seed,
        stations_q_rad=stations,
        ir_regions=IR_REGIONS,
        arm=duty.arm,
        payload_kg=duty.payload_kg,
    )
    calibration_config = dataclasses.replace(config, noise_seed=args.seed + 1000)
    run, spec = calibration_cycle(
        calibration_config, duty, calibration_hours * HOURS, args.measure_every
    )
    names = [
        *(f"heat:{j + 1}" for j in range(run.joint_heat_w.shape[1])),
        "convection",
        "alpha",
        *(f"offset:{name}" for name, _, _ in IR_REGIONS),
    ]
    # First every parameter, to report what the cycle can and cannot identify; then only the
    # identifiable ones, the others left at the preset's value (a factor the data do not see
    # is not moved to its bound by noise).
    full = identify_arm(run, spec, names)
    kept = [p.name for p in full.parameters if p.identifiable]
    identified = full if len(kept) == len(names) else identify_arm(run, spec, kept)
    calibrated = time.perf_counter()
    series, noise, run_wall_s = evaluation_run(
        config, duty, hours * HOURS, args.measure_every, identified
    )
    total_wall_s = time.perf_counter() - started
    load = os.getloadavg()
    summaries = {name: s.summary() for name, s in series.items()}
    drift = summaries["none"]
    rows: list[list[Any]] = []
    for name, summary in summaries.items():
        reduction = 1.0 - summary["rms_3d_um"] / drift["rms_3d_um"]
        rotation_reduction = 1.0 - summary["rms_rotation_urad"] / drift["rms_rotation_urad"]
        summary["reduction_3d"] = reduction
        summary["reduction_rotation"] = rotation_reduction
        summary["rms_over_noise"] = summary["rms_3d_um"] / noise["noise_3d_um"]
        summary["rotation_over_noise"] = summary["rms_rotation_urad"] / noise["noise_rotation_urad"]
        rows.append(
            [
                name,
                summary["rms_3d_um"],
                summary["max_3d_um"],
                f"{100 * reduction:.1f} %",
                summary["rms_over_noise"],
                summary["true_rms_3d_um"],
                summary["rms_rotation_urad"],
                f"{100 * rotation_reduction:.1f} %",
                summary["rotation_over_noise"],
                summary["true_rms_rotation_urad"],
            ]
        )
    print(
        f"A465 '{DUTY}', {hours:g} h, seed {args.seed}, "
        f"{len(series['none'].measured_mm)} measurements, cameras {config.rig.count} per station"
    )
    print_table(
        [
            "controller",
            "RMS 3-D um",
            "max 3-D um",
            "3-D removed",
            "RMS/noise",
            "true RMS um",
            "RMS rot urad",
            "rot removed",
            "rot/noise",
            "true rot urad",
        ],
        rows,
    )
    print(
        f"\n3-D measurement noise {noise['noise_3d_um']:.2f} um, rotation "
        f"{noise['noise_rotation_urad']:.2f} urad (one measurement, still cold arm)"
    )
    truth = ArmBench(config)
    true_values = {
        **{f"heat:{j + 1}": float(k) for j, k in enumerate(truth.heat_scales)},
        "convection": config.convection_scale,
        "alpha": config.alpha_scale,
        **{f"offset:{name}": value for name, value in truth.ir_offsets_c.items()},
    }
    refit = {p.name: p for p in identified.parameters}
    print(
        f"\nidentification from the {calibration_hours:g}-h calibration cycle "
        f"({run.time_s.size} measurements; all parameters, then the identifiable ones refitted):"
    )
    print_table(
        ["parameter", "truth", "all: value", "SE", "identifiable", "refit", "why not"],
        [
            [
                p.name,
                true_values[p.name],
                p.value,
                p.standard_error,
                p.identifiable,
                refit[p.name].value if p.name in refit else "(preset)",
                p.reason or "-",
            ]
            for p in full.parameters
        ],
    )
    print(
        f"conditioning of the normalised J^T J: all {full.conditioning:.3g}, "
        f"refit {identified.conditioning:.3g}"
    )
    print(
        f"\nwall time: {hours:g}-h run {run_wall_s:.1f} s, calibration + identification "
        f"{calibrated - started:.1f} s, total {total_wall_s:.1f} s; load average "
        f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} on {os.cpu_count()} CPUs"
    )
    write_results(
        "bench_arm" + ("_quick" if args.quick else ""),
        {
            "hours": hours,
            "calibration_hours": calibration_hours,
            "seed": args.seed,
            "measure_every_s": args.measure_every,
            "noise": noise,
            "controllers": summaries,
            "identification": {"all": full.to_dict(), "refit": identified.to_dict()},
            "truth": true_values,
            "wall_s": {"run": run_wall_s, "total": total_wall_s},
            "load_average": list(load),
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
