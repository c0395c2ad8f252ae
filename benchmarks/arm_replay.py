"""The arm chain replayed in process, for benchmarks/bench_arm_scenarios.py: a truth file's arm
(config/truths, ``bench.arm_truth``) runs a duty cycle on the simulated bench, uncompensated,
measured as the daemon measures it, and each controller is then played along that run step by
step exactly as an arm run's steps use it (daemon/run/arm/step.py order: room -> model advance
-> prediction -> measurement -> IR into the observer -> tool and IR into the adaptation).

What is the daemon's own code here: the bench's make-up from the settings
(drivers/sim/arm_devices.py ``bench_config``: stations at the cycle's measured poses, the IR
regions), the controller and its options (daemon/run/arm/setup.py ``default_arm_setup``: the
preset, an identified arm model by name, prediction model+ir, ``arm.adapt``), the room
following (ArmController.follow_room), the identification's input (the heat record of the
controller's motor model on the identification grid, the room readings as its ambient:
daemon/commands/arm_identify.py) and the fit (daemon/arm/identify_final.py), the arm model
file (daemon/arm/arm_model.py). What is not: the pty, the emulator's serial moves and the
5-megapixel frames. The tool is measured through the rendered marker windows of every camera
of the station (drivers/sim/arm_markers.py: centroids, triangulation, pose fit), the same
meter as the daemon's without whole frames; a compensation is assumed to reach its target, so
a controller's residual is the measured displacement less its prediction, which is what a
compensated run measures (benchmarks/bench_arm_daemon.py measures it through the robot).

Why a replay: a measurement every few minutes of arm time, as a lab's run at real time
measures every step (the accelerated daemon bench measures once per 40 minutes of arm time:
12 steps of 8 hours, config/arm-sim.toml), and one uncompensated run serves every controller.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from config import Settings, load_settings
from daemon.arm.arm_model import ArmModel, arm_model_toml, new_arm_model_path
from daemon.arm.calibration_program import duty_cycle_toml, program_for_task
from daemon.arm.controller import ArmController
from daemon.arm.controller_loading import load_controller
from daemon.arm.duty import DutyCycle, arm_inverse, load_duty_cycle
from daemon.arm.identify_final import ArmCalibration, identify_arm_final
from daemon.arm.identify_parameters import default_parameters
from daemon.arm.ir_regions import region_nodes
from daemon.arm.loading import load_arm
from daemon.arm.response import ArmModelSpec, ArmRunData, marker_sensitivity
from daemon.arm.room import ambient_series
from daemon.arm.run import MeasuredPose
from daemon.commands.arm_identify import arm_model_from
from daemon.commands.arm_run import IDENTIFY_STEP_S, TOOL_POINT_MM, identify_options
from daemon.run.arm.prepare import reference_frames
from daemon.run.arm.setup import ArmPlan, arm_file, default_arm_setup
from daemon.run.states import RunParameters
from drivers.sim.arm_bench import ArmBench
from drivers.sim.arm_devices import bench_config
from drivers.sim.arm_motion import DutyCycleMotion

CONFIG = Path(__file__).resolve().parent.parent / "config" / "arm-sim.toml"
#: Frames of each station's cold reference (``arm.reference_frames``; the daemon's least is 4,
#: MIN_REFERENCE_FRAMES). The reference's error is in every later drift of its pose: with 4
#: frames it is half the meter's 1-sigma, constant through the run, and with one measured pose
#: (task B) no model can remove it (issue 29, cold-draughty-room B: its 4-frame reference was
#: 3.1 um off, a 3.5-sigma draw in y, 3.0 of the 5.5 um left by a model given every true
#: factor; benchmarks/bench_arm_bisect.py --meter). A lab measures its zero once before an
#: 8-hour run: 16 frames (a quarter of the 1-sigma) cost seconds.
REFERENCE_FRAMES = 16
#: Frames of the meter's noise measurement on the still, cold arm.
NOISE_FRAMES = 30


def bench_settings(
    truth: str, duty: str, seed: int, data_dir: Path, *, arm: str = "crs-a465", frames: int = 1
) -> Settings:
    """config/arm-sim.toml with the truth, the arm, the cycle (its stations), the seed, the
    frames per measurement (``arm.frames_per_measurement``), a data folder."""
    data = load_settings(CONFIG, environ={}).model_dump()
    data["bench"].update({"seed": seed, "arm_truth": truth})
    data["arm"].update(
        {
            "arm_file": arm,
            "duty_cycle": duty,
            "frames_per_measurement": frames,
            "reference_frames": max(REFERENCE_FRAMES, frames),
        }
    )
    data["storage"].update({"data_dir": str(data_dir), "report_at_end": False})
    return Settings.model_validate(data)


def calibration_program(settings: Settings, task: str, folder: Path) -> str:
    """The arm's calibration program at ``task``'s stations (what ``calibrate model`` plays by
    default), written as a duty cycle file; its path."""
    arm = load_arm(arm_file(settings))
    duty = load_duty_cycle(task, arm_inverse(arm))
    program = program_for_task(arm, duty, settings.arm.arm_file, f"{duty.arm}-calibration")
    path = folder / "calibration-program.toml"
    path.write_text(duty_cycle_toml(program, settings.arm.arm_file), encoding="utf-8")
    return str(path)


@dataclass(frozen=True)
class SimulatedRun:
    """One uncompensated run of a cycle on the truth, as the daemon would record it."""

    cycle: str
    arm: str  # the arm's name (an arm model names it)
    poses: tuple[MeasuredPose, ...]  # the controller's measured poses (the stations)
    time_s: np.ndarray  # (K,) arm time of each measurement
    pose_index: np.ndarray  # (K,) which pose
    displacement_mm: np.ndarray  # (K x 3) the tool point's drift from its cold pose
    true_displacement_mm: np.ndarray  # (K x 3) the truth's own tool error (no meter noise)
    regions_c: tuple[dict[str, float], ...]  # each measurement's IR regions
    room_c: np.ndarray  # (K,) the room thermometer at each measurement (the step's start)
    room_start_c: float  # the thermometer at the start (the cold arm's room)
    data: ArmRunData  # identification's view (room readings as the ambient)
    spec: ArmModelSpec
    meter_sigma_um: float  # 3-D 1-sigma of one measurement (still, cold arm)

    @property
    def drift_rms_um(self) -> float:
        return 1000.0 * math.sqrt(float(np.mean(np.sum(self.displacement_mm**2, axis=1))))


def measurement_schedule(
    duty: DutyCycle, duration_s: float, every_s: float
) -> list[tuple[float, str]]:
    """(arm time, pose name) of each measurement: mid-dwell at the measured poses as the cycle
    visits them, at least ``every_s`` apart."""
    arrivals = duty.arrival_times_s()
    visits = [
        (arrivals[k] + pose.dwell_s / 2.0, pose.name)
        for k, pose in enumerate(duty.poses)
        if pose.measure
    ]
    out: list[tuple[float, str]] = []
    last = -math.inf
    cycle = 0
    while True:
        for offset, name in visits:
            t = cycle * duty.period_s + offset
            if t > duration_s:
                return out
            if t - last >= every_s:
                out.append((t, name))
                last = t
        cycle += 1


def simulate(
    settings: Settings, duty_name: str, noise_seed: int, duration_s: float, every_s: float
) -> SimulatedRun:
    """An uncompensated run of ``duty_name`` on the settings' truth, with other measurement
    noise (``noise_seed``), measured every ``every_s`` at least (module docstring)."""
    settings = settings.model_copy(
        update={"arm": settings.arm.model_copy(update={"duty_cycle": duty_name})}
    )
    options = identify_options(settings)
    controller = load_controller(arm_file(settings), duty_name, options)
    duty = controller.duty
    poses = controller.measured_poses(settings.arm.measured_poses)
    config = bench_config(settings, controller.arm, duty, settings.bench.seed)
    config = dataclasses.replace(config, noise_seed=noise_seed, payload_kg=duty.payload_kg)
    bench = ArmBench(config, DutyCycleMotion(duty), arm=controller.arm)
    station = {pose.name: k for k, pose in enumerate(duty.measured_poses())}
    index = {pose.name: k for k, pose in enumerate(poses)}
    cold = []
    frames = reference_frames(settings)  # as the daemon's run measures its references
    for k, q in enumerate(bench.stations_q_rad):
        cold.append(np.mean([bench.measure_tool(k, q).pose[:3, 3] for _ in range(frames)], axis=0))
    each = settings.arm.frames_per_measurement

    def measured(station: int) -> np.ndarray:
        """One measurement of ``each`` frames. The daemon averages each marker's centroid over
        the frames before one triangulation and pose fit; here the poses of single frames are
        averaged: the same mean to first order in the jitter (the fit is smooth and the jitter
        ~0.03 px), and the same sqrt(frames) on the noise."""
        q = bench.stations_q_rad[station]
        position: np.ndarray = np.mean(
            [bench.measure_tool(station, q).pose[:3, 3] for _ in range(each)], axis=0
        )
        return position

    # the truth at the cold references (the arm at the room where it starts, as measured)
    cold_true = [bench.tool_pose_true(q)[:3, 3] for q in bench.stations_q_rad]
    still = np.array([measured(0) for _ in range(NOISE_FRAMES)])
    sigma_um = 1000.0 * math.sqrt(
        float(np.sum((still - still.mean(axis=0)) ** 2)) / (NOISE_FRAMES - 1)
    )
    room_start = bench.room_read()
    times, pose_index, displacement, regions, rooms = [], [], [], [], []
    true_displacement = []
    for t, name in measurement_schedule(duty, duration_s, every_s):
        bench.advance_to(t)
        rooms.append(bench.room_read())  # the step reads the room first
        s = station[name]
        q = bench.stations_q_rad[s]
        times.append(t)
        pose_index.append(index[name])
        displacement.append(measured(s) - cold[s])
        true_displacement.append(bench.tool_pose_true(q)[:3, 3] - cold_true[s])
        regions.append(bench.ir_read())
    steps = math.ceil(duration_s / IDENTIFY_STEP_S) + 1
    heat = np.array(
        [
            controller.mean_heat_w(k * IDENTIFY_STEP_S, (k + 1) * IDENTIFY_STEP_S)
            for k in range(steps)
        ]
    )
    names = sorted(regions[0])  # every region, as daemon/commands/arm_identify.py
    nodes = region_nodes(controller.thermal, names)
    time_s = np.array(times)
    room_c = np.array(rooms)
    data = ArmRunData(
        heat_step_s=IDENTIFY_STEP_S,
        joint_heat_w=heat,
        ambient_c=ambient_series(
            np.concatenate([[0.0], time_s]), np.concatenate([[room_start], room_c]),
            IDENTIFY_STEP_S, steps, settings.model.ambient_c,
        ),
        time_s=np.round(time_s / IDENTIFY_STEP_S) * IDENTIFY_STEP_S,
        pose_index=np.array(pose_index, dtype=np.intp),
        marker_displacement_mm=np.array(displacement).reshape(-1, 1, 3),
        region_c={r: np.array([reading[r] for reading in regions]) for r in nodes},
        name=duty_name,
    )  # fmt: skip
    spec = ArmModelSpec(
        description=controller.thermal.description,
        node_spacing_mm=controller.thermal.node_spacing_mm,
        regions=nodes,
        sensitivities=[
            marker_sensitivity(controller.arm, pose.q_rad, TOOL_POINT_MM, options.bending)
            for pose in poses
        ],
        across_link=controller.thermal.across_link,
    )
    return SimulatedRun(
        duty.name, controller.arm.name, poses, time_s, data.pose_index,
        np.array(displacement), np.array(true_displacement), tuple(regions), room_c, room_start,
        data, spec, sigma_um,
    )  # fmt: skip


def calibrate(
    settings: Settings, run: SimulatedRun, name: str, parameters: list[str] | None = None
) -> tuple[ArmModel, ArmCalibration]:
    """Identification of ``run`` (every default parameter, then the identifiable ones
    refitted: identify_arm_final), saved as arm model ``name`` in the settings' data folder."""
    names = parameters or default_parameters(
        run.data.joint_heat_w.shape[1], run.spec.regions, run.spec.across_link
    )
    calibration = identify_arm_final(run.data, run.spec, names)
    model = arm_model_from(name, run.arm, run.cycle, run.cycle, calibration)
    path = new_arm_model_path(name, settings.storage.data_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(arm_model_toml(model), encoding="utf-8")
    return model, calibration


def plan_for(
    settings: Settings, cycle: str, *, arm_model: str | None, ir: bool, adapt: bool
) -> ArmPlan:
    """The daemon's controller for a run of ``cycle`` (daemon/run/arm/setup.py)."""
    arm = settings.arm.model_copy(update={"adapt": adapt, "duty_cycle": cycle})
    settings = settings.model_copy(update={"arm": arm})
    parameters = RunParameters.from_settings(
        settings, duty_cycle=cycle, arm_model=arm_model, prediction="model+ir" if ir else "model"
    )
    return default_arm_setup(settings, parameters)


def replay(plan: ArmPlan, run: SimulatedRun, *, room: bool) -> dict[str, Any]:
    """The controller of ``plan`` along ``run``, step by step as daemon/run/arm/step.py: the
    room read (followed when ``room``), the model advanced to the measurement, the tool error
    predicted at the pose, then the measurement: IR into the observer (model+ir), the tool's
    displacement and the IR into the adaptation (arm.adapt). The predictions (K x 3, mm) and
    the adaptation's estimates after each step."""
    controller = plan.predictor
    assert isinstance(controller, ArmController)
    by_name = {pose.name: pose for pose in plan.poses}
    predicted = np.zeros_like(run.displacement_mm)
    estimates: list[dict[str, list[float]]] = []
    if room:
        controller.follow_room(run.room_start_c)
    for m, t in enumerate(run.time_s):
        if room:
            controller.follow_room(float(run.room_c[m]))
        controller.advance_to(float(t))
        pose = by_name[run.poses[int(run.pose_index[m])].name]
        predicted[m] = controller.tool_error(pose).translation_mm
        controller.observe(run.regions_c[m])  # a no-op without model+ir, as in the step
        if controller.adapting:
            controller.adapt(pose, run.displacement_mm[m], run.regions_c[m])
            estimates.append(controller.adaptation_estimates())
    return {"predicted_mm": predicted, "estimates": estimates}


def residual_figures(
    run: SimulatedRun, predicted_mm: np.ndarray, rows: slice = slice(None)
) -> dict[str, float]:
    """3-D RMS of the displacement less the prediction over ``rows`` (um), the share of the
    drift's RMS removed, the RMS over the meter's 1-sigma; beside them the same on the truth's
    own tool error (``true_*``: what the bench knows and a lab cannot measure; the meter's
    noise and its references' error are not in it)."""

    def rms_of(values: np.ndarray) -> float:
        return math.sqrt(float(np.mean(np.sum(values**2, axis=1))))

    measured = run.displacement_mm[rows]
    truth = run.true_displacement_mm[rows]
    drift = rms_of(measured)
    rms = rms_of(measured - predicted_mm[rows])
    true_drift = rms_of(truth)
    true_rms = rms_of(truth - predicted_mm[rows])
    return {
        "rms_3d_um": 1000.0 * rms,
        "drift_rms_3d_um": 1000.0 * drift,
        "removed": 1.0 - rms / drift,
        "rms_over_sigma": 1000.0 * rms / run.meter_sigma_um,
        "true_rms_3d_um": 1000.0 * true_rms,
        "true_drift_rms_3d_um": 1000.0 * true_drift,
        "true_removed": 1.0 - true_rms / true_drift,
    }


def summary_estimates(estimates: Mapping[str, list[float]]) -> dict[str, list[float]]:
    return {name: [round(v, 4) for v in pair] for name, pair in estimates.items()}


__all__ = [
    "SimulatedRun",
    "bench_settings",
    "calibrate",
    "calibration_program",
    "plan_for",
    "replay",
    "residual_figures",
    "simulate",
]
