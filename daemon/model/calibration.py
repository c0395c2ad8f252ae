"""What an identified network file carries besides its node values (issue 19).

``thermocomp identify`` writes the identified network (per-node heat, expansion, convection,
contact resistances: the ``[[nodes]]`` and ``[[resistances]]`` tables) and, in its
``[identification]`` table, where the values came from and how sure they are: the source runs,
the date, each fitted parameter with its standard error and identifiability flag, and the IR
offsets of the regions with their uncertainty. The run's model takes the node values; the
IR observer (daemon.model.observer) starts from the offsets, with their uncertainty as prior.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

#: The TOML table of a network file that holds a :class:`Calibration`.
CALIBRATION_TABLE = "identification"


@dataclass(frozen=True)
class CalibratedParameter:
    """One fitted group of identification (daemon.model.identify.FittedParameter)."""

    name: str
    value: float  # a scale factor, or an offset in degC
    standard_error: float | None  # None: unbounded (the data do not see it)
    relative_error: float | None = None
    identifiable: bool = True
    reason: str = ""


@dataclass(frozen=True)
class Calibration:
    """Provenance and uncertainties of an identified network (module docstring)."""

    base_network: str
    source_runs: tuple[str, ...]
    identified_at: str  # ISO 8601, UTC
    parameters: tuple[CalibratedParameter, ...] = ()
    ir_offsets_c: Mapping[str, float] = field(default_factory=dict)
    ir_offset_sigma_c: Mapping[str, float] = field(default_factory=dict)
    temperature_rms_c: float | None = None
    deformation_rms_um: float | None = None
    validation_runs: tuple[str, ...] = ()
    validation_deformation_rms_um: float | None = None

    @property
    def identifiable(self) -> dict[str, bool]:
        return {p.name: p.identifiable for p in self.parameters}


def offset_sigmas_c(
    offsets: Mapping[str, tuple[str, ...]], standard_errors_c: Mapping[str, float | None]
) -> dict[str, float]:
    """Each region's offset uncertainty from the offset parameters acting on it
    (``offsets``: parameter -> its regions; their errors add in quadrature, correlations
    ignored); an unbounded error gives ``inf``."""
    variance: dict[str, float] = {}
    for parameter, regions in offsets.items():
        error = standard_errors_c.get(parameter)
        square = math.inf if error is None or not math.isfinite(error) else error * error
        for region in regions:
            variance[region] = variance.get(region, 0.0) + square
    return {region: math.sqrt(value) for region, value in variance.items()}


__all__ = [
    "CALIBRATION_TABLE",
    "CalibratedParameter",
    "Calibration",
    "offset_sigmas_c",
]
