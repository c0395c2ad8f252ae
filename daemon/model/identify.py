"""Grey-box identification of a thermal network from a recorded warm-up (issue 9).

With Table 5.1 as printed the network's slowest time constant is ~2,200 s where the bench
showed ~520 s (DESIGN.md "Table 5.1"): "reaching the measured curve is the job of
identification from recorded data". The network keeps its structure (nodes, capacitances,
positions); a few physically meaningful groups of its parameters are scaled to fit a run's
IR region temperatures and its measured deformation:

* ``convection`` (every node) or ``convection:A..B`` (the nodes between nodes A and B): h, so
  the conductance to ambient (faces and end faces);
* ``heat`` (all heaters, one factor) or ``heat:N`` (heater node N): the heat really entering
  the link per watt commanded;
* ``contact:N``: the resistances joining node N (a shaft) to its neighbours;
* ``alpha``: the effective expansion coefficient of every node;
* ``offset`` (every IR region) or ``offset:REGION``: an additive IR sensor offset (degC).

Scale factors are fitted as logarithms (positive by construction, bounded to [1/10, 10]),
offsets linearly within +-5 degC; ``scipy.optimize.least_squares`` with a robust loss
(``soft_l1``), since an IR frame or a centroid can fail. The responses come from the exact
zero-order-hold solution of the network (the modes of :mod:`daemon.model.model`), evaluated
at every sample time at once. Standard errors and correlations come from the Jacobian at the
solution, ``cov = s^2 (J^T J)^-1`` with ``s^2`` the weighted residual variance.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from scipy.optimize import least_squares

from daemon.analysis.steps import RunSteps
from daemon.model.calibration import (
    CALIBRATION_TABLE,
    CalibratedParameter,
    Calibration,
    offset_sigmas_c,
)
from daemon.model.model import NetworkModes
from daemon.model.network import FloatArray, NetworkError, ThermalNetwork

logger = logging.getLogger(__name__)

ParameterKind = Literal["convection", "heat", "contact", "alpha", "offset"]
PARAMETER_KINDS: tuple[ParameterKind, ...] = ("convection", "heat", "contact", "alpha", "offset")

#: Bounds of a fitted scale factor (its logarithm is fitted) and of an IR offset (degC; the
#: FLIR A40M's accuracy is +-2 degC, thesis 3.2.2).
SCALE_BOUNDS = (0.1, 10.0)
OFFSET_BOUND_C = 5.0
#: A parameter is not identifiable when its relative standard error exceeds this (a log SE
#: of 0.5 is a factor e^0.5 = 1.65 either way), when an offset's SE exceeds OFFSET_SE_LIMIT_C,
#: when it loads a direction of J^T J that the data do not see (singular value ratio below
#: SINGULAR_RATIO), or when it correlates with another one beyond CORRELATION_LIMIT.
RELATIVE_SE_LIMIT = 0.5
OFFSET_SE_LIMIT_C = 1.0
SINGULAR_RATIO = 1e-7
CORRELATION_LIMIT = 0.995
#: The robust loss and its scale (in units of a residual's standard deviation).
LOSS = "soft_l1"
LOSS_SCALE = 3.0
#: Relative step of the central differences of the reported Jacobian.
JACOBIAN_STEP = 1e-5

HeatSchedule = tuple[tuple[float, dict[str, float]], ...]


class IdentificationError(ValueError):
    """The run or the parameter list cannot be used for identification."""


# -- data ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunData:
    """A run as identification sees it: sample times (s from a cold start at ambient), the IR
    region means (degC, NaN where missing), the measured deformation along the link (unscaled
    µm, NaN where missing) and the heat commanded: ``(from_s, {node: W})`` pieces."""

    time_s: FloatArray
    region_c: dict[str, FloatArray]
    deformation_um: FloatArray
    heat_schedule: HeatSchedule
    ambient_c: float = 22.0
    name: str = "run"

    def __post_init__(self) -> None:
        count = self.time_s.size
        if count < 2:
            raise IdentificationError(f"{self.name}: needs at least two samples, got {count}")
        if not np.all(np.isfinite(self.time_s)) or np.any(np.diff(self.time_s) < 0):
            raise IdentificationError(f"{self.name}: times must be finite and increasing")
        for region, values in self.region_c.items():
            if values.shape != (count,):
                raise IdentificationError(f"{self.name}: region {region!r} has the wrong length")
        if self.deformation_um.shape != (count,):
            raise IdentificationError(f"{self.name}: deformation has the wrong length")


def heat_schedule(heat_w: Mapping[str, float], heater_off_s: float | None = None) -> HeatSchedule:
    """The bench's schedule (drivers.sim.bench): heaters on at 0, off at ``heater_off_s``."""
    on: HeatSchedule = ((0.0, dict(heat_w)),)
    return on if heater_off_s is None else (*on, (float(heater_off_s), {}))


