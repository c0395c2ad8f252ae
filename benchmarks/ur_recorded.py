"""The UR bench on an ACCELERATED clock, without its 500 Hz network loop (issue 31): an
uncompensated followed run of the UR5e program recorded into a run database as the daemon's
followed run records it, and a compensated one replayed against the bench truth. Used by
benchmarks/bench_ur_identify.py and tests/test_ur_calibrate_model.py.

Hours of the program take seconds to minutes: the emulated controller (drivers/sim/ur/
controller.py: the program played on the joint arm, the bench truth heated by the motion it
made, the joint temperature sensors) is sampled every ``step_s`` of emulator time instead of
run at its 2 ms cycle (as benchmarks/bench_ur_followed.py does). What is recorded is the
followed run's own code: the state's columns by FollowedKind._state_into, the measurement at a
dwell by daemon/run/followed/measure.py DwellMeasurement (the first step of each dwell at a
measured pose, with the joints at rest; the drift against the pose's first measurement), the
tool measured by the bench's cameras (rendered marker windows, centroids, triangulation, pose
fit: drivers/sim/arm_bench.py measure_tool, the UR bench cameras' renderer). To keep the
rendering cheap a dwell is measured at most once per ``measure_every_s`` per pose (the daemon
measures every dwell); between measurements one step per ``record_every_s`` carries the joint
temperatures (the daemon records every step). With a room thermometer (room.driver not none:
the bench's, drivers/sim/ur/room.py) every recorded step carries its reading (``room_c``), as
the followed run records it, and the replayed models follow it (follow_room).

The motor heat (arm.heat_from): with ``measured`` every recorded step carries the heat of the
motion the emulated arm made since the last one (``heat_json``: the program's joints sampled
every HEAT_SAMPLE_S, as the driver's log of RTDE packages, through the followed run's own
daemon/run/followed/heat.py), and a replayed model with that setting advances on it. ``pauses``
((start s, end s) of emulator time) pause the program as the Dashboard's ``pause`` does.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from config.settings import Settings
from daemon.arm import kinematics
from daemon.arm.correction import correction_for
from daemon.arm.run import ToolMeasurement
from daemon.arm.types import FloatArray, pose_difference
from daemon.run.arm.measure import pose_sigmas
from daemon.run.followed.heat import MEASURED, FollowedHeat, MeasuredHeat, heat_json
from daemon.run.followed.kind import FollowedKind
from daemon.run.followed.measure import DwellMeasurement
from daemon.run.followed.setup import followed_model
from daemon.run.states import RunParameters
from daemon.storage.recorder import Recorder
from daemon.storage.step_record import StepRecord
from drivers.base import OffsetRobotState
from drivers.sim.arm_bench import ArmBench
from drivers.sim.ur.controller import URController, URControllerConfig
from drivers.sim.ur.player import PlayerState
from drivers.ur.modes import RobotMode, RuntimeState, SafetyMode
from drivers.ur.motion import MotionSamples

#: The longest a dwell's measurement is waited for (s, wall): the bench's frames and fit take
#: well under a second; a hang fails the recording instead of blocking it.
MEASURE_WAIT_S = 60.0

UM_PER_MM = 1000.0
#: The program's motion sampled for the measured heat (s): the driver logs 125-500 packages a
#: second; 20 a second keeps the heat of the UR5e program's moves within 0.2 % (the
#: closing note's 0.1 % at 125 Hz, 0.9 % at 10 Hz) at a tenth of the CPU.
HEAT_SAMPLE_S = 0.05

Pauses = tuple[tuple[float, float], ...]


class ProgramMotion:
    """The played program's motion since the last take, sampled every ``dt_s`` up to the
    emulator time the caller has advanced the program to (a drivers/ur/motion.py log)."""

    def __init__(self, controller: URController, dt_s: float = HEAT_SAMPLE_S) -> None:
        self.controller = controller
        self.dt_s = dt_s
        self._next_s = 0.0

    def take(self, until_s: float) -> MotionSamples:
        times = np.arange(self._next_s, until_s + 1e-9, self.dt_s)
        if not len(times):
            return MotionSamples.empty()
        self._next_s = float(times[-1]) + self.dt_s
        samples = [self.controller.player.sample(float(t)) for t in times]
        return MotionSamples(
            times,
            np.array([s.q_rad for s in samples]),
            np.array([s.qd_rad_s for s in samples]),
            np.array([s.qdd_rad_s2 for s in samples]),
        )


def follow_pauses(controller: URController, t_s: float, pauses: Pauses) -> None:
    """The program paused while ``t_s`` is in one of ``pauses``, playing otherwise (the
    Dashboard's pause and play at ``t_s``); then played up to ``t_s``."""
    player = controller.player
    paused = any(start <= t_s < end for start, end in pauses)
    if paused and player.state is PlayerState.PLAYING:
        player.advance(t_s)
        player.pause(t_s)
    elif not paused and player.state is PlayerState.PAUSED:
        player.play(t_s)
    player.advance(t_s)


def emulated(seed: int, truth: dict[str, Any], duty: str | None = None) -> URController:
    """The UR bench's controller (seeded truth, the bench's cameras at the program's measured
    poses), its truth replaced by one made to break the model when ``truth`` gives
    ArmBenchConfig values (heat_scales, convection_scale, ambient_drift_c_per_h...); ``duty``
    the program it plays (a config/duty name), else the controller's default (the UR5e
    pick-and-place)."""
    config = URControllerConfig(seed=seed)
    if duty is not None:
        config = dataclasses.replace(config, duty=duty)
    controller = URController(config)
    if truth:
        base = controller.bench.config
        config = dataclasses.replace(base, **truth)
        controller.bench = ArmBench(config, motion=controller.player, arm=controller.arm)
    return controller


@dataclass
class _BenchMeter:
    """The tool measured by the bench's cameras of the station the program dwells at."""

    bench: ArmBench
    q_rad: FloatArray = field(default_factory=lambda: np.zeros(6))
    station: int = 0
    #: each measurement's own 1-sigma of the 3-D position (mm): the measurement's noise
    sigmas_mm: list[float] = field(default_factory=list)

    async def measure(
        self, expected_pose: FloatArray, frames: int | None = None
    ) -> ToolMeasurement:
        del expected_pose, frames  # the rendered windows are at the true tool already
        fit = self.bench.measure_tool(self.station, self.q_rad)
        sigma_mm, sigma_rad = pose_sigmas(fit.covariance)  # as the arm run's meter reports it
        self.sigmas_mm.append(sigma_mm)
        return ToolMeasurement(fit.pose, sigma_mm, True, {}, sigma_rad)


def _state(controller: URController, t_s: float, instance: int) -> OffsetRobotState:
    q = controller.player.joints(t_s)
    sample = controller.player.sample(t_s)
    pose = kinematics.forward(controller.arm, q)
    return OffsetRobotState(
        timestamp_s=t_s,
        received_s=t_s,
        joints_rad=tuple(float(v) for v in q),
        joint_speeds_rad_s=tuple(float(v) for v in sample.qd_rad_s),
        tcp_pose=(float(pose[0, 3]), float(pose[1, 3]), float(pose[2, 3]), 0.0, 0.0, 0.0),
        tcp_speed=(0.0,) * 6,
        joint_temperatures_c=controller.joint_temperatures(t_s),
        robot_mode=int(RobotMode.RUNNING),
        safety_mode=int(SafetyMode.NORMAL),
        runtime_state=int(RuntimeState.PLAYING),
        at_pose=controller.player.at_pose(t_s),
        accepted_sequence=0,
        program_status=0,
        applied_offset_mm=(0.0, 0.0, 0.0),
        applied_rotation_rad=(0.0, 0.0, 0.0),
        program_instance=instance,
    )


def record_calibration_run(
    settings: Settings,
    controller: URController,
    data_dir: Path,
    *,
    hours: float,
    step_s: float = 0.25,
    measure_every_s: float = 120.0,
    record_every_s: float = 20.0,
    pauses: Pauses = (),
) -> tuple[int, list[float]]:
    """An uncompensated followed run of ``hours`` recorded into ``data_dir``'s run database
    (module docstring): its id, and each camera measurement's own 3-D 1-sigma (mm)."""
    motion = ProgramMotion(controller)
    heat = (
        MeasuredHeat(controller.arm, controller.duty.payload_kg)
        if settings.arm.heat_from == MEASURED
        else None
    )
    heat_from_s = 0.0
    parameters = RunParameters.from_settings(settings, compensation="off")
    room = settings.room.driver != "none"
    bench = controller.bench
    taught = controller.duty.poses
    stations = {k + 1: n for n, k in enumerate(i for i, p in enumerate(taught) if p.measure)}
    meter = _BenchMeter(bench)
    state_now: list[OffsetRobotState] = []
    measurement = DwellMeasurement(
        meter,
        lambda q: kinematics.forward(controller.arm, q),
        lambda: state_now[-1],
        bench.config.rig.count,
    )
    last_measured: dict[int, float] = {}
    controller.player.play(0.0)
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run(
            parameters.model_dump(mode="json"),
            settings.model_dump(mode="json"),
            {"kind": FollowedKind.name, "recorded": "benchmarks/ur_recorded.py"},
            "offline",
            kind=FollowedKind.name,
        )
        step = 0
        last_record = -math.inf
        for k in range(1, round(hours * 3600.0 / step_s) + 1):
            t = k * step_s
            follow_pauses(controller, t, pauses)
            at_pose = controller.player.at_pose(t)
            due = at_pose and t - last_measured.get(at_pose, -math.inf) >= measure_every_s
            if not due and t - last_record < record_every_s:
                continue
            state = _state(controller, t, 1)
            if not due:  # a moving or not-yet-due step: the measurement sees no new dwell
                state = dataclasses.replace(state, at_pose=0)
            record = StepRecord(run_id=run_id, step=step, scheduled_s=t, actual_s=t, lateness_s=0.0)
            FollowedKind._state_into(record, state)
            if room:  # the followed run's step reads the room first (FollowedKind._read_room)
                record.room_c = controller.room_temperature(t)
            if heat is not None:  # the motion since the last recorded step (FollowedHeat)
                heat.add(motion.take(t))
                power = heat.take_mean_w()
                if power is not None:
                    record.heat_json = heat_json(heat_from_s, t, power, MEASURED)
                heat_from_s = t
            record.correction_tx_mm = record.correction_ty_mm = record.correction_tz_mm = 0.0
            flags: list[str] = []
            errors: list[str] = []
            if due:
                bench.advance_to(t)
                meter.q_rad = np.asarray(state.joints_rad)
                meter.station = stations[at_pose]
                state_now.append(state)
                measured, record = asyncio.run(_measure_now(measurement, state, record, flags))
                state_now.clear()
                if measured is not None:
                    last_measured[at_pose] = t
            else:
                record.flags, record.error = ",".join(flags), "; ".join(errors)
            recorder.write_step(record)
            step += 1
            last_record = t
        recorder.finish_run(run_id, "finished", {"kind": FollowedKind.name}, None)
    return run_id, meter.sigmas_mm


async def _measure_now(
    measurement: DwellMeasurement, state: OffsetRobotState, record: StepRecord, flags: list[str]
) -> tuple[ToolMeasurement | None, StepRecord]:
    """The followed run's dwell measurement as its steps make it (start, then collect into
    the step's row), waited for here: the bench's clock stands still while it measures."""
    if not measurement.start(state, record, flags):
        record.flags = ",".join(flags)
        return None, record
    record.flags = ",".join(flags)
    rows: list[StepRecord] = []

    async def keep(row: StepRecord) -> None:
        rows.append(row)

    found = await measurement.collect(keep, wait_s=MEASURE_WAIT_S)
    return found, rows[-1]


def compensated_removal(
    runs: dict[str, tuple[Settings, str | None]],
    controller: URController,
    *,
    hours: float,
    sample_s: float = 60.0,
    pauses: Pauses = (),
) -> dict[str, dict[str, Any]]:
    """Compensated followed runs replayed against the truth (benchmarks/bench_ur_followed.py's
    method), one pass of the truth for all: every ``sample_s`` each run's model (the followed
    run's, daemon/run/followed/setup.py, with its settings and its arm model: None for the
    preset) is advanced, fed the joint temperatures (as its settings' prediction says), and
    its correction at the program's joints is taken as applied; the residual is the truth's
    error plus it. A run whose settings say arm.heat_from measured advances on the heat of the
    program's motion since the last sample (the followed run's FollowedHeat), the program
    paused over ``pauses``. A run whose settings have a room thermometer (room.driver) follows the
    bench's room sensor (one reading per sample, before the advance, as the followed run).
    Per run: the RMS over the last half (a warm arm), the worst, and the uncompensated drift
    beside them."""
    models = {
        name: followed_model(
            settings, RunParameters.from_settings(settings, step_s=sample_s, arm_model=arm_model)
        )
        for name, (settings, arm_model) in runs.items()
    }
    rooms = {name for name, (settings, _) in runs.items() if settings.room.driver != "none"}
    motion = ProgramMotion(controller)
    heats = {
        name: FollowedHeat.on(models[name].controller, None)
        for name, (settings, _) in runs.items()
        if settings.arm.heat_from == MEASURED
    }
    bench = controller.bench
    controller.player.play(0.0)
    residual: dict[str, list[float]] = {name: [] for name in models}
    uncompensated: list[float] = []
    for t in (float(v) for v in np.arange(sample_s, hours * 3600.0 + 1e-6, sample_s)):
        follow_pauses(controller, t, pauses)
        samples = motion.take(t)
        temperatures = controller.joint_temperatures(t)
        room_c = controller.room_temperature(t) if rooms else math.nan
        bench.advance_to(t)
        q = controller.player.joints(t)
        error = pose_difference(bench.tool_pose_cold(q), bench.tool_pose_true(q)).translation_mm
        uncompensated.append(float(np.linalg.norm(error)) * UM_PER_MM)
        for name, model in models.items():
            if name in rooms:
                model.follow_room(room_c)
            if name in heats:
                heats[name].hold(samples, model.time_s, t)
            model.advance_to(t)
            model.observe(temperatures)
            correction = correction_for(model.tool_error(q)).translation_mm
            residual[name].append(float(np.linalg.norm(error + correction)) * UM_PER_MM)
    warm = len(uncompensated) // 2

    def rms(values: list[float]) -> float:
        return math.sqrt(sum(v * v for v in values) / len(values))

    return {
        name: {
            "samples": len(values),
            "uncompensated_rms_um": rms(uncompensated[warm:]),
            "uncompensated_max_um": max(uncompensated),
            "rms_um": rms(values[warm:]),
            "max_um": max(values),
            "removed": 1.0 - rms(values[warm:]) / rms(uncompensated[warm:]),
        }
        for name, values in residual.items()
    }
