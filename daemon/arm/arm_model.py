"""An identified arm model (issue 20): what ``thermocomp identify RUN --save NAME`` keeps of
an arm run's identification (daemon/arm/identify.py) and what ``thermocomp run --arm-model
NAME`` (``"arm_model"`` in POST /runs) gives the controller's model (daemon/arm/controller.py).

The file (``<storage.data_dir>/arm-models/NAME.toml``) carries the factors applied to the
preset arm's model: each joint's heat per watt of the motor model, the convection, the
expansion coefficient, the joints' heat capacity and each joint's bending share (1.0, or the
settings' share, where the calibration could not identify the factor: the preset's value
stays), each IR region's offset with its 1-sigma, every fitted parameter with its standard
error and identifiable flag (from the FINAL fit, issue 29), and where it came from (arm, duty
cycle, source run, date). A model whose parameters are not all identified carries a loud
``warning`` and the list ``not_identified``; one saved with ``--force`` despite a value outside
its physical range (daemon/arm/identify_parameters.py PHYSICAL_RANGES) lists those values in
``implausible``. Both are served by the API and recorded by a run that uses the model.
Names follow the saved networks' rules (daemon.model.presets.check_network_name); the arm
presets' names (config/arms) are refused.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from config.inputs import InputError, no_such_name
from config.settings import read_toml
from daemon.arm.description import MAX_ARM_JOINTS
from daemon.arm.loading import available_arms
from daemon.model.calibration import CalibratedParameter
from daemon.model.presets import check_network_name, new_saved_path

#: The data directory's folder of identified arm models.
ARM_MODELS_FOLDER = "arm-models"
#: The file format's version (a later one may add fields; this reader refuses others).
FORMAT_VERSION = 1


class ArmModelNotFoundError(InputError, LookupError):
    """No saved arm model of that name (404 over the API)."""


class ArmModelError(InputError):
    """An arm model file that does not load."""


@dataclass(frozen=True)
class ArmModel:
    """The identified factors of an arm's model and their provenance (module docstring)."""

    name: str
    arm: str
    heat_scales: tuple[float, ...]  # per joint, x the motor model's heat
    convection_scale: float = 1.0
    alpha_scale: float = 1.0
    ir_offsets_c: Mapping[str, float] = field(default_factory=dict)
    ir_offset_sigma_c: Mapping[str, float] = field(default_factory=dict)
    parameters: tuple[CalibratedParameter, ...] = ()
    duty_cycle: str = ""
    source_runs: tuple[str, ...] = ()
    identified_at: str = ""
    marker_rms_um: float | None = None
    temperature_rms_c: float | None = None
    # ``identify --validate RUN``: the model's prediction of another recorded run of the arm,
    # nothing refitted, beside the preset's (daemon/arm/identify.py evaluate_arm)
    validation_runs: tuple[str, ...] = ()
    validation_marker_rms_um: float | None = None
    validation_temperature_rms_c: float | None = None
    validation_preset_marker_rms_um: float | None = None
    #: issue 29: the joints' heat capacity factor and each joint's bending share (empty: the
    #: run's arm.motor_side_share)
    capacity_scale: float = 1.0
    bending_shares: tuple[float, ...] = ()
    #: not empty when the model is not fully calibrated (what the calibration could not
    #: identify and what that means), with the parameters concerned
    warning: str = ""
    not_identified: tuple[str, ...] = ()
    #: values outside their physical range saved anyway (``--force``), each with its range
    implausible: tuple[str, ...] = ()

    @property
    def calibrated(self) -> bool:
        """Every parameter identified and every value physical."""
        return not self.not_identified and not self.implausible

    def provenance(self) -> dict[str, Any]:
        """What a run records of the model it used."""
        return {
            "name": self.name,
            "arm": self.arm,
            "duty_cycle": self.duty_cycle,
            "source_runs": list(self.source_runs),
            "identified_at": self.identified_at,
            "heat_scales": list(self.heat_scales),
            "convection_scale": self.convection_scale,
            "alpha_scale": self.alpha_scale,
            "ir_offsets_c": dict(self.ir_offsets_c),
            "capacity_scale": self.capacity_scale,
            "bending_shares": list(self.bending_shares),
            "identifiable": {p.name: p.identifiable for p in self.parameters},
            "validation_runs": list(self.validation_runs),
            "calibrated": self.calibrated,
            "warning": self.warning,
            "not_identified": list(self.not_identified),
            "implausible": list(self.implausible),
        }


def check_fits(model: ArmModel, arm_name: str, joints: int) -> None:
    """An arm model applies to the arm it was identified on, one heat factor per joint;
    ArmModelError in one line otherwise."""
    if model.arm != arm_name:
        raise ArmModelError(
            f"arm model {model.name!r} was identified on arm {model.arm!r}, this run's arm is "
            f"{arm_name!r}"
        )
    if len(model.heat_scales) != joints:
        raise ArmModelError(
            f"arm model {model.name!r} has {len(model.heat_scales)} heat_scales, arm "
            f"{arm_name!r} {joints} joints"
        )
    if model.bending_shares and len(model.bending_shares) != joints:
        raise ArmModelError(
            f"arm model {model.name!r} has {len(model.bending_shares)} bending_shares, arm "
            f"{arm_name!r} {joints} joints"
        )