def measured_deformation_um(steps: RunSteps) -> FloatArray:
    """The links' own deformation each step (unscaled µm along the link): the measured error
    with the commanded compensation taken out, divided by the deformation scale.

    residual = scale x true + offset (the robot moved by the offset, thesis 6.4.4) and the
    offset is -scale x predicted, so ``residual - compensation = scale x true``; in an ``off``
    run the offset is 0 and the drift IS the scaled deformation."""
    compensation = np.nan_to_num(steps.compensation_um, nan=0.0)
    deformation: FloatArray = (steps.residual_um - compensation) / steps.deformation_scale
    return deformation


def run_data_from_steps(
    steps: RunSteps,
    heat: HeatSchedule,
    *,
    ambient_c: float = 22.0,
    name: str | None = None,
) -> RunData:
    """A recorded or exported run (daemon.analysis.steps) as :class:`RunData`; the measurement
    time of a step is when it ran (``actual_s``), else when it was scheduled."""
    actual = steps.numeric.get("actual_s")
    times = actual if actual is not None and np.all(np.isfinite(actual)) else steps.time_s
    return RunData(
        time_s=np.asarray(times, dtype=np.float64),
        region_c={region: np.asarray(v, np.float64) for region, v in steps.ir_mean_c.items()},
        deformation_um=measured_deformation_um(steps),
        heat_schedule=heat,
        ambient_c=ambient_c,
        name=name or (f"run {steps.run_id}" if steps.run_id else "run"),
    )


# -- the exact response at every sample time ----------------------------------------------------


def _drive_w(network: ThermalNetwork, heat_w: FloatArray, ambient_c: float) -> FloatArray:
    drive: FloatArray = heat_w + network.ambient_conductance_w_per_c * ambient_c
    return drive


def heat_vector(network: ThermalNetwork, heat_w: Mapping[str, float]) -> FloatArray:
    """Heat inputs keyed by node name as a vector (a key naming no node: NetworkError)."""
    return network.heat_by_name(heat_w)


def simulate_temperatures(
    network: ThermalNetwork,
    schedule: Sequence[tuple[float, FloatArray]],
    ambient_c: float,
    times_s: FloatArray,
) -> FloatArray:
    """Node temperatures (samples x nodes) from ambient at t = 0 under piecewise-constant heat
    vectors ``schedule`` = ``[(from_s, heat per node W)]``: the zero-order-hold solution of
    ThermalModel's exact stepper in closed form (each mode ``z`` relaxes as
    ``z_ss + (z0 - z_ss) e^{-lam (t - t0)}``), so a whole run costs one matrix product."""
    modes = NetworkModes(network)
    rates, vectors, root_c = modes.rates, modes.vectors, modes.root_c
    z = vectors.T @ (root_c * np.full(network.node_count, ambient_c))
    pieces = sorted(schedule, key=lambda piece: piece[0])
    if not pieces or pieces[0][0] > 0.0:
        pieces.insert(0, (0.0, np.zeros(network.node_count)))
    result = np.empty((times_s.size, network.node_count))
    for k, (start, heat) in enumerate(pieces):
        end = pieces[k + 1][0] if k + 1 < len(pieces) else math.inf
        steady = (vectors.T @ (_drive_w(network, heat, ambient_c) / root_c)) / rates
        inside = (times_s >= start) & (times_s < end) if k else (times_s < end)
        if inside.any():
            decay = np.exp(-np.outer(times_s[inside] - start, rates))
            result[inside] = ((steady + (z - steady) * decay) @ vectors.T) / root_c
        if math.isfinite(end):
            z = steady + (z - steady) * np.exp(-rates * (end - start))
    return result


