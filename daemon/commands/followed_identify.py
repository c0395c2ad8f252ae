"""A recorded FOLLOWED run (issue 31: a UR playing its own program, daemon/run/followed/) as the
arm's identification sees it (daemon/arm/identify.py, the A465's: nothing is fitted here), for
daemon/commands/arm_identify.py load_arm_run.

What the followed run recorded, read back READ-ONLY (daemon/commands/arm_identify.py reads an
arm run the same way; its ArmRun is what this module returns, so the fit, the identifiability
flags, the physical ranges, the saved arm model and ``--validate`` are the A465's):

- the measured tool errors are the run's CAMERA measurements at the program's dwells
  (daemon/run/followed/measure.py): steps with a measured translation and neither the flag
  ``bench-truth`` (the UR bench's truth, not a camera) nor a discard. Each is the tool's pose
  relative to that pose's first measurement in the run (flag ``first-step-reference``), less
  the change of the correction the run wrote since then (zero in ``calibrate model``'s
  calibration run, compensation off). The identification's displacement is from the cold
  start: the program's first dwells come seconds after the start, when the arm has not
  warmed (a followed run assumes a robot that starts cold, as daemon/arm/
  joint_temperatures.py JOINT_INITIAL_SIGMA_C says), but that first measurement is one
  camera measurement, with its noise, and its error is in every later drift of its pose. So
  the fit takes each pose's reference error as unknown (ArmRunData.reference_fitted: a
  constant per pose and axis, eliminated): taken as the exact cold tool it put the UR5e's
  alpha 1.3-2.5 % high on every seed-1 calibration (the same camera noise in every scenario),
  and 1.002-1.082 on five noise seeds of one run, against the truth's 1.05;
- the pose is the program's at-pose register (``arm_pose``: k, the k-th pose of the taught
  cycle, 1-based), its sensitivity at that pose's taught joints (the robot dwells there);
- the thermal input is the JOINT TEMPERATURES (``ir_json``: ``joint1`` .. ``jointN``), each
  tied to its joint's heat node as the followed run's observer ties it
  (daemon/arm/joint_temperatures.py joint_regions), with one sensor offset each
  (``offset:jointK``, saved as the model's ``ir_offsets_c`` that the run's observer starts
  from); every step's reading is used, one per IDENTIFY_STEP_S, not only the measured steps';
- the motor heat is the heat the run's model saw: each step's recorded ``heat_json`` (the
  motion the robot actually made, arm.heat_from measured: daemon/run/followed/heat.py) as a
  RecordedHeat, the controller's heat source; where no step recorded one (arm.heat_from
  duty-cycle, a run recorded before issue 31's measured heat, a gap) the program's duty cycle
  on the run's time, as the run's model then advanced. So identification and the run see the
  same heat input: a program paused or slowed during the calibration run heats the
  identification's model as it heated the arm, and its factors are not bent to explain the
  cooling of a pause the duty cycle never had.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import sqlite3
from contextlib import closing
from pathlib import Path
from typing import Any

import numpy as np

from config import Settings
from daemon.arm.controller import ArmController
from daemon.arm.controller_loading import load_controller
from daemon.arm.heat import HeatSource
from daemon.arm.joint_temperatures import joint_regions
from daemon.commands.arm_run import (
    IDENTIFY_STEP_S,
    ArmRun,
    ArmRunInputError,
    RunRows,
    assemble_arm_run,
    identify_options,
)
from daemon.run.arm.setup import arm_file
from daemon.run.followed.heat import RecordedHeat, parse_heat_json
from daemon.storage.recorder import DATABASE_NAME

logger = logging.getLogger(__name__)

#: Flags of a step whose measurement columns are not a camera measurement of the tool.
NOT_CAMERA = frozenset({"bench-truth", "moved-during-frames", "camera-error", "marker-error"})

_COLUMNS = (
    "actual_s, arm_pose, measured_tx_um, measured_ty_um, measured_tz_um, "
    "correction_tx_mm, correction_ty_mm, correction_tz_mm, ir_json, room_c, flags, {heat}"
)


def is_followed_run(config: dict[str, Any]) -> bool:
    """A run recorded with robot.driver ur-rtde is a followed run (daemon/run/kinds.py)."""
    robot = config.get("robot") or {}
    return robot.get("driver") == "ur-rtde"


def _rows(data_dir: Path, run_id: int) -> list[tuple[Any, ...]]:
    path = Path(data_dir) / DATABASE_NAME
    try:
        with closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as db:
            # a database no daemon opened since issue 31's measured heat lacks its column
            present = {row[1] for row in db.execute("PRAGMA table_info(steps)")}
            columns = _COLUMNS.format(heat="heat_json" if "heat_json" in present else "NULL")
            return list(
                db.execute(f"SELECT {columns} FROM steps WHERE run_id = ? ORDER BY step", (run_id,))
            )
    except sqlite3.Error as err:
        raise ArmRunInputError(f"cannot read {path}: {err}") from err


def _vector(values: tuple[Any, ...], scale: float = 1.0) -> np.ndarray[Any, np.dtype[np.float64]]:
    return np.array([float(v) * scale if v is not None else 0.0 for v in values])


def _camera_measured(row: tuple[Any, ...]) -> bool:
    flags = set(filter(None, (row[10] or "").split(",")))
    return bool(row[1]) and row[2] is not None and not flags & NOT_CAMERA


def load_followed_run(
    data_dir: Path, run_id: int, parameters: dict[str, Any], config: dict[str, Any]
) -> ArmRun:
    """The recorded followed run as identification sees it (module docstring);
    ArmRunInputError in one line when it cannot be identified from."""
    settings = Settings.model_validate(config)
    # the program the run followed (its parameters', from arm.duty_cycle: RunParameters)
    duty: str | None = parameters.get("duty_cycle", settings.arm.duty_cycle)
    if duty is None:
        raise ArmRunInputError(f"run {run_id}: a followed run without a duty cycle")
    options = identify_options(settings)
    try:
        controller = load_controller(arm_file(settings), duty, options)
    except (OSError, ValueError) as err:
        raise ArmRunInputError(f"run {run_id}: its arm or duty cycle: {err}") from err
    taught = controller.duty.poses
    measured_poses = [k + 1 for k, pose in enumerate(taught) if pose.measure]
    index = {str(k): n for n, k in enumerate(measured_poses)}
    regions = joint_regions(controller)
    time_scale = float(parameters.get("time_scale", 1.0))
    rows = _rows(data_dir, run_id)
    controller.heat = _recorded_heat(controller, rows)
    times: list[float] = []
    pose_index: list[int] = []
    displacement: list[np.ndarray[Any, np.dtype[np.float64]]] = []
    readings: list[dict[str, float]] = []
    rooms: list[tuple[float | None, float | None]] = []
    reference_correction: dict[str, np.ndarray[Any, np.dtype[np.float64]]] = {}
    last_bin = -1
    cameras = 0
    for row in rows:
        if row[0] is None:
            continue
        t = float(row[0]) * time_scale
        rooms.append((t, row[9]))
        camera = _camera_measured(row) and str(row[1]) in index
        this_bin = math.floor(t / IDENTIFY_STEP_S)
        if not camera and this_bin == last_bin:
            continue  # one joint-temperature reading per heat step between the measurements
        reading = _joint_reading(row[8], regions)
        if camera:
            cameras += 1
            correction = _vector(row[5:8])
            reference = reference_correction.setdefault(str(row[1]), correction)
            measured = _vector(row[2:5], 1e-3)
            displacement.append(measured - (correction - reference))
            pose_index.append(index[str(row[1])])
        elif reading:
            displacement.append(np.full(3, math.nan))
            pose_index.append(0)
        else:
            continue
        last_bin = this_bin
        times.append(t)
        readings.append(reading)
    if cameras < 2:
        raise ArmRunInputError(
            f"run {run_id} has {cameras} camera measurement(s) of the tool: identification "
            "needs the tool measured at the program's dwells over hours (tool cameras: "
            "arm.bench_cameras on the UR bench, arm.camera_devices on a robot)"
        )
    measured = np.array(displacement).reshape(len(times), 1, 3)
    walked = RunRows(times, pose_index, measured, readings, rooms)
    return assemble_arm_run(
        f"run {run_id}",
        controller,
        walked,
        options=options,
        settings=settings,
        regions=regions,
        pose_q_rad=[np.asarray(taught[k - 1].q_rad) for k in measured_poses],
        duty_cycle=str(duty),
        reference_fitted=True,
    )


def _recorded_heat(controller: ArmController, rows: list[tuple[Any, ...]]) -> HeatSource:
    """The heat the run's model saw (module docstring): the steps' recorded heat over the duty
    cycle's where none was recorded; the duty cycle's alone when no step recorded any."""
    joints = len(controller.arm.joints)
    record = RecordedHeat(controller.heat, joints)
    for row in rows:
        parsed = parse_heat_json(row[11], joints)
        if parsed is not None:
            with contextlib.suppress(ValueError):  # out of time order: not the run's own
                record.hold(*parsed)
    if not len(record):
        return controller.heat
    logger.info("followed run: recorded heat over %.2f h of arm time", record.covered_s / 3600)
    return record


def _joint_reading(text: str | None, regions: dict[str, tuple[int, ...]]) -> dict[str, float]:
    """The step's joint temperatures (degC) by region name; empty when it has none."""
    if not text:
        return {}
    try:
        values = json.loads(text)
    except json.JSONDecodeError:
        return {}
    reading: dict[str, float] = {}
    for name in regions:
        value = values.get(name, {}).get("mean_c") if isinstance(values, dict) else None
        if isinstance(value, int | float) and math.isfinite(value):
            reading[name] = float(value)
    return reading