def saved_arm_models_dir(data_dir: Path) -> Path:
    return Path(data_dir) / ARM_MODELS_FOLDER


def check_arm_model_name(name: str) -> str:
    """``name`` if it is a plain name (the saved networks' rule), else ValueError."""
    try:
        return check_network_name(name)
    except ValueError as err:
        raise InputError(
            f"arm model {name!r} is not a name (letters, digits, '.', '_', '-', at most 64, "
            "no path)"
        ) from err


def available_saved_arm_models(data_dir: Path) -> list[str]:
    folder = saved_arm_models_dir(data_dir)
    return sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []


def named_arm_model_path(name: str, data_dir: Path) -> Path:
    """The saved arm model ``name``: ValueError for a malformed name, ArmModelNotFoundError
    for an unknown one."""
    check_arm_model_name(name)
    path = saved_arm_models_dir(data_dir) / f"{name}.toml"
    if not path.exists():  # anything else there (a folder, a pipe): its loader says what
        names = available_saved_arm_models(data_dir)
        listed = f"saved in {saved_arm_models_dir(data_dir)}: {', '.join(names) or 'none'}"
        raise ArmModelNotFoundError(no_such_name("saved arm model", name, names, listed))
    return path


def new_arm_model_path(name: str, data_dir: Path) -> Path:
    """Where ``--save NAME`` writes an arm model: a plain name, no arm preset's, not yet
    taken (ValueError)."""
    check_arm_model_name(name)
    return new_saved_path(name, saved_arm_models_dir(data_dir), available_arms(), "an arm preset")


# -- TOML ----------------------------------------------------------------------------------------


def _value(value: object) -> str:
    """A TOML value: JSON's strings, numbers and booleans are TOML's (finite numbers only)."""
    if isinstance(value, bool | str | int):
        return json.dumps(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ArmModelError(f"a non-finite value {value} cannot be saved")
        return repr(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_value(item) for item in value) + "]"
    raise TypeError(f"no TOML for {value!r}")


def arm_model_toml(model: ArmModel, header: str = "") -> str:
    lines = [f"# {line}" for line in header.splitlines()]
    top: dict[str, object] = {
        "format": FORMAT_VERSION,
        "name": model.name,
        "arm": model.arm,
        "duty_cycle": model.duty_cycle,
        "source_runs": list(model.source_runs),
        "identified_at": model.identified_at,
        "heat_scales": list(model.heat_scales),
        "convection_scale": model.convection_scale,
        "alpha_scale": model.alpha_scale,
        "capacity_scale": model.capacity_scale,
        "bending_shares": list(model.bending_shares),
        "calibrated": model.calibrated,
        "warning": model.warning,
        "not_identified": list(model.not_identified),
        "implausible": list(model.implausible),
    }
    if model.marker_rms_um is not None:
        top["marker_rms_um"] = model.marker_rms_um
    if model.temperature_rms_c is not None:
        top["temperature_rms_c"] = model.temperature_rms_c
    if model.validation_runs:
        top["validation_runs"] = list(model.validation_runs)
    for key, item in (
        ("validation_marker_rms_um", model.validation_marker_rms_um),
        ("validation_temperature_rms_c", model.validation_temperature_rms_c),
        ("validation_preset_marker_rms_um", model.validation_preset_marker_rms_um),
    ):
        if item is not None and math.isfinite(item):
            top[key] = float(item)
    lines += [f"{key} = {_value(value)}" for key, value in top.items()]
    for table, values in (
        ("ir_offsets_c", model.ir_offsets_c),
        ("ir_offset_sigma_c", model.ir_offset_sigma_c),
    ):
        lines += ["", f"[{table}]"]
        lines += [f"{json.dumps(k)} = {_value(float(v))}" for k, v in values.items()]
    for p in model.parameters:
        lines += ["", "[[parameters]]", f"name = {_value(p.name)}"]
        # a parameter never fitted (a joint the calibration cycle never heats) has no value:
        # the file leaves it out, the reason says why
        for key, item in (
            ("value", p.value),
            ("standard_error", p.standard_error),
            ("relative_error", p.relative_error),
        ):
            if item is not None and math.isfinite(item):
                lines.append(f"{key} = {_value(float(item))}")
        lines += [f"identifiable = {_value(p.identifiable)}", f"reason = {_value(p.reason)}"]
    return "\n".join(lines) + "\n"


#: A factor of an arm model (x the preset's heat, convection or alpha) is within these: an
#: identification that needed more found a wrong model, not a factor (issue 26).
MIN_SCALE = 1e-3
MAX_SCALE = 1e3


def _floats(
    values: object, what: str, low: float = MIN_SCALE, high: float = MAX_SCALE
) -> tuple[float, ...]:
    """One number per joint, each finite within [low, high] (a factor by default)."""
    if not isinstance(values, list) or not all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in values
    ):
        raise ArmModelError(f"{what} must be a list of numbers")
    if not 1 <= len(values) <= MAX_ARM_JOINTS:
        raise ArmModelError(
            f"{what}: {len(values)} values, one per joint (at most {MAX_ARM_JOINTS})"
        )
    result = tuple(float(v) for v in values)
    if not all(math.isfinite(v) and low <= v <= high for v in result):
        raise ArmModelError(f"{what} must be numbers from {low:g} to {high:g}")
    return result