# -- parameters ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Parameter:
    """One fitted group: ``kind`` acting on ``targets`` (node indices, or region names)."""

    name: str
    kind: ParameterKind
    targets: tuple[str, ...]
    node_indices: tuple[int, ...] = ()

    @property
    def is_log(self) -> bool:
        return self.kind != "offset"

    @property
    def bounds(self) -> tuple[float, float]:
        if self.is_log:
            return math.log(SCALE_BOUNDS[0]), math.log(SCALE_BOUNDS[1])
        return -OFFSET_BOUND_C, OFFSET_BOUND_C


def default_parameters(network: ThermalNetwork, regions: Mapping[str, Sequence[str]]) -> list[str]:
    """Convection, each heater's heat input, the expansion coefficient and (with IR regions)
    one common IR offset."""
    names = ["convection", *(f"heat:{node}" for node in network.heater_nodes), "alpha"]
    return [*names, "offset"] if regions else names


def parse_parameters(
    specs: Sequence[str],
    network: ThermalNetwork,
    regions: Mapping[str, Sequence[str]],
) -> list[Parameter]:
    """Parameters from their names (module docstring); raises IdentificationError."""
    parsed: list[Parameter] = []
    for spec in specs:
        kind, _, argument = spec.strip().partition(":")
        if kind not in PARAMETER_KINDS:
            raise IdentificationError(
                f"unknown parameter {spec!r}; kinds: {', '.join(PARAMETER_KINDS)}"
            )
        try:
            parsed.append(_parameter(spec.strip(), kind, argument, network, regions))
        except NetworkError as err:
            raise IdentificationError(f"parameter {spec!r}: {err}") from err
    names = [p.name for p in parsed]
    if len(set(names)) != len(names):
        raise IdentificationError(f"a parameter is given twice: {', '.join(names)}")
    if not parsed:
        raise IdentificationError("no parameter to fit")
    return parsed


def _parameter(
    spec: str,
    kind: ParameterKind,
    argument: str,
    network: ThermalNetwork,
    regions: Mapping[str, Sequence[str]],
) -> Parameter:
    every = tuple(range(network.node_count))
    if kind == "offset":
        if not regions:
            raise IdentificationError(f"parameter {spec!r}: the run has no IR region")
        if argument and argument not in regions:
            raise IdentificationError(
                f"parameter {spec!r}: unknown region; regions: {', '.join(regions)}"
            )
        return Parameter(spec, kind, (argument,) if argument else tuple(regions))
    if kind == "alpha":
        if argument:
            raise IdentificationError(f"parameter {spec!r}: alpha takes no argument")
        return Parameter(spec, kind, (), every)
    if kind == "convection":
        if not argument:
            return Parameter(spec, kind, (), every)
        first, sep, last = argument.partition("..")
        if not sep:
            raise IdentificationError(f"parameter {spec!r}: write convection:A..B (node names)")
        low, high = sorted(
            float(network.positions_mm[network.node_index(node)]) for node in (first, last)
        )
        inside = (network.positions_mm >= low) & (network.positions_mm <= high)
        return Parameter(spec, kind, (first, last), tuple(int(i) for i in np.flatnonzero(inside)))
    if kind == "heat":
        nodes = (argument,) if argument else network.heater_nodes
        if not nodes:
            raise IdentificationError(f"parameter {spec!r}: the network names no heater node")
        indices = tuple(network.node_named(n, "heat node") for n in nodes)  # by name (issue 19)
        return Parameter(spec, kind, tuple(nodes), indices)
    if not argument:
        raise IdentificationError(f"parameter {spec!r}: write contact:NODE (a shaft's node)")
    index = network.node_index(argument)
    if not any(index in (r.a, r.b) for r in network.resistances):
        raise IdentificationError(f"parameter {spec!r}: node {argument!r} joins no other node")
    return Parameter(spec, kind, (argument,), (index,))


