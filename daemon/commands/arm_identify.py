"""``thermocomp identify RUN_ID`` for an arm run (issue 20): the recorded run as
daemon/arm/identify.py sees it, the fit, and the arm model (daemon/arm/arm_model.py) that
``--save NAME`` writes and ``thermocomp run --arm-model NAME`` uses. The command itself and
what it prints are daemon/commands/arm_identify_cli.py.

What the run recorded, read back READ-ONLY (as daemon/commands/identify.py reads a two-link run):

- its parameters (the duty cycle, ``time_scale``) and settings (the arm file, ambient, the
  motor heat's resolution ``arm.motion_dt_s``): the controller's preset model is rebuilt from
  them, and the heat its motor model predicts for the duty cycle's commanded motion over each
  IDENTIFY_STEP_S of arm time (JointHeatProfile: deterministic, what the run's model used);
- each step's measured pose (``arm_pose``), the tool's measured translation relative to the
  pose's cold reference (``measured_t*_um``) minus the correction commanded there
  (``correction_t*_mm``; zero in an uncompensated run): the arm's thermal displacement of the
  tool point, at the step's arm time ``actual_s * time_scale``. Only the translation is used:
  the preset model turns no tool (``arm.bending`` off) and the measured rotation is the 3-D
  measurement's noise (docs/explanation/arm.md);
- each step's IR regions (``ir_json``) tied to the model's nodes by name
  (daemon/arm/ir_regions.py: ``<link>-mid``, ``<link>@<fraction>``).

A followed run (a UR playing its own program, issue 31) is read by
daemon/commands/followed_identify.py: its cameras' measurements at the program's dwells, its
joint temperatures as the thermal input; the fit and everything after it are the same.

The fit (daemon/arm/identify_final.py identify_arm_final): every parameter first (heat per joint,
convection, alpha, the joints' capacity, with ``arm.bending`` the bending share, one IR offset
per region), reported with its standard error and whether the run identifies it; then the
identifiable ones refitted until the refit identifies each (the flags are the FINAL fit's),
the others left at the preset's value. A model that is not fully identified is saved with a
warning in the file (and the API, and every run that uses it); a value outside its physical
range (daemon/arm/identify_parameters.py) refuses the save unless ``--force``. Progress goes
to stderr while the fit runs.

``--validate RUN_ID`` is the two-link meaning on the arm: another recorded run of the same arm
(any duty cycle, compensated or not: its correction is taken out as above) is predicted by the
identified model, nothing refitted, and by the preset; the RMS of each prediction's error in
the tool's translation and the IR regions says whether the model carries over
(daemon/arm/identify.py evaluate_arm). The saved model records the validation.
"""

from __future__ import annotations

import json
import math
import sqlite3
from contextlib import closing
from dataclasses import asdict, dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from config import Settings
from daemon.arm.arm_model import ArmModel
from daemon.arm.controller_loading import load_controller
from daemon.arm.identify import (
    ArmFitQuality,
    ArmIdentification,
    Progress,
    evaluate_arm,
)
from daemon.arm.identify_final import IN_COMBINATION, ArmCalibration, identify_arm_final
from daemon.arm.identify_parameters import (
    default_parameters,
    heat_joints,
    outside_physical_range,
)
from daemon.arm.ir_regions import region_nodes
from daemon.calibration.identify_run import (
    recorded_parameters,
)
from daemon.commands.arm_run import (
    ArmRun,
    ArmRunInputError,
    RunRows,
    assemble_arm_run,
    identify_options,
)
from daemon.commands.followed_identify import is_followed_run, load_followed_run
from daemon.model.calibration import CalibratedParameter
from daemon.model.identify import IdentificationError
from daemon.run.arm.setup import arm_file
from daemon.storage.recorder import DATABASE_NAME


