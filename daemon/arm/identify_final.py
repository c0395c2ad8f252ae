"""The calibration's whole fit of the arm model (issue 29): every parameter, then the
identifiable ones refitted (with one pooled heat factor for the joints whose own heats the
cycle cannot tell apart, :func:`heat_pools`) until the refit's own report identifies each,
so that the flags and the values a saved model carries come from the FINAL fit (the first
fit's flag beside the refit's value made a pinned convection pass for identified), and a
joint the cycle never heats is left out with its reason (daemon/arm/identify.py fits)."""

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
    evaluate_arm,
    identify_arm,
)
from daemon.arm.identify_groups import GROUP_REASON, LOADING
from daemon.arm.identify_parameters import heat_joints, pooled_heat_name
from daemon.arm.ir_regions import identification_regions
from daemon.model.identify import FittedParameter

#: At most this many refits before the final one (each drops what the last did not identify).
MAX_REFITS = 4
#: At most this many refits untangling trade-offs (each pools one: identify_groups).
MAX_UNTANGLE = 4
#: Heats that trade off are pooled only when the pool raises the weighted cost by less than
#: this (:func:`cost_rise`): the 95 % quantile of chi-square with one degree of freedom (the
#: data do not reject one factor for them). Measured on the UR5e: task A's and task B's pools
#: -10.8 and -21.8 (default truth; below zero: the pooled fit predicts the tool and the
#: section means better than the split one), 1.6, -3.3 and -0.3, 1.0 (corner-low, two pools
#: each); the calibration program on the corner-low truth rejects pooling the shoulder's and
#: the elbow's heats (18.0: their factors 0.59 and 0.50 on 0.6 and 0.5 are told apart),
#: where the pool had cost 5 points of removal on both tasks.
POOL_COST_RISE = 3.84
#: Heat factors the cycle could not identify that carry at least this share of its motor heat
#: are pooled with every other heated joint's when their own pool is not identified either.
POOL_ALL_SHARE = 0.1
#: A joint whose heat never exceeds this share of the largest joint heat is silent (rounding:
#: a joint the cycle never moves gets 1e-31 W from the motor model's arithmetic).
SILENT_SHARE = 1e-9


@dataclass(frozen=True)
class ArmCalibration:
    """A calibration's whole fit: ``full`` (every parameter asked for that the cycle can act
    on), ``final`` (the identified ones, refitted until each is identified in its own report)
    and why each parameter left out of ``final`` was (its name -> the reason, from the fit or
    the check that dropped it). Flags and values come from ``final``; the others keep their
    prior. A parameter of ``final`` flagged not identified is one the cycle told only in
    combination (:attr:`combined`): its value is used, its report says so."""

    names: tuple[str, ...]
    full: ArmIdentification | None
    final: ArmIdentification | None
    dropped: dict[str, str]

    @property
    def identified(self) -> tuple[str, ...]:
        """The parameters the final fit identifies (alone or as a pool)."""
        if self.final is None:
            return ()
        return tuple(p.name for p in self.final.parameters if p.identifiable)

    @property
    def combined(self) -> tuple[str, ...]:
        """The final fit's parameters told only in combination with others (identify_groups,
        none of them a split of joint heats: those are pooled): their values are the cycle's
        fit, used by the model and flagged not identified; on another cycle they may not
        hold (issue 29)."""
        if self.final is None:
            return ()
        return tuple(p.name for p in self.final.parameters if not p.identifiable)

    @property
    def pools(self) -> tuple[str, ...]:
        """The pooled heat factors the final fit identifies (``heat:1+2``)."""
        return tuple(n for n in self.identified if len(heat_joints(n)) > 1)

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
    """The calibration's fit (:func:`_identify_final`) on the IR regions' section means;
    again with the regions on a link's faces too when the means leave joint heats that carry
    at least POOL_ALL_SHARE of the cycle's heat unidentified (:func:`faces_needed`)."""
    names = [p.name for p in _checked_specs(run, model, parameters)]
    means = set(identification_regions(model.regions))
    if means == set(model.regions):
        return _identify_final(run, model, names, progress)
    on_means = _identify_final(
        dataclasses.replace(run, region_c={r: v for r, v in run.region_c.items() if r in means}),
        dataclasses.replace(model, regions={r: n for r, n in model.regions.items() if r in means}),
        [n for n in names if not n.startswith("offset:") or n.partition(":")[2] in means],
        progress,
    )
    if not faces_needed(run, on_means):
        return on_means
    if progress is not None:
        progress("again with the regions on the links' faces: the means leave the heats open")
    with_faces = _identify_final(run, model, names, progress)
    return with_faces if with_faces.final is not None else on_means