def _mapping(values: object, what: str) -> dict[str, float]:
    if not isinstance(values, dict):
        raise ArmModelError(f"[{what}] must be a table of numbers")
    try:
        table = {str(k): float(v) for k, v in values.items()}
    except (TypeError, ValueError) as err:
        raise ArmModelError(f"[{what}] must be a table of numbers") from err
    if not all(math.isfinite(v) for v in table.values()):
        raise ArmModelError(f"[{what}] must be finite numbers")
    return table


def _number_or_nan(value: float | None) -> float:
    """A parameter's value; NaN when the file has none (never fitted)."""
    return math.nan if value is None else value


def _optional(data: Mapping[str, Any], key: str) -> float | None:
    """An optional number of the file (absent: None)."""
    value = data.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ArmModelError(f"{key} must be a number")
    return float(value)


def load_arm_model(path: Path) -> ArmModel:
    """An arm model file (ArmModelError naming the file when it does not load)."""
    data = read_toml(Path(path), ArmModelError)  # bounded, regular files only, one line
    try:
        if data.get("format") != FORMAT_VERSION:
            raise ArmModelError(f"format {data.get('format')!r}, expected {FORMAT_VERSION}")
        parameters = tuple(
            CalibratedParameter(
                name=str(p["name"]),
                value=_number_or_nan(_optional(p, "value")),
                standard_error=_optional(p, "standard_error"),
                relative_error=_optional(p, "relative_error"),
                identifiable=bool(p.get("identifiable", True)),
                reason=str(p.get("reason", "")),
            )
            for p in data.get("parameters", [])
        )
        scales = (
            float(data.get("convection_scale", 1.0)),
            float(data.get("alpha_scale", 1.0)),
            float(data.get("capacity_scale", 1.0)),
        )
        if not all(math.isfinite(v) and MIN_SCALE <= v <= MAX_SCALE for v in scales):
            raise ArmModelError(
                "convection_scale, alpha_scale and capacity_scale must be factors from "
                f"{MIN_SCALE:g} to {MAX_SCALE:g}"
            )
        shares = data.get("bending_shares", [])
        bending = _floats(shares, "bending_shares", 0.0, 1.0) if shares else ()
        if not all(0.0 < v < 1.0 for v in bending):
            raise ArmModelError("bending_shares must lie between 0 and 1")
        return ArmModel(
            name=str(data["name"]),
            arm=str(data["arm"]),
            heat_scales=_floats(data["heat_scales"], "heat_scales"),
            convection_scale=scales[0],
            alpha_scale=scales[1],
            ir_offsets_c=_mapping(data.get("ir_offsets_c", {}), "ir_offsets_c"),
            ir_offset_sigma_c=_mapping(data.get("ir_offset_sigma_c", {}), "ir_offset_sigma_c"),
            parameters=parameters,
            duty_cycle=str(data.get("duty_cycle", "")),
            source_runs=tuple(str(r) for r in data.get("source_runs", [])),
            identified_at=str(data.get("identified_at", "")),
            marker_rms_um=_optional(data, "marker_rms_um"),
            temperature_rms_c=_optional(data, "temperature_rms_c"),
            validation_runs=tuple(str(r) for r in data.get("validation_runs", [])),
            validation_marker_rms_um=_optional(data, "validation_marker_rms_um"),
            validation_temperature_rms_c=_optional(data, "validation_temperature_rms_c"),
            validation_preset_marker_rms_um=_optional(data, "validation_preset_marker_rms_um"),
            capacity_scale=scales[2],
            bending_shares=bending,
            warning=str(data.get("warning", "")),
            not_identified=tuple(str(n) for n in data.get("not_identified", [])),
            implausible=tuple(str(n) for n in data.get("implausible", [])),
        )
    except ArmModelError as err:
        raise ArmModelError(f"{path}: {err}") from err
    except (KeyError, TypeError, ValueError) as err:
        raise ArmModelError(f"{path}: missing or malformed {err}") from err


__all__ = [
    "ARM_MODELS_FOLDER",
    "ArmModel",
    "ArmModelError",
    "ArmModelNotFoundError",
    "arm_model_toml",
    "available_saved_arm_models",
    "check_arm_model_name",
    "check_fits",
    "load_arm_model",
    "named_arm_model_path",
    "new_arm_model_path",
    "saved_arm_models_dir",
]
