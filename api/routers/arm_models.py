"""``GET /arm-models`` and ``GET /arm-models/{name}``: the identified arm models saved in the
data directory (``thermocomp identify RUN --save NAME`` of an arm run, issue 20), each with its
identification table (source runs, date, fit RMS, every parameter's value, standard error and
identifiability, the IR offsets, the validation if any), and what an arm run may name besides:
the arm presets and duty cycles installed.

A run names an arm model by name (``"arm_model"`` in POST /runs); these routes read the small
TOML files on the daemon's bounded read pool, never on the event loop.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter
from fastapi import Path as PathParam
from pydantic import BaseModel, Field

from api.deps import DaemonDep, ReadAccess, SettingsDep
from api.errors import ApiError, ErrorBody
from daemon.arm.arm_model import (
    ArmModel,
    ArmModelError,
    available_saved_arm_models,
    load_arm_model,
    saved_arm_models_dir,
)
from daemon.arm.duty import available_duty_cycles
from daemon.arm.loading import available_arms
from daemon.model.presets import NETWORK_NAME

router = APIRouter(tags=["arm models"], dependencies=[ReadAccess])

#: The saved models' name rule (daemon/arm/arm_model.py: the saved networks' rule). Checked in
#: the route rather than by FastAPI so that a malformed name gets one line saying what a name
#: is; the description still gives the pattern.
ArmModelName = Annotated[
    str,
    PathParam(
        description="A saved arm model's name (GET /arm-models lists them).",
        json_schema_extra={"pattern": f"^{NETWORK_NAME.pattern}$", "maxLength": 64},
    ),
]


class ArmModelParameter(BaseModel):
    name: str = Field(
        description="heat:J, convection, alpha, capacity, share[:J] or offset:REGION."
    )
    value: float = Field(description="The factor (x the preset's) or the offset (degC).")
    standard_error: float | None = Field(description="None: unbounded (nothing seen).")
    relative_error: float | None
    identifiable: bool
    reason: str = Field(description="Why it is not identifiable (empty when it is).")


class ArmModelInfo(BaseModel):
    """An identified arm model: what a run with ``"arm_model": NAME`` applies to the preset
    arm's model, and where it came from."""

    name: str
    arm: str = Field(description="The arm it was identified on (a run of another is refused).")
    duty_cycle: str = Field(description="The duty cycle of the calibration run.")
    source_runs: list[str]
    identified_at: str = Field(description="UTC, ISO 8601.")
    marker_rms_um: float | None = Field(description="The fit's tool-translation residual RMS.")
    temperature_rms_c: float | None = Field(description="The fit's IR residual RMS.")
    heat_scales: list[float] = Field(description="Per joint, x the motor model's heat.")
    convection_scale: float
    alpha_scale: float
    capacity_scale: float = Field(description="The joints' heat capacity, x the preset's.")
    bending_shares: list[float] = Field(
        description="Each joint's bending share (empty: the run's arm.motor_side_share)."
    )
    calibrated: bool = Field(
        description="Every parameter identified by the final fit and every value physical."
    )
    warning: str = Field(description="Empty, or why this model is NOT fully calibrated.")
    not_identified: list[str] = Field(description="Parameters left at the preset's value.")
    implausible: list[str] = Field(
        description="Values outside their physical range, saved with --force."
    )
    ir_offsets_c: dict[str, float]
    ir_offset_sigma_c: dict[str, float]
    parameters: list[ArmModelParameter]
    validation_runs: list[str] = Field(description="identify --validate: the runs predicted.")
    validation_marker_rms_um: float | None = Field(
        description="The validation run's tool translation predicted by this model: error RMS."
    )
    validation_preset_marker_rms_um: float | None = Field(
        description="The same by the preset arm's model (every factor 1, no IR offset)."
    )
    validation_temperature_rms_c: float | None


class ArmModelProblem(BaseModel):
    name: str
    error: str


class ArmModelList(BaseModel):
    arm_runs: bool = Field(description="Whether this daemon runs arm runs (arm.enabled).")
    arm_presets: list[str] = Field(description="The installed arms (config/arms).")
    duty_cycles: list[str] = Field(description="The installed duty cycles (config/duty).")
    arm_models: list[ArmModelInfo]
    unreadable: list[ArmModelProblem]


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _finite_map(values: Mapping[str, float]) -> dict[str, float]:
    return {key: value for key, value in values.items() if math.isfinite(value)}


