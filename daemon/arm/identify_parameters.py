"""The parameters of the arm's identification (issue 20, issue 29): what each name acts on, the
fit's bounds and the physical range a calibrated value must lie in (daemon/arm/identify.py
fits them).

Kinds (``kind`` or ``kind:ARGUMENT``):

* ``heat:J`` (joint J, 1-based), ``heat:J+K+...`` (those joints, one factor: a pool,
  :func:`pooled_heat_name`) or ``heat`` (every joint, one factor): the heat really released in
  the joint per watt the motor model predicts from the motion;
* ``convection``: h of every surface (links and joint housings);
* ``alpha``: the expansion coefficient of every link;
* ``capacity``: the heat capacity of every joint's motor and gearbox housing (their masses are
  estimates, daemon/arm/arm_network.py DEFAULT_JOINT_MASS_KG; the links' come from the arm
  file's masses and materials);
* ``share`` or ``share:J``: the bending share, the part of a joint's flange conductance that
  reaches the "+" row of its links (arm_network.JointBody.plus_share: where the motor housing
  sits heats that side first and bends the link); only for a model resolving the temperature
  across the links;
* ``offset`` (every IR region) or ``offset:REGION``: an additive IR offset (degC).

Factors (heat, convection, alpha, capacity) are fitted as logarithms, the share and the offsets
as themselves. The fit's bounds are wide (a factor of 10 either way, shares 0.3-0.99, offsets
+-5 degC) so that the data, not the bound, decide; a value AT a bound is not identified
(daemon.model.identify_uncertainty). The PHYSICAL range is narrower: what the quantity can be
on a real arm. A calibrated value outside it means the model absorbed something it does not
describe (a warming room soaked into convection, issue 29): ``identify --save`` and
``calibrate model`` refuse to save it without ``--force``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from daemon.arm.types import FloatArray
from daemon.model.identify_parameters import OFFSET_BOUND_C, SCALE_BOUNDS, IdentificationError
from daemon.model.identify_uncertainty import OFFSET_SE_LIMIT_C

ArmParameterKind = Literal["heat", "convection", "alpha", "capacity", "share", "offset"]
ARM_PARAMETER_KINDS: tuple[ArmParameterKind, ...] = (
    "heat",
    "convection",
    "alpha",
    "capacity",
    "share",
    "offset",
)
#: Kinds that change the network itself (its modes are recomputed); the others scale or shift
#: the responses of one network linearly.
NETWORK_KINDS: frozenset[str] = frozenset({"convection", "capacity", "share"})
#: Joins the joints of a pooled heat factor's name (``heat:1+3+5``).
POOL_SEPARATOR = "+"
#: The fit's bounds of a bending share: below 0.3 the housing's side would get the least of
#: its own flange's heat; 0.99 leaves the other row a path.
SHARE_BOUNDS = (0.3, 0.99)
#: A share's standard error beyond this (absolute) is not an identified share.
SHARE_SE_LIMIT = 0.1

#: The physical range of each kind (a calibrated value outside refuses the save), with why:
PHYSICAL_RANGES: Mapping[str, tuple[float, float]] = {
    # the motor model's losses: copper's resistance from 20 to 120 degC (x1.4), a gearbox's
    # friction run in or not (x2 either way): a factor of 4 either way at most
    "heat": (0.25, 4.0),
    # free convection of gases 2-25 W/m^2K (Incropera, Fundamentals of Heat and Mass Transfer,
    # Table 1.1) around the preset's 7.75 (thesis 3.4): x0.3 to x3
    "convection": (0.3, 3.0),
    # the link material's handbook expansion coefficient (6061-T6 23.4-23.6e-6 /K, thesis
    # Table 3.1); alloys, tempers and anodising of one family within about +-10 %
    "alpha": (0.88, 1.12),
    # a motor + gearbox housing's mass estimated to within a factor of 2
    "capacity": (0.5, 2.0),
    # the housing on one side of the link: at least half of its flange's heat enters that side
    # (0.5 heats both alike), not all of it; a little below 0.5 is within a fit's noise
    "share": (0.45, 0.95),
    # an IR camera's accuracy (+-2 degC, thesis 3.2.2) and an emissivity error
    "offset": (-3.0, 3.0),
}


@dataclass(frozen=True)
class ArmParameter:
    """One fitted group: ``kind`` acting on ``indices`` (joints) or ``targets`` (IR regions)."""

    name: str
    kind: ArmParameterKind
    targets: tuple[str, ...] = ()
    indices: tuple[int, ...] = ()

    @property
    def is_log(self) -> bool:
        return self.kind not in ("offset", "share")

    @property
    def bounds(self) -> tuple[float, float]:
        if self.is_log:
            return math.log(SCALE_BOUNDS[0]), math.log(SCALE_BOUNDS[1])
        if self.kind == "share":
            return SHARE_BOUNDS
        return -OFFSET_BOUND_C, OFFSET_BOUND_C

    @property
    def absolute_se_limit(self) -> float:
        """The largest standard error of an identified linear parameter (share or offset)."""
        return SHARE_SE_LIMIT if self.kind == "share" else OFFSET_SE_LIMIT_C

    @property
    def unit(self) -> str:
        return "" if self.kind == "share" else " degC"

    @property
    def changes_network(self) -> bool:
        return self.kind in NETWORK_KINDS

    @property
    def physical_range(self) -> tuple[float, float]:
        return PHYSICAL_RANGES[self.kind]

    def value(self, fitted: float) -> float:
        """The parameter's value (a factor, a share, degC) from its fitted number."""
        return math.exp(fitted) if self.is_log else float(fitted)