def faces_needed(run: ArmRunData, calibration: ArmCalibration) -> bool:
    """Whether a fit on the section means left joint heats unidentified (alone: a pool does
    not tell the split) that carry at least POOL_ALL_SHARE of the cycle's motor heat. The
    faces by a joint see where its heat enters the link, so they tell the shoulder's heat from
    the elbow's on a task that heats both in step, where the means cannot (issue 29, corner-
    high truth calibrated on task B: one pooled heat, 92.3 % of task A's drift removed; with
    the faces heats 1-3 identified, 97.5 %). They are not used otherwise: by a joint the
    controller's 50-mm model misses a face by ~0.2 degC, which pulls the fitted factors where
    the means already identify them (ir_regions.identification_regions)."""
    full = calibration.full
    if full is None:
        return False
    missed = [  # a multiple correlation alone is pooled on the means, not a reason for faces
        heat_joints(p.name)[0]
        for p in full.parameters
        if not p.identifiable
        and len(heat_joints(p.name)) == 1
        and not all(part.startswith(GROUP_REASON) for part in p.reason.split("; "))
    ]
    energy = np.abs(run.joint_heat_w).sum(axis=0)
    total = float(energy.sum())
    return total > 0.0 and sum(float(energy[j - 1]) for j in missed) >= POOL_ALL_SHARE * total


def _identify_final(
    run: ArmRunData,
    model: ArmModelSpec,
    parameters: Sequence[str],
    progress: Progress | None,
) -> ArmCalibration:
    """Every parameter (but :func:`silent_parameters`), then the identifiable ones refitted,
    again until the refit identifies each parameter it fits (at most MAX_REFITS refits; a
    value at its bound in a refit is not identified and is dropped like the others). Joint
    heats the full fit could not identify are refitted as one pooled factor
    (:func:`heat_pools`, the first pool the refit identifies); no pool identified: left at
    the preset's, as the others."""
    names = tuple(p.name for p in _checked_specs(run, model, parameters))
    dropped = silent_parameters(run, names)
    asked = [name for name in names if name not in dropped]
    if not asked:
        return ArmCalibration(names, None, None, dropped)
    full = identify_arm(run, model, asked, progress=progress)
    base, asked, pools = untangle(run, model, full, asked, dropped, progress=progress)
    names = (*names, *(pool for pool in pools if pool not in names))
    dropped.update(  # those told in combination are kept, flagged (_combined)
        {p.name: p.reason for p in base.parameters if not p.identifiable}
    )
    for name in base.entangled:
        dropped.pop(name)
    identified = [p.name for p in base.parameters if p.identifiable or p.name in base.entangled]
    for pool, members in heat_pools(run, base):
        kept = [name for name in identified if name not in members] + [pool]
        trial = dict(dropped)
        final = _refit(run, model, kept, trial, progress)
        if final is not None and pool in {p.name for p in final.parameters}:
            for name in members:  # identified together, not alone
                reason = trial.get(name, "identified alone")
                trial[name] = f"{reason}; its heat is fitted with the pool {pool}"
            return ArmCalibration((*names, pool), full, _combined(final), trial)
    final = base if not dropped.keys() & set(asked) else _refit(
        run, model, identified, dropped, progress
    )  # fmt: skip
    if final is None:
        dropped.update({name: dropped.get(name, "no refit identified it") for name in asked})
    return ArmCalibration(names, full, None if final is None else _combined(final), dropped)