def _info(model: ArmModel, name: str) -> ArmModelInfo:
    return ArmModelInfo(
        name=name,
        arm=model.arm,
        duty_cycle=model.duty_cycle,
        source_runs=list(model.source_runs),
        identified_at=model.identified_at,
        marker_rms_um=_finite(model.marker_rms_um),
        temperature_rms_c=_finite(model.temperature_rms_c),
        heat_scales=list(model.heat_scales),
        convection_scale=model.convection_scale,
        alpha_scale=model.alpha_scale,
        capacity_scale=model.capacity_scale,
        bending_shares=list(model.bending_shares),
        calibrated=model.calibrated,
        warning=model.warning,
        not_identified=list(model.not_identified),
        implausible=list(model.implausible),
        ir_offsets_c=_finite_map(model.ir_offsets_c),
        ir_offset_sigma_c=_finite_map(model.ir_offset_sigma_c),
        parameters=[
            ArmModelParameter(
                name=p.name,
                value=p.value,
                standard_error=_finite(p.standard_error),
                relative_error=_finite(p.relative_error),
                identifiable=p.identifiable,
                reason=p.reason,
            )
            for p in model.parameters
            if math.isfinite(p.value)
        ],
        validation_runs=list(model.validation_runs),
        validation_marker_rms_um=_finite(model.validation_marker_rms_um),
        validation_preset_marker_rms_um=_finite(model.validation_preset_marker_rms_um),
        validation_temperature_rms_c=_finite(model.validation_temperature_rms_c),
    )


def _read(data_dir: Path, name: str) -> ArmModelInfo:
    """One saved model (blocking: a file); ArmModelError when it does not load."""
    return _info(load_arm_model(saved_arm_models_dir(data_dir) / f"{name}.toml"), name)


def _read_all(data_dir: Path, arm_runs: bool) -> ArmModelList:
    """Every saved model and the installed presets (blocking: files and folders)."""
    models, problems = [], []
    for name in available_saved_arm_models(data_dir):
        try:
            models.append(_read(data_dir, name))
        except ArmModelError as err:
            problems.append(ArmModelProblem(name=name, error=str(err)))
    return ArmModelList(
        arm_runs=arm_runs,
        arm_presets=available_arms(),
        duty_cycles=available_duty_cycles(),
        arm_models=models,
        unreadable=problems,
    )


def _lookup(data_dir: Path, name: str) -> ArmModelInfo | None:
    """The saved model ``name``, None when there is none (blocking)."""
    if name not in available_saved_arm_models(data_dir):
        return None
    return _read(data_dir, name)


@router.get("/arm-models")
async def list_arm_models(settings: SettingsDep, daemon: DaemonDep) -> ArmModelList:
    """The identified arm models saved in the data directory, each with its identification
    table, the unreadable ones with the reason, and the arm presets and duty cycles an arm
    run may name."""
    return await daemon.read(_read_all, settings.storage.data_dir, settings.arm.enabled)


@router.get(
    "/arm-models/{name}",
    responses={
        404: {"model": ErrorBody, "description": "no saved arm model of that name"},
        422: {"model": ErrorBody, "description": "not a name, or the file does not load"},
    },
)
async def get_arm_model(
    name: ArmModelName, settings: SettingsDep, daemon: DaemonDep
) -> ArmModelInfo:
    """One saved arm model's identification table (as in the list)."""
    if not NETWORK_NAME.fullmatch(name):
        raise ApiError(
            422,
            "validation",
            f"arm model {name!r} is not a name (letters, digits, '.', '_', '-', at most 64, "
            "starting with a letter or digit; no path)",
            [{"field": "path.name", "message": "not an arm model name", "type": "value_error"}],
        )
    data_dir = settings.storage.data_dir
    try:
        found = await daemon.read(_lookup, data_dir, name)
    except ArmModelError as err:
        raise ApiError(422, "validation", f"arm model {name!r} does not load: {err}") from err
    if found is None:
        names = await daemon.read(available_saved_arm_models, data_dir)
        raise ApiError(
            404,
            "not-found",
            f"no saved arm model {name!r} (saved: {', '.join(names) or 'none'}; "
            "`thermocomp identify RUN --save NAME` of an arm run saves one)",
        )
    return found