def default_parameters(
    joints: int, regions: Mapping[str, Sequence[int]], across_link: bool = False
) -> list[str]:
    """Each joint's heat, convection, alpha, the joints' capacity, with a model across the links
    the bending share, and (with IR regions) one offset per region."""
    names = [*(f"heat:{j + 1}" for j in range(joints)), "convection", "alpha", "capacity"]
    if across_link:
        names.append("share")
    return [*names, *(f"offset:{region}" for region in regions)]


def parse_parameters(
    names: Sequence[str],
    joints: int,
    regions: Mapping[str, Sequence[int]],
    across_link: bool = True,
) -> list[ArmParameter]:
    """The parameters from their names (module docstring); raises IdentificationError."""
    parsed: list[ArmParameter] = []
    for raw in names:
        spec = raw.strip()
        kind, _, argument = spec.partition(":")
        if kind in ("heat", "share"):
            if argument:
                numbers = argument.split(POOL_SEPARATOR) if kind == "heat" else [argument]
                if not all(n.isdigit() and 1 <= int(n) <= joints for n in numbers):
                    raise IdentificationError(f"{spec!r}: joints are numbered 1..{joints}")
                indices: tuple[int, ...] = tuple(int(n) - 1 for n in numbers)
            else:
                indices = tuple(range(joints))
            if kind == "share" and not across_link:
                raise IdentificationError(
                    f"{spec!r}: the model does not resolve the temperature across the links "
                    "(arm.bending off): there is no bending share to fit"
                )
            parsed.append(ArmParameter(spec, kind, (), indices))  # type: ignore[arg-type]
        elif kind in ("convection", "alpha", "capacity"):
            if argument:
                raise IdentificationError(f"{spec!r}: {kind} takes no argument")
            parsed.append(ArmParameter(spec, kind))  # type: ignore[arg-type]
        elif kind == "offset":
            if not regions:
                raise IdentificationError(f"{spec!r}: the run has no IR region")
            if argument and argument not in regions:
                raise IdentificationError(f"{spec!r}: unknown region {argument!r}")
            parsed.append(ArmParameter(spec, "offset", (argument,) if argument else tuple(regions)))
        else:
            raise IdentificationError(
                f"unknown parameter {spec!r}; kinds: heat[:J], convection, alpha, capacity, "
                "share[:J], offset[:R]"
            )
    if len({p.name for p in parsed}) != len(parsed):
        raise IdentificationError("a parameter is given twice")
    if not parsed:
        raise IdentificationError("no parameter to fit")
    for kind in ("heat", "share"):
        covered = [j for p in parsed if p.kind == kind for j in p.indices]
        if len(covered) != len(set(covered)):
            raise IdentificationError(f"a joint's {kind} is given twice")
    return parsed