@dataclass(frozen=True)
class Applied:
    """A parameter vector applied: the scaled network, heat factor per node, offset per
    region."""

    network: ThermalNetwork
    heat_factor: FloatArray
    offsets_c: dict[str, float]


def apply_parameters(
    network: ThermalNetwork,
    parameters: Sequence[Parameter],
    values: FloatArray,
    regions: Mapping[str, Sequence[str]],
) -> Applied:
    """The network with fitted values (log scales and linear offsets) applied."""
    convection = np.ones(network.node_count)
    alpha = np.ones(network.node_count)
    heat = np.ones(network.node_count)
    contact = np.ones(network.node_count)
    offsets = dict.fromkeys(regions, 0.0)
    for parameter, value in zip(parameters, values, strict=True):
        factor = math.exp(value) if parameter.is_log else 1.0
        chosen = list(parameter.node_indices)
        if parameter.kind == "convection":
            convection[chosen] *= factor
        elif parameter.kind == "alpha":
            alpha[chosen] *= factor
        elif parameter.kind == "heat":
            heat[chosen] *= factor
        elif parameter.kind == "contact":
            contact[chosen] *= factor
        else:
            for region in parameter.targets:
                offsets[region] += float(value)
    resistances = tuple(
        dataclasses.replace(r, r_c_per_w=r.r_c_per_w * contact[r.a] * contact[r.b])
        for r in network.resistances
    )
    scaled = dataclasses.replace(
        network,
        r_ambient_c_per_w=network.r_ambient_c_per_w / convection,
        r_end_c_per_w=network.r_end_c_per_w / convection,
        alpha_per_c=network.alpha_per_c * alpha,
        resistances=resistances,
    )
    return Applied(scaled, heat, offsets)


def observation_matrix(
    network: ThermalNetwork, regions: Mapping[str, Sequence[str]]
) -> dict[str, FloatArray]:
    """Each IR region's row: the mean of the nodes it covers (IrRegion.node ties a region to
    a node; a region over several nodes sees their mean)."""
    rows: dict[str, FloatArray] = {}
    for region, nodes in regions.items():
        if not nodes:
            raise IdentificationError(f"region {region!r} is tied to no node")
        row = np.zeros(network.node_count)
        for node in nodes:
            row[network.node_index(node)] += 1.0 / len(nodes)
        rows[region] = row
    return rows


# -- the fit ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FitQuality:
    """Residual RMS of the temperatures (degC) and of the deformation (µm), and counts."""

    temperature_rms_c: float | None
    deformation_rms_um: float | None
    temperature_samples: int
    deformation_samples: int


@dataclass(frozen=True)
class FittedParameter:
    name: str
    value: float  # the scale factor (log kinds) or the offset in degC
    standard_error: float  # of ``value`` (delta method for scale factors)
    relative_error: float | None  # SE of the logarithm: the relative SE of a scale factor
    identifiable: bool
    reason: str = ""


def find_parameter(parameters: Sequence[FittedParameter], name: str) -> FittedParameter:
    """The fitted parameter called ``name`` (KeyError when there is none)."""
    for parameter in parameters:
        if parameter.name == name:
            return parameter
    raise KeyError(name)