#: How the report of a parameter fitted in combination begins (identify_groups; the model
#: uses its value, flagged; daemon/commands/arm_identify.py checks its physical range).
IN_COMBINATION = "fitted in combination, not identified alone"


def _combined(fit: ArmIdentification) -> ArmIdentification:
    """``fit`` with each parameter told only in combination (``fit.entangled``) reported as
    fitted in combination: its value is kept (keeping its prior instead made the others
    absorb the difference: UR5e default truth task A, convection at the preset's 1 on a
    truth of 0.8 put the capacity at 2.5), its flag says not identified."""
    parameters = tuple(
        dataclasses.replace(p, identifiable=False, reason=f"{IN_COMBINATION}: {p.reason}")
        if p.name in fit.entangled and not p.reason.startswith(IN_COMBINATION)
        else p
        for p in fit.parameters
    )
    return dataclasses.replace(fit, parameters=parameters)


def untangle(
    run: ArmRunData,
    model: ArmModelSpec,
    fit: ArmIdentification,
    asked: list[str],
    dropped: dict[str, str],
    *,
    progress: Progress | None,
) -> tuple[ArmIdentification, list[str], list[str]]:
    """``fit`` refitted while a parameter is flagged for a correlation alone (pairwise or
    with the others together: identify_groups), one trade-off at a time, the one the data
    see least: the joint heats taking part in it (two or more) become one pooled factor (the
    cycle fixes their sum, not their split) unless the data reject one factor for them
    (:func:`cost_rise` > POOL_COST_RISE: the split is told); a trade-off that is not a split
    of heats (the heats against the convection: the steady state fixes heat over
    convection), or whose pool is rejected, ends the untangling, its parameters kept and
    reported fitted in combination (:func:`_combined`; keeping their prior instead made the
    others absorb it). At most MAX_UNTANGLE refits.
    Returns the last fit, its parameter names and the pools made; ``dropped`` gets why each
    parameter left (issue 29: on a UR5e task the base's and the shoulder's heats traded off
    with the capacity, and the biased values were flagged identified)."""
    names = list(asked)
    pools: list[str] = []
    for _ in range(MAX_UNTANGLE):
        if not fit.entangled or len(names) < 2:
            break
        loading = dict(zip((p.name for p in fit.parameters), fit.weakest, strict=True))
        reasons = {p.name: p.reason for p in fit.parameters}
        heats = [n for n in names if heat_joints(n) and abs(loading[n]) >= LOADING]
        if len(heats) < 2:  # not a split of heats: reported in combination (_combined)
            break
        pool = pooled_heat_name(sorted(j for n in heats for j in heat_joints(n)))
        pooled_names = [n for n in names if n not in heats] + [pool]
        if progress is not None:
            progress(f"refit with the heats that trade off pooled: {pool}")
        pooled = identify_arm(run, model, pooled_names, progress=progress)
        if cost_rise(run, model, fit, pooled) > POOL_COST_RISE:  # the data tell the split
            break
        for name in heats:
            others = ", ".join(h for h in heats if h != name)
            dropped[name] = (
                f"{reasons[name] or 'identified'}; it trades off with {others} on this "
                f"cycle: its heat is fitted with the pool {pool}"
            )
        names, fit = pooled_names, pooled
        pools.append(pool)
    return fit, names, pools


