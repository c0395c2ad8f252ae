"""The priors of an arm controller's online estimates (daemon/arm/controller.py): the
adaptation's and the IR observer's, from the model's factors and what its identification left
of each. Pure."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from daemon.arm.adaptation import PRIOR_LOG_SIGMA
from daemon.arm.arm_model import ArmModel
from daemon.arm.run import FloatArray

#: The observer's prior on an IR offset the model file gives no uncertainty for (degC): the
#: FLIR's +-2 degC accuracy, as the two-link observer (daemon/model/observer.py).
DEFAULT_OFFSET_SIGMA_C = 2.0
#: The least prior 1-sigma of a log factor the IR observer adapts (an identified factor's
#: relative standard error can be tiny; the observer must still be able to move it).
OBSERVER_MIN_LOG_SIGMA = 0.05


def adaptation_priors(
    identified: ArmModel | None,
    heat_scales: Sequence[float] | FloatArray,
    alpha_scale: float,
    regions: Mapping[str, object] | None = None,
) -> dict[str, tuple[float, float]]:
    """The adaptation's prior: this model's factors; the 1-sigma of an identified one its
    relative standard error (the default where not identified); each IR region's offset
    (``regions``) the identified one with its 1-sigma, else 0 within the camera's
    accuracy (DEFAULT_OFFSET_SIGMA_C)."""
    fitted = {} if identified is None else {p.name: p for p in identified.parameters}
    values = {f"heat:{j + 1}": float(v) for j, v in enumerate(heat_scales)}
    values["alpha"] = alpha_scale
    values["convection"] = 1.0 if identified is None else identified.convection_scale
    priors = {}
    for name, value in values.items():
        p = fitted.get(name)
        sigma = PRIOR_LOG_SIGMA
        if p is not None and p.identifiable and p.relative_error is not None:
            sigma = max(float(p.relative_error), 0.01)
        priors[name] = (value, sigma)
    share = fitted.get("share")
    if share is not None and share.identifiable and share.standard_error is not None:
        # an identified share keeps its own (absolute) 1-sigma, not the preset's wide prior:
        # the IR alone would otherwise move it to what fits the regions, not the tool
        priors["share"] = (float(share.value), max(float(share.standard_error), 0.005))
    offsets = {} if identified is None else identified.ir_offsets_c
    spreads = {} if identified is None else identified.ir_offset_sigma_c
    for region in regions or ():
        spread = float(spreads.get(region, math.inf))
        if region not in offsets or not math.isfinite(spread) or spread <= 0.0:
            priors[f"offset:{region}"] = (0.0, DEFAULT_OFFSET_SIGMA_C)
        else:
            priors[f"offset:{region}"] = (float(offsets[region]), spread)
    return priors


def observer_adapted(
    identified: ArmModel | None, joint_node_names: Sequence[str]
) -> tuple[list[str], dict[str, tuple[float, float]]]:
    """What the IR observer estimates with the temperatures (issue 29): each joint's heat
    (at its node) and the convection, as factors of this model's (prior 1), each with
    the 1-sigma its identification left (PRIOR_LOG_SIGMA where not identified). Without
    them a wrong heat or convection comes back between two IR readings: the filter
    corrected the temperatures, never what drives them (corner-low truth, preset with the
    IR: 43 % of the drift removed with the temperatures alone)."""
    fitted = {} if identified is None else {p.name: p for p in identified.parameters}

    def sigma(name: str) -> float:
        p = fitted.get(name)
        if p is not None and p.identifiable and p.relative_error is not None:
            return max(float(p.relative_error), OBSERVER_MIN_LOG_SIGMA)
        return PRIOR_LOG_SIGMA

    names: list[str] = []
    priors: dict[str, tuple[float, float]] = {}
    for j, node in enumerate(joint_node_names):
        names.append(f"heat:{node}")
        priors[f"heat:{node}"] = (1.0, sigma(f"heat:{j + 1}"))
    names.append("convection")
    priors["convection"] = (1.0, sigma("convection"))
    return names, priors