def recorded_run(data_dir: Path, run_id: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """The run's parameters and settings, read-only; ArmRunInputError when there is none."""
    return recorded_parameters(data_dir, run_id, ArmRunInputError)


def is_arm_run(parameters: dict[str, Any]) -> bool:
    return parameters.get("duty_cycle") is not None


_STEP_COLUMNS = (
    "actual_s, arm_pose, measured_tx_um, measured_ty_um, measured_tz_um, "
    "correction_tx_mm, correction_ty_mm, correction_tz_mm, ir_json, room_c"
)


def _steps(data_dir: Path, run_id: int) -> list[tuple[Any, ...]]:
    path = Path(data_dir) / DATABASE_NAME
    try:
        with closing(sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)) as db:
            return list(
                db.execute(
                    f"SELECT {_STEP_COLUMNS} FROM steps WHERE run_id = ? ORDER BY step",
                    (run_id,),
                )
            )
    except sqlite3.Error as err:
        raise ArmRunInputError(f"cannot read {path}: {err}") from err


def _number(value: object) -> float:
    return float(value) if isinstance(value, int | float) else math.nan


def load_arm_run(data_dir: Path, run_id: int) -> ArmRun:
    """The recorded arm run as identification sees it (module docstring)."""
    parameters, config = recorded_run(data_dir, run_id)
    if is_followed_run(config):  # a UR that played its own program (issue 31)
        return load_followed_run(data_dir, run_id, parameters, config)
    if not is_arm_run(parameters):
        raise ArmRunInputError(f"run {run_id} is not an arm run (no duty cycle)")
    settings = Settings.model_validate(config)
    options = identify_options(settings)
    try:
        controller = load_controller(arm_file(settings), parameters["duty_cycle"], options)
        poses = controller.measured_poses(settings.arm.measured_poses)
    except (OSError, ValueError) as err:
        raise ArmRunInputError(f"run {run_id}: its arm or duty cycle: {err}") from err
    index = {pose.name: k for k, pose in enumerate(poses)}
    time_scale = float(parameters.get("time_scale", 1.0))
    times, pose_index, displacement = [], [], []
    readings: list[dict[str, float]] = []
    rooms: list[tuple[float | None, float | None]] = []  # the room thermometer (issue 29)
    for row in _steps(data_dir, run_id):
        actual_s, pose = row[0], row[1]
        if actual_s is not None:
            rooms.append((float(actual_s) * time_scale, row[9]))
        if pose not in index or actual_s is None:
            continue
        measured = np.array([_number(v) for v in row[2:5]]) / 1000.0
        correction = np.array([_number(v) if v is not None else 0.0 for v in row[5:8]])
        times.append(float(actual_s) * time_scale)
        pose_index.append(index[pose])
        displacement.append((measured - correction).reshape(1, 3))
        regions = json.loads(row[8]) if row[8] else {}
        readings.append({name: _number(value.get("mean_c")) for name, value in regions.items()})
    if len(times) < 2:
        raise ArmRunInputError(f"run {run_id} has fewer than two measured steps")
    # every region the run read: identify_arm_final fits the section means first and the
    # faces only when the means leave the heats open
    names = sorted({name for reading in readings for name in reading})
    walked = RunRows(times, pose_index, np.array(displacement), readings, rooms)
    return assemble_arm_run(
        f"run {run_id}",
        controller,
        walked,
        options=options,
        settings=settings,
        regions=region_nodes(controller.thermal, names),
        pose_q_rad=[pose.q_rad for pose in poses],
        duty_cycle=str(parameters["duty_cycle"]),
    )


def identify_arm_run(
    run: ArmRun, parameters: list[str] | None, progress: Progress | None = None
) -> ArmCalibration:
    """Every parameter (``parameters``, default identify_parameters.default_parameters), then
    the identifiable ones refitted until each is identified (module docstring); raises
    IdentificationError when none is."""
    joints = run.data.joint_heat_w.shape[1]
    names = parameters or default_parameters(joints, run.spec.regions, run.spec.across_link)
    calibration = identify_arm_final(run.data, run.spec, names, progress=progress)
    if calibration.final is None:
        raise IdentificationError(f"{run.name} identifies none of {', '.join(names)}")
    return calibration


