"""The identified network as a file (issue 19): its node values, and the ``[identification]``
table of where it came from and how sure identification is (daemon/model/calibration.py
reads it back)."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

from daemon.model.calibration import (
    CALIBRATION_TABLE,
    CalibratedParameter,
    Calibration,
    offset_sigmas_c,
)
from daemon.model.network import ThermalNetwork

if TYPE_CHECKING:
    from daemon.model.identify import IdentificationResult


def calibration_of(
    result: IdentificationResult,
    base_network: str,
    source_runs: Sequence[str],
    identified_at: str,
    validation_runs: Sequence[str] = (),
) -> Calibration:
    """What the identified network file records besides its node values (issue 19): the
    provenance, every fitted parameter with its error and identifiability, and the IR offsets
    with their uncertainty (the observer's starting point)."""
    errors = {
        p.name: (p.standard_error if math.isfinite(p.standard_error) else None)
        for p in result.parameters
    }
    offsets = {spec.name: spec.targets for spec in result.specs if spec.kind == "offset"}
    validation = result.validation
    return Calibration(
        base_network=base_network,
        source_runs=tuple(source_runs),
        identified_at=identified_at,
        parameters=tuple(
            CalibratedParameter(
                name=p.name,
                value=p.value,
                standard_error=errors[p.name],
                relative_error=p.relative_error
                if p.relative_error is None or math.isfinite(p.relative_error)
                else None,
                identifiable=p.identifiable,
                reason=p.reason,
            )
            for p in result.parameters
        ),
        ir_offsets_c={
            r: v
            for r, v in result.offsets_c.items()
            if any(r in regions for regions in offsets.values())
        },
        ir_offset_sigma_c=offset_sigmas_c(offsets, errors),
        temperature_rms_c=result.fit.temperature_rms_c,
        deformation_rms_um=result.fit.deformation_rms_um,
        validation_runs=tuple(validation_runs),
        validation_deformation_rms_um=None if validation is None else validation.deformation_rms_um,
    )


def _calibration_toml(calibration: Calibration) -> list[str]:
    lines = [
        "",
        "# Where this network came from and how sure identification is (daemon.model.calibration)",
        f"[{CALIBRATION_TABLE}]",
        f"base_network = {_toml_value(calibration.base_network)}",
        f"source_runs = {_toml_value(list(calibration.source_runs))}",
        f"identified_at = {_toml_value(calibration.identified_at)}",
        f"validation_runs = {_toml_value(list(calibration.validation_runs))}",
    ]
    for key, number in (
        ("temperature_rms_c", calibration.temperature_rms_c),
        ("deformation_rms_um", calibration.deformation_rms_um),
        ("validation_deformation_rms_um", calibration.validation_deformation_rms_um),
    ):
        if number is not None and math.isfinite(number):
            lines.append(f"{key} = {_toml_value(number)}")
    for table, values in (
        ("ir_offsets_c", calibration.ir_offsets_c),
        ("ir_offset_sigma_c", calibration.ir_offset_sigma_c),
    ):
        lines += ["", f"[{CALIBRATION_TABLE}.{table}]"]
        lines += [f"{_toml_value(r)} = {_toml_value(float(v))}" for r, v in values.items()]
    for parameter in calibration.parameters:
        lines += [
            "",
            f"[[{CALIBRATION_TABLE}.parameters]]",
            f"name = {_toml_value(parameter.name)}",
            f"value = {_toml_value(parameter.value)}",
        ]
        for key, error in (
            ("standard_error", parameter.standard_error),
            ("relative_error", parameter.relative_error),
        ):
            if error is not None and math.isfinite(error):
                lines.append(f"{key} = {_toml_value(error)}")
        lines.append(f"identifiable = {'true' if parameter.identifiable else 'false'}")
        if parameter.reason:
            lines.append(f"reason = {_toml_value(parameter.reason)}")
    return lines


def _toml_value(value: float | str | Sequence[float] | Sequence[str]) -> str:
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a valid TOML basic string
    if isinstance(value, float | int):
        number = float(value)
        if math.isinf(number):
            return "inf"
        return repr(number)
    return "[" + ", ".join(_toml_value(item) for item in value) + "]"


def network_toml(network: ThermalNetwork, header: str = "") -> str:
    """``network`` in the ``[[nodes]]``/``[[resistances]]`` format of config/networks/ that
    :func:`daemon.model.load_network` reads (floats at full precision, so it reloads to the
    same matrices)."""
    lines = [f"# {line}" for line in header.splitlines()]
    lines += [
        f"name = {_toml_value(network.name)}",
        f"description = {_toml_value(network.description)}",
        f"reference_nodes = {_toml_value(list(network.reference_nodes))}",
        f"heater_nodes = {_toml_value(list(network.heater_nodes))}",
        f"direction = {_toml_value(network.direction.tolist())}",
    ]
    if network.bar_ends_mm is not None:
        lines.append(f"bar_ends_mm = {_toml_value(list(network.bar_ends_mm))}")
    for i, name in enumerate(network.node_names):
        lines += [
            "",
            "[[nodes]]",
            f"name = {_toml_value(name)}",
            f"position_mm = {_toml_value(float(network.positions_mm[i]))}",
            f"capacitance_j_per_c = {_toml_value(float(network.capacitance_j_per_c[i]))}",
            f"alpha_per_c = {_toml_value(float(network.alpha_per_c[i]))}",
        ]
        for key, array in (
            ("r_ambient_c_per_w", network.r_ambient_c_per_w),
            ("r_end_c_per_w", network.r_end_c_per_w),
        ):
            if math.isfinite(array[i]):
                lines.append(f"{key} = {_toml_value(float(array[i]))}")
        if network.heat_w[i] != 0.0:
            lines.append(f"heat_w = {_toml_value(float(network.heat_w[i]))}")
    for resistance in network.resistances:
        between = [network.node_names[resistance.a], network.node_names[resistance.b]]
        lines += [
            "",
            "[[resistances]]",
            f"between = {_toml_value(between)}",
            f"r_c_per_w = {_toml_value(resistance.r_c_per_w)}",
        ]
    if network.calibration is not None:
        lines += _calibration_toml(network.calibration)
    return "\n".join(lines) + "\n"
