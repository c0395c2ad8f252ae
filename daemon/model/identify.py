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
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from daemon.analysis.steps import RunSteps
from daemon.model.identify_parameters import (
    OFFSET_BOUND_C,
    PARAMETER_KINDS,
    SCALE_BOUNDS,
    Applied,
    IdentificationError,
    Parameter,
    ParameterKind,
    apply_parameters,
    default_parameters,
    observation_matrix,
    parse_parameters,
)
from daemon.model.identify_uncertainty import (
    CORRELATION_LIMIT,
    JACOBIAN_STEP,
    OFFSET_SE_LIMIT_C,
    RELATIVE_SE_LIMIT,
    SINGULAR_RATIO,
    FitQuality,
    FittedParameter,
    central_jacobian,
    conditioning,
    find_parameter,
    parameters_report,
    residual_variance,
    rms,
    uncertainty,
)
from daemon.model.model import NetworkModes
from daemon.model.network import FloatArray, ThermalNetwork

# The parameters, the uncertainty report and the network file are modules of their own
# (identify_parameters.py, identify_uncertainty.py, identified_network.py); they are part of
# identification's interface.
__all__ = [
    "CORRELATION_LIMIT",
    "JACOBIAN_STEP",
    "OFFSET_BOUND_C",
    "OFFSET_SE_LIMIT_C",
    "PARAMETER_KINDS",
    "RELATIVE_SE_LIMIT",
    "SCALE_BOUNDS",
    "SINGULAR_RATIO",
    "Applied",
    "FitQuality",
    "FittedParameter",
    "HeatSchedule",
    "IdentificationError",
    "IdentificationResult",
    "Parameter",
    "ParameterKind",
    "RunData",
    "apply_parameters",
    "central_jacobian",
    "conditioning",
    "default_parameters",
    "evaluate",
    "find_parameter",
    "heat_schedule",
    "heat_vector",
    "identify",
    "measured_deformation_um",
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

logger = logging.getLogger(__name__)


#: The robust loss and its scale (in units of a residual's standard deviation).
LOSS = "soft_l1"
LOSS_SCALE = 3.0

HeatSchedule = tuple[tuple[float, dict[str, float]], ...]


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


# -- the fit ------------------------------------------------------------------------------------
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