#: The saved model's advice to a lab that runs it on another task anyway (issue 29): the
#: online adaptation starts from this model, each factor it did not identify (kept at the
#: preset, pooled or fitted in combination) with the wide prior, each identified one with its
#: own standard error (daemon/arm/controller_priors.py), so the run learns from its tool
#: measurements what this cycle could not teach. Measured on the UR5e's two tasks over 8
#: plausible truths (docs/explanation/bench-truth.md, "Transfer with the run learning"): the
#: other task's model alone removed 87.3-96.7 % of the drift (10 of 16 cases >= 93 %),
#: adapting from it 91.0-98.5 % (15 of 16; the miss at the meter's cap). An arm run of
#: another duty cycle adapts from such a model by itself (arm.adapt unset, the default:
#: daemon/run/arm/setup.py adapts); a followed run (a UR playing its own program) does not
#: adapt (daemon/run/followed/build.py NOT_ADAPTING): its joint temperatures correct it.
ADAPT_ADVICE = (
    "An arm run (the A465's) of another task adapts from this model by itself (arm.adapt "
    "unset, the default; set arm.adapt = true or false to decide): the run then learns from "
    "its tool measurements what this cycle could not teach (each of these from a wide prior, "
    "each identified factor from its own standard error); a followed run, a UR's, does not "
    "adapt (its joint temperatures correct the model)."
)


def not_identified_warning(calibration: ArmCalibration) -> str:
    """The file's loud warning for a model not fully identified (empty when it is): what
    keeps the preset's value, what the cycle told only in combination (pooled heats, values
    fitted along a trade-off: right for this cycle's mix, not for another's), and what a lab
    must do (issue 29: a UR5e model identified from a task removed 82-92 % of another task's
    drift, the calibration program's 97 %)."""
    missing = calibration.not_identified
    if not missing:
        return ""
    combined = set(calibration.combined) | set(calibration.pools)
    preset = [n for n in missing if n not in combined and not _pooled_member(calibration, n)]
    parts = ["NOT FULLY CALIBRATED:"]
    if preset:
        parts.append(
            f"{', '.join(preset)} could not be identified from the calibration run and keep "
            "the preset's values; the compensation relies on them unchecked."
        )
    if combined:
        parts.append(
            f"{', '.join(sorted(combined))} {'was' if len(combined) == 1 else 'were'} told "
            "only in combination by this cycle (heats pooled, values fitted along a "
            "trade-off): they hold for this cycle's mix of joints, not for another task's."
        )
    parts.append(
        "A calibration cycle that works each joint in turn identifies them; calibrate on one "
        "before using this model on another task: on the A465 thermocomp calibrate model "
        "(its default calibration program; --calibration-cycle names another), on a robot "
        "that plays its own program (a UR) a run of a taught program that does so "
        "(docs/how-to/universal-robots.md)."
    )
    parts.append(ADAPT_ADVICE)
    return " ".join(parts)


def _pooled_member(calibration: ArmCalibration, name: str) -> bool:
    """Whether joint heat ``name`` is fitted as part of a pool of the final fit."""
    joints = set(heat_joints(name))
    return bool(joints) and any(
        joints <= set(heat_joints(pool)) for pool in (*calibration.pools, *calibration.combined)
    )


def implausible_values(model: ArmModel) -> list[str]:
    """The identified values outside their physical range (identify_parameters), each with
    its range; only parameters the final fit identified or fitted in combination are checked
    (the others keep their prior)."""
    return [
        reason
        for p in model.parameters
        if (p.identifiable or p.reason.startswith(IN_COMBINATION))
        and (reason := outside_physical_range(p.name, p.value)) is not None
    ]


def arm_model_of(name: str, run: ArmRun, calibration: ArmCalibration) -> ArmModel:
    """The arm model file's content of a recorded run's calibration (:func:`arm_model_from`)."""
    return arm_model_from(name, run.controller.arm.name, run.duty_cycle, run.name, calibration)