def parameters_report(
    parameters: Sequence[FittedParameter], correlation: FloatArray
) -> dict[str, Any]:
    """The ``parameters`` and ``correlation`` entries of an identification's JSON document
    (the two-link network's and the arm's alike)."""
    names = [p.name for p in parameters]
    return {
        "parameters": [dataclasses.asdict(p) for p in parameters],
        "correlation": {
            a: {b: float(correlation[i, j]) for j, b in enumerate(names)}
            for i, a in enumerate(names)
        },
    }


@dataclass(frozen=True)
class IdentificationResult:
    parameters: tuple[FittedParameter, ...]
    correlation: FloatArray
    fit: FitQuality
    network: ThermalNetwork  # the identified network (heat inputs: heat_w)
    heat_w: dict[str, float]  # the heat each heater node receives, as identified (W)
    offsets_c: dict[str, float]
    values: FloatArray  # raw fitted vector (log scales, offsets)
    specs: tuple[Parameter, ...]
    success: bool
    message: str
    warnings: tuple[str, ...] = ()
    validation: FitQuality | None = field(default=None)

    def parameter(self, name: str) -> FittedParameter:
        return find_parameter(self.parameters, name)

    def to_dict(self) -> dict[str, Any]:
        return {
            **parameters_report(self.parameters, self.correlation),
            "fit": dataclasses.asdict(self.fit),
            "validation": None if self.validation is None else dataclasses.asdict(self.validation),
            "heat_w": self.heat_w,
            "offsets_c": self.offsets_c,
            "success": self.success,
            "message": self.message,
            "warnings": list(self.warnings),
        }


class _Problem:
    """Weighted residuals of a run for a parameter vector."""

    def __init__(
        self,
        run: RunData,
        network: ThermalNetwork,
        parameters: Sequence[Parameter],
        regions: Mapping[str, Sequence[str]],
    ) -> None:
        self.run, self.network, self.parameters = run, network, list(parameters)
        self.regions = {r: nodes for r, nodes in regions.items() if r in run.region_c}
        self.rows = observation_matrix(network, self.regions)
        self.heat = [(start, heat_vector(network, w)) for start, w in run.heat_schedule]
        self.masks = {r: np.isfinite(run.region_c[r]) for r in self.regions}
        self.deformation_mask = np.isfinite(run.deformation_um)
        self.temperature_sigma_c = 1.0
        self.deformation_sigma_um = 1.0

    def predictions(self, values: FloatArray) -> tuple[dict[str, FloatArray], FloatArray]:
        applied = apply_parameters(self.network, self.parameters, values, self.regions)
        schedule = [(start, heat * applied.heat_factor) for start, heat in self.heat]
        temperatures = simulate_temperatures(
            applied.network, schedule, self.run.ambient_c, self.run.time_s
        )
        regions = {r: temperatures @ row + applied.offsets_c[r] for r, row in self.rows.items()}
        weights = applied.network.deformation_weights_um_per_c()
        deformation: FloatArray = (temperatures - self.run.ambient_c) @ weights
        return regions, deformation

    def raw_residuals(self, values: FloatArray) -> tuple[FloatArray, FloatArray]:
        regions, deformation = self.predictions(values)
        temperature = [(regions[r] - self.run.region_c[r])[self.masks[r]] for r in self.rows]
        flat_t = np.concatenate(temperature) if temperature else np.zeros(0)
        flat_d = (deformation - self.run.deformation_um)[self.deformation_mask]
        return flat_t, flat_d

    def weighted(self, values: FloatArray) -> FloatArray:
        temperature, deformation = self.raw_residuals(values)
        return np.concatenate(
            [temperature / self.temperature_sigma_c, deformation / self.deformation_sigma_um]
        )

    def quality(self, values: FloatArray) -> FitQuality:
        temperature, deformation = self.raw_residuals(values)
        return FitQuality(
            temperature_rms_c=rms(temperature),
            deformation_rms_um=rms(deformation),
            temperature_samples=int(temperature.size),
            deformation_samples=int(deformation.size),
        )