def cost_rise(
    run: ArmRunData, model: ArmModelSpec, fit: ArmIdentification, constrained: ArmIdentification
) -> float:
    """How much the weighted cost rises from ``fit`` to ``constrained``, a fit of the same
    data with fewer parameters: a likelihood-ratio statistic, chi-square with one degree of
    freedom per parameter removed when the constraint holds. Judged on the tool and the IR
    regions' section means (ir_regions.identification_regions), each kind weighed by
    ``fit``'s own residual RMS there: the regions on a link's faces, where the controller's
    50-mm model misses the temperature by ~0.2 degC by a joint, rejected every pool (the
    UR5e default truth's task A: 36.5 with the faces, 0.8 without)."""
    means = set(identification_regions(model.regions))
    run = dataclasses.replace(run, region_c={r: v for r, v in run.region_c.items() if r in means})
    model = dataclasses.replace(
        model, regions={r: n for r, n in model.regions.items() if r in means}
    )
    before, after = evaluate_arm(fit, run, model), evaluate_arm(constrained, run, model)
    rise = 0.0
    for rms, new_rms, count in (
        (before.marker_rms_mm, after.marker_rms_mm, before.marker_samples),
        (before.temperature_rms_c, after.temperature_rms_c, before.temperature_samples),
    ):
        if rms and new_rms is not None:
            rise += count * ((new_rms / rms) ** 2 - 1.0)
    return rise


def _refit(
    run: ArmRunData,
    model: ArmModelSpec,
    kept: list[str],
    dropped: dict[str, str],
    progress: Progress | None,
) -> ArmIdentification | None:
    """``kept`` refitted until the refit identifies each parameter it fits (at most
    MAX_REFITS fits), each one a refit does not identify added to ``dropped``; None when
    nothing is left or the last refit still left one unidentified."""
    for _ in range(MAX_REFITS):
        if not kept:
            return None
        if progress is not None:
            progress(f"refit of the {len(kept)} identifiable parameters")
        final = identify_arm(run, model, kept, progress=progress)
        missed = {
            p.name: f"refit: {p.reason}"
            for p in final.parameters
            if not p.identifiable and p.name not in final.entangled
        }
        if not missed:
            return final
        dropped.update(missed)
        kept = [name for name in kept if name not in missed]
    return None


def heat_pools(run: ArmRunData, full: ArmIdentification) -> list[tuple[str, tuple[str, ...]]]:
    """The heat pools to try, in order, each (its name, the joint heats it replaces), when
    the full fit could not identify some joints' heat factors: one factor for those joints
    (two or more), then, if they carry at least POOL_ALL_SHARE of the cycle's heat, one for
    every heated joint. A task that heats the shoulder and the elbow together fixes their
    total heat, not its split; left at the preset's 1, the total's error went into the
    convection, the expansion and the capacity, which then transferred to no other cycle
    (issue 29, corner-low truth calibrated on task B: every joint heat dropped, convection
    1.69, capacity 4.1 and alpha 0.83 on a truth of 0.5, 0.7 and 0.9, 91.8 % of task A's drift
    removed; with one pooled heat 0.51, 0.71 and 0.90, 94.4 %). The wrists' heats, never
    identifiable and a few percent of the heat, pool with nothing else."""
    heats = {p.name: p for p in full.parameters if len(heat_joints(p.name)) == 1}
    missed = [  # one told in combination is kept (untangle), not pooled again
        name for name, p in heats.items() if not p.identifiable and name not in full.entangled
    ]
    if not missed:
        return []
    energy = np.abs(run.joint_heat_w).sum(axis=0)
    share = sum(float(energy[heat_joints(n)[0] - 1]) for n in missed) / float(energy.sum())
    pools: list[tuple[str, tuple[str, ...]]] = []
    if len(missed) >= 2:
        pools.append((pooled_heat_name([heat_joints(n)[0] for n in missed]), tuple(missed)))
    if share >= POOL_ALL_SHARE and len(heats) > len(missed):
        pools.append((pooled_heat_name([heat_joints(n)[0] for n in heats]), tuple(heats)))
    return pools


__all__ = [
    "MAX_REFITS",
    "MAX_UNTANGLE",
    "POOL_ALL_SHARE",
    "POOL_COST_RISE",
    "SILENT_SHARE",
    "ArmCalibration",
    "cost_rise",
    "faces_needed",
    "heat_pools",
    "identify_arm_final",
    "silent_parameters",
    "untangle",
]
