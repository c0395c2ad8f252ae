"""The calibration's whole fit of the arm model (issue 29): every parameter, then the
identifiable ones refitted until the refit's own report identifies each, so that the flags and
the values a saved model carries come from the FINAL fit (the first fit's flag beside the
refit's value made a pinned convection pass for identified), and a joint the cycle never heats
is left out with its reason (daemon/arm/identify.py fits)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from daemon.arm.identify import (
    ArmIdentification,
    ArmModelSpec,
    ArmRunData,
    Progress,
    _checked_specs,
    identify_arm,
)
from daemon.model.identify import FittedParameter

#: At most this many refits before the final one (each drops what the last did not identify).
MAX_REFITS = 4
#: A joint whose heat never exceeds this share of the largest joint heat is silent (rounding:
#: a joint the cycle never moves gets 1e-31 W from the motor model's arithmetic).
SILENT_SHARE = 1e-9


@dataclass(frozen=True)
class ArmCalibration:
    """A calibration's whole fit: ``full`` (every parameter asked for that the cycle can act
    on), ``final`` (the identified ones, refitted until each is identified in its own report)
    and why each parameter left out of ``final`` was (its name -> the reason, from the fit or
    the check that dropped it). Flags and values come from ``final``; the others keep their
    prior."""

    names: tuple[str, ...]
    full: ArmIdentification | None
    final: ArmIdentification | None
    dropped: dict[str, str]

    @property
    def identified(self) -> tuple[str, ...]:
        return () if self.final is None else tuple(p.name for p in self.final.parameters)

    @property
    def not_identified(self) -> tuple[str, ...]:
        return tuple(name for name in self.names if name not in self.identified)

    def parameters(self) -> list[FittedParameter]:
        """Every parameter asked for, in its order: the final fit's, or (dropped) the full
        fit's value and error, flagged not identifiable with the reason."""
        final = {} if self.final is None else {p.name: p for p in self.final.parameters}
        full = {} if self.full is None else {p.name: p for p in self.full.parameters}
        result = []
        for name in self.names:
            if name in final:
                result.append(final[name])
            elif name in full:
                reason = self.dropped.get(name, full[name].reason)
                result.append(dataclasses.replace(full[name], identifiable=False, reason=reason))
            else:
                result.append(
                    FittedParameter(name, math.nan, math.inf, None, False, self.dropped[name])
                )
        return result


def silent_parameters(run: ArmRunData, names: Sequence[str]) -> dict[str, str]:
    """The heat factors of joints the cycle never heats (the motor model predicts no heat):
    the data cannot depend on them, so they are left out of the fit (an optimiser walks such
    a parameter to a bound at the cost of hundreds of evaluations)."""
    silent = {}
    largest = float(np.max(np.abs(run.joint_heat_w), initial=0.0))
    for name in names:
        kind, _, argument = name.strip().partition(":")
        joint = int(argument) if argument.isdigit() else 0
        heats = kind == "heat" and 1 <= joint <= run.joint_heat_w.shape[1]
        if heats and not np.any(run.joint_heat_w[:, joint - 1] > SILENT_SHARE * largest):
            silent[name] = f"this cycle releases no heat in joint {argument}"
    return silent


def identify_arm_final(
    run: ArmRunData,
    model: ArmModelSpec,
    parameters: Sequence[str] | None = None,
    *,
    progress: Progress | None = None,
) -> ArmCalibration:
    """Every parameter (but :func:`silent_parameters`), then the identifiable ones refitted,
    again until the refit identifies each parameter it fits (at most MAX_REFITS refits; a
    value at its bound in a refit is not identified and is dropped like the others)."""
    names = tuple(p.name for p in _checked_specs(run, model, parameters))
    dropped = silent_parameters(run, names)
    asked = [name for name in names if name not in dropped]
    if not asked:
        return ArmCalibration(names, None, None, dropped)
    full = identify_arm(run, model, asked, progress=progress)
    dropped.update({p.name: p.reason for p in full.parameters if not p.identifiable})
    final: ArmIdentification | None = full
    refits = 0
    while final is not None and any(not p.identifiable for p in final.parameters):
        if final is not full:
            dropped.update(
                {p.name: f"refit: {p.reason}" for p in final.parameters if not p.identifiable}
            )
        kept = [p.name for p in final.parameters if p.identifiable]
        if not kept or refits >= MAX_REFITS:
            final = None
            break
        if progress is not None:
            progress(f"refit of the {len(kept)} identifiable parameters")
        final = identify_arm(run, model, kept, progress=progress)
        refits += 1
    if final is None:
        dropped.update({name: dropped.get(name, "no refit identified it") for name in asked})
    return ArmCalibration(names, full, final, dropped)


__all__ = [
    "MAX_REFITS",
    "SILENT_SHARE",
    "ArmCalibration",
    "identify_arm_final",
    "silent_parameters",
]