# -- the uncertainty report, shared with the arm's identification (daemon.arm.identify) ------


def rms(values: FloatArray) -> float | None:
    """The root mean square of ``values``; None when there is none."""
    return float(np.sqrt(np.mean(values**2))) if values.size else None


def central_jacobian(
    residuals: Callable[[FloatArray], FloatArray],
    values: FloatArray,
    step: float = JACOBIAN_STEP,
    *,
    relative: bool = True,
) -> FloatArray:
    """The Jacobian of ``residuals`` at ``values`` by central differences: each parameter's
    step is ``step`` times max(1, |value|) when ``relative``, else ``step``."""
    columns = []
    for k in range(values.size):
        h = step * max(1.0, abs(values[k])) if relative else step
        up, down = values.copy(), values.copy()
        up[k] += h
        down[k] -= h
        columns.append((residuals(up) - residuals(down)) / (2.0 * h))
    return np.column_stack(columns)


def residual_variance(residuals: FloatArray, parameters: int) -> float:
    """``s^2``: the weighted residuals' sum of squares over their degrees of freedom."""
    return float(residuals @ residuals) / max(residuals.size - parameters, 1)


def identify(
    run: RunData,
    network: ThermalNetwork,
    regions: Mapping[str, Sequence[str]],
    parameters: Sequence[str] | None = None,
    *,
    temperature_sigma_c: float = 0.1,
    deformation_sigma_um: float = 1.0,
) -> IdentificationResult:
    """Fit ``parameters`` (names, module docstring; default :func:`default_parameters`) of
    ``network`` to ``run``. ``regions`` ties each IR region to the node(s) it covers.

    Two passes: the first weighs the residuals with the given sigmas, the second with the
    first pass's residual RMS of each kind, so that temperatures and deformation count by
    their own noise; the covariance is then ``s^2 (J^T J)^-1`` with ``s^2`` the weighted
    residual variance (close to 1 when the model is right)."""
    used_regions = {r: tuple(n) for r, n in regions.items() if r in run.region_c}
    names = list(parameters) if parameters else default_parameters(network, used_regions)
    specs = parse_parameters(names, network, used_regions)
    problem = _Problem(run, network, specs, used_regions)
    count = int(sum(m.sum() for m in problem.masks.values()) + problem.deformation_mask.sum())
    if count <= len(specs):
        raise IdentificationError(
            f"{run.name}: {count} measurements cannot fit {len(specs)} parameters"
        )
    lower = np.array([p.bounds[0] for p in specs])
    upper = np.array([p.bounds[1] for p in specs])
    values = np.zeros(len(specs))
    result = _fit_pass(
        problem,
        values,
        lower,
        upper,
        temperature_sigma_c=temperature_sigma_c,
        deformation_sigma_um=deformation_sigma_um,
    )
    # Second pass: each kind weighed by its own residual RMS.
    quality = problem.quality(np.asarray(result.x, dtype=np.float64))
    result = _fit_pass(
        problem,
        np.asarray(result.x, dtype=np.float64),
        lower,
        upper,
        temperature_sigma_c=max(quality.temperature_rms_c or temperature_sigma_c, 1e-3),
        deformation_sigma_um=max(quality.deformation_rms_um or deformation_sigma_um, 1e-3),
    )
    values = np.asarray(result.x, dtype=np.float64)
    jacobian = central_jacobian(problem.weighted, values)
    variance = residual_variance(problem.weighted(values), len(specs))
    fitted, correlation, warnings = uncertainty(specs, values, jacobian, variance)
    applied = apply_parameters(network, specs, values, used_regions)
    heat_nodes = {
        network.node_names[network.node_index(node)]
        for _, heat in run.heat_schedule
        for node in heat
    }
    nominal = max(
        (heat_vector(network, w) for _, w in run.heat_schedule),
        key=lambda vector: float(vector.sum()),
        default=np.zeros(network.node_count),
    )
    heat_w = {
        node: float(
            nominal[network.node_index(node)] * applied.heat_factor[network.node_index(node)]
        )
        for node in sorted(heat_nodes, key=network.node_index)
    }
    fit = problem.quality(values)
    logger.info(
        "%s: identified %s; RMS %s degC, %s um",
        run.name,
        ", ".join(f"{p.name}={p.value:.4g}" for p in fitted),
        fit.temperature_rms_c,
        fit.deformation_rms_um,
    )
    return IdentificationResult(
        parameters=tuple(fitted),
        correlation=correlation,
        fit=fit,
        network=dataclasses.replace(
            applied.network,
            name=f"{network.name}-identified",
            description=f"{network.name} identified from {run.name}: "
            + ", ".join(f"{p.name} {p.value:.4g}" for p in fitted),
            heat_w=np.array([heat_w.get(n, 0.0) for n in network.node_names]),
        ),
        heat_w=heat_w,
        offsets_c=applied.offsets_c,
        values=values,
        specs=tuple(specs),
        success=bool(result.success),
        message=str(result.message),
        warnings=tuple(warnings),
    )