def arm_model_from(
    name: str, arm: str, duty_cycle: str, source: str, calibration: ArmCalibration
) -> ArmModel:
    """The arm model file's content: the final fit's factors (the preset's where not
    identified), every parameter's report from the final fit (or why it was dropped), the
    offsets' 1-sigma, the warning when not all are identified; ``arm`` the arm's name,
    ``source`` the calibration run's."""
    final = calibration.final
    assert final is not None  # identify_arm_run refuses a calibration that identifies nothing
    refitted = {p.name: p for p in final.parameters}
    sigmas = {
        region: float(refitted[f"offset:{region}"].standard_error)
        for region in final.scales.offsets_c
        if f"offset:{region}" in refitted
    }
    offsets = {r: float(v) for r, v in final.scales.offsets_c.items() if r in sigmas}
    shares = final.scales.shares if any(s.kind == "share" for s in final.specs) else None
    parameters = tuple(
        CalibratedParameter(
            name=p.name,
            value=p.value,
            standard_error=p.standard_error,
            relative_error=p.relative_error,
            identifiable=p.identifiable,
            reason=p.reason,
        )
        for p in calibration.parameters()
    )
    return ArmModel(
        name=name,
        arm=arm,
        heat_scales=tuple(float(v) for v in final.scales.heat),
        convection_scale=float(final.scales.convection),
        alpha_scale=float(final.scales.alpha),
        ir_offsets_c=offsets,
        ir_offset_sigma_c=sigmas,
        parameters=parameters,
        duty_cycle=duty_cycle,
        source_runs=(source,),
        identified_at=datetime.now(UTC).isoformat(timespec="seconds"),
        marker_rms_um=None if final.fit.marker_rms_mm is None else 1000 * final.fit.marker_rms_mm,
        temperature_rms_c=final.fit.temperature_rms_c,
        capacity_scale=float(final.scales.capacity),
        bending_shares=() if shares is None else tuple(float(v) for v in shares),
        warning=not_identified_warning(calibration),
        not_identified=calibration.not_identified,
    )


def checked_for_save(model: ArmModel, force: bool) -> ArmModel:
    """``model`` ready to save: ArmRunInputError naming every value outside its physical range
    unless ``force`` (then those values are listed in the file's ``implausible``)."""
    implausible = tuple(implausible_values(model))
    if implausible and not force:
        raise ImplausibleModelError(
            f"not saved: {'; '.join(implausible)} (the model absorbed something it does not "
            "describe: a warming room, a wrong arm file; --force saves it anyway, flagged)"
        )
    return replace(model, implausible=implausible)


class ImplausibleModelError(Exception):
    """An identified value outside its physical range, and no ``--force`` (exit status 1)."""


@dataclass(frozen=True)
class ArmValidation:
    """Another recorded run of the arm as the identified model and the preset predict it."""

    run: str
    duty_cycle: str
    identified: ArmFitQuality
    preset: ArmFitQuality

    def to_dict(self) -> dict[str, Any]:
        return {
            "run": self.run,
            "duty_cycle": self.duty_cycle,
            "identified": asdict(self.identified),
            "preset": asdict(self.preset),
        }


def validate_arm_run(run: ArmRun, refit: ArmIdentification, other: ArmRun) -> ArmValidation:
    """``other`` predicted by the final fit and by the preset (module docstring);
    ArmRunInputError when it is a run of another arm."""
    if other.controller.arm.name != run.controller.arm.name:
        raise ArmRunInputError(
            f"{other.name} ran arm {other.controller.arm.name!r}, {run.name} arm "
            f"{run.controller.arm.name!r}: a model validates on its own arm"
        )
    return ArmValidation(
        run=other.name,
        duty_cycle=other.duty_cycle,
        identified=evaluate_arm(refit, other.data, other.spec),
        preset=evaluate_arm(None, other.data, other.spec),
    )


def validated_model(model: ArmModel, validation: ArmValidation | None) -> ArmModel:
    """``model`` with its validation recorded (unchanged without one)."""
    if validation is None:
        return model
    return replace(
        model,
        validation_runs=(validation.run,),
        validation_marker_rms_um=_um(validation.identified.marker_rms_mm),
        validation_temperature_rms_c=validation.identified.temperature_rms_c,
        validation_preset_marker_rms_um=_um(validation.preset.marker_rms_mm),
    )


def _um(value_mm: float | None) -> float | None:
    return None if value_mm is None else 1000.0 * value_mm