@dataclass(frozen=True)
class ArmScales:
    """A parameter vector applied: heat factor per joint, convection and alpha factors, IR
    offset per region, the joints' capacity factor and each joint's bending share (None: the
    model's own)."""

    heat: FloatArray
    convection: float
    alpha: float
    offsets_c: dict[str, float]
    capacity: float = 1.0
    shares: tuple[float, ...] | None = None


def pooled_heat_name(joints: Sequence[int]) -> str:
    """The name of one heat factor shared by ``joints`` (1-based): ``heat:1+3+5``."""
    return "heat:" + POOL_SEPARATOR.join(str(j) for j in sorted(joints))


def heat_joints(name: str) -> tuple[int, ...]:
    """The joints (1-based) a ``heat:J`` or pooled ``heat:J+K`` name acts on; () for others
    (a plain ``heat`` included: it names no joint)."""
    kind, _, argument = name.strip().partition(":")
    numbers = argument.split(POOL_SEPARATOR)
    if kind != "heat" or not all(n.isdigit() for n in numbers):
        return ()
    return tuple(int(n) for n in numbers)


def initial_values(specs: Sequence[ArmParameter], prior_shares: Sequence[float]) -> FloatArray:
    """The fit's start: every factor 1, every offset 0, every share the model's own."""
    return np.array(
        [
            float(np.mean([prior_shares[j] for j in spec.indices])) if spec.kind == "share" else 0.0
            for spec in specs
        ]
    )


def apply_values(
    specs: Sequence[ArmParameter],
    values: FloatArray,
    joints: int,
    regions: Sequence[str],
    prior_shares: Sequence[float] | None = None,
) -> ArmScales:
    """The scales a fitted vector stands for (shares not fitted stay ``prior_shares``)."""
    heat = np.ones(joints)
    convection = alpha = capacity = 1.0
    offsets = dict.fromkeys(regions, 0.0)
    shares = None if prior_shares is None else list(prior_shares)
    for spec, value in zip(specs, values, strict=True):
        if spec.kind == "heat":
            heat[list(spec.indices)] *= math.exp(value)
        elif spec.kind == "convection":
            convection *= math.exp(value)
        elif spec.kind == "alpha":
            alpha *= math.exp(value)
        elif spec.kind == "capacity":
            capacity *= math.exp(value)
        elif spec.kind == "share":
            if shares is None:
                shares = [0.5] * joints
            for j in spec.indices:
                shares[j] = float(value)
        else:
            for region in spec.targets:
                offsets[region] += float(value)
    return ArmScales(
        heat, convection, alpha, offsets, capacity, None if shares is None else tuple(shares)
    )


def outside_physical_range(name: str, value: float) -> str | None:
    """Why ``value`` of parameter ``name`` is not physical (None when it is)."""
    kind = name.partition(":")[0]
    low, high = PHYSICAL_RANGES.get(kind, (-math.inf, math.inf))
    if low <= value <= high:
        return None
    return f"{name} = {value:.4g} is outside its physical range [{low:g}, {high:g}]"


__all__ = [
    "ARM_PARAMETER_KINDS",
    "NETWORK_KINDS",
    "PHYSICAL_RANGES",
    "POOL_SEPARATOR",
    "SHARE_BOUNDS",
    "ArmParameter",
    "ArmParameterKind",
    "ArmScales",
    "apply_values",
    "default_parameters",
    "heat_joints",
    "initial_values",
    "outside_physical_range",
    "parse_parameters",
    "pooled_heat_name",
]