def _fit_pass(
    problem: _Problem,
    start: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
    *,
    temperature_sigma_c: float,
    deformation_sigma_um: float,
) -> Any:
    problem.temperature_sigma_c = temperature_sigma_c
    problem.deformation_sigma_um = deformation_sigma_um
    return least_squares(
        problem.weighted,
        start,
        bounds=(lower, upper),
        loss=LOSS,
        f_scale=LOSS_SCALE,
        x_scale=1.0,
        diff_step=1e-6,
        max_nfev=200 * start.size,
    )


def _normalised_information(jacobian: FloatArray) -> tuple[FloatArray, FloatArray]:
    """J^T J normalised by its diagonal (so its singular values compare directions, not
    units), and the square root of that diagonal."""
    information = jacobian.T @ jacobian
    diagonal = np.sqrt(np.clip(np.diag(information), 1e-300, None))
    return information / np.outer(diagonal, diagonal), diagonal


def conditioning(jacobian: FloatArray) -> float:
    """The largest over the smallest singular value of the normalised J^T J."""
    normalised, _ = _normalised_information(jacobian)
    singular = np.linalg.svd(normalised, compute_uv=False)
    return float(singular[0] / max(singular[-1], 1e-300))


def uncertainty(
    specs: Sequence[Parameter], values: FloatArray, jacobian: FloatArray, variance: float
) -> tuple[list[FittedParameter], FloatArray, list[str]]:
    """Standard errors, correlations and identifiability from ``J`` at the solution
    (``values``, the fitted vector: log scales and offsets; ``variance``, the weighted
    residual variance :func:`residual_variance`): the fitted parameters, their correlation
    matrix and a warning for each one the data do not identify.

    J^T J is normalised by its diagonal before the pseudo-inverse, so the singular values
    compare directions, not units; a parameter loading a direction with a singular value
    below SINGULAR_RATIO x the largest is one the data cannot tell from the others. It is
    not identifiable either when |correlation| with another exceeds CORRELATION_LIMIT, when
    its relative SE exceeds RELATIVE_SE_LIMIT (an offset's SE OFFSET_SE_LIMIT_C), or when it
    ends at its bound. The two-link and the arm identification (daemon.arm.identify) both
    report with it."""
    normalised, diagonal = _normalised_information(jacobian)
    u, singular, _ = np.linalg.svd(normalised)
    weak = singular < SINGULAR_RATIO * singular[0]
    inverse = (u[:, ~weak] / singular[~weak]) @ u[:, ~weak].T
    if weak.any():  # the unseen directions have unbounded variance: say so, not a small number
        inverse = inverse + (u[:, weak] / (SINGULAR_RATIO * singular[0])) @ u[:, weak].T
    covariance = variance * inverse / np.outer(diagonal, diagonal)
    se_raw = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    correlation = covariance / np.outer(np.where(se_raw > 0, se_raw, 1.0), se_raw + (se_raw == 0))
    np.fill_diagonal(correlation, 1.0)
    loading = (np.abs(u[:, weak]) > 0.1).any(axis=1) if weak.any() else np.zeros(len(specs), bool)
    fitted: list[FittedParameter] = []
    warnings: list[str] = []
    for k, spec in enumerate(specs):
        reasons = []
        if loading[k]:
            reasons.append("J^T J is near-singular along this parameter")
        partners = [
            specs[j].name
            for j in range(len(specs))
            if j != k and abs(correlation[k, j]) > CORRELATION_LIMIT
        ]
        if partners:
            reasons.append(f"|correlation| > {CORRELATION_LIMIT} with {', '.join(partners)}")
        if spec.is_log:
            value = math.exp(values[k])
            relative: float | None = float(se_raw[k])
            standard_error = value * float(se_raw[k])
            if se_raw[k] > RELATIVE_SE_LIMIT:
                reasons.append(f"relative standard error {se_raw[k]:.3g} > {RELATIVE_SE_LIMIT}")
        else:
            value, relative, standard_error = float(values[k]), None, float(se_raw[k])
            if standard_error > OFFSET_SE_LIMIT_C:
                reasons.append(f"standard error {standard_error:.3g} degC > {OFFSET_SE_LIMIT_C}")
        at_bound = math.isclose(values[k], spec.bounds[0], abs_tol=1e-6) or math.isclose(
            values[k], spec.bounds[1], abs_tol=1e-6
        )
        if at_bound:
            reasons.append("at its bound")
        reason = "; ".join(reasons)
        if reason:
            warnings.append(f"{spec.name} is not identifiable from these data: {reason}")
        fitted.append(
            FittedParameter(spec.name, value, standard_error, relative, not reason, reason)
        )
    return fitted, correlation, warnings


def evaluate(
    result: IdentificationResult,
    run: RunData,
    network: ThermalNetwork,
    regions: Mapping[str, Sequence[str]],
) -> FitQuality:
    """How well the identified parameters (applied to the same base ``network``) predict
    another run: the residual RMS over it, nothing refitted."""
    used = {r: tuple(n) for r, n in regions.items() if r in run.region_c}
    specs = [s for s in result.specs if s.kind != "offset" or set(s.targets) <= set(used)]
    values = np.array([v for s, v in zip(result.specs, result.values, strict=True) if s in specs])
    problem = _Problem(run, network, specs, used)
    return problem.quality(values)


def validate(
    result: IdentificationResult,
    run: RunData,
    network: ThermalNetwork,
    regions: Mapping[str, Sequence[str]],
) -> IdentificationResult:
    """``result`` with its validation on ``run`` filled in."""
    return dataclasses.replace(result, validation=evaluate(result, run, network, regions))


# -- the network file ---------------------------------------------------------------------------


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


__all__ = [
    "PARAMETER_KINDS",
    "FitQuality",
    "FittedParameter",
    "IdentificationError",
    "IdentificationResult",
    "Parameter",
    "RunData",
    "calibration_of",
    "central_jacobian",
    "conditioning",
    "default_parameters",
    "evaluate",
    "find_parameter",
    "heat_schedule",
    "identify",
    "measured_deformation_um",
    "network_toml",
    "observation_matrix",
    "parameters_report",
    "parse_parameters",
    "residual_variance",
    "rms",
    "run_data_from_steps",
    "simulate_temperatures",
    "uncertainty",
    "validate",
]
