"""Grey-box identification of the arm's thermal model from a calibration cycle (issues 20, 29).

The arm generalisation of :mod:`daemon.model.identify`: the controller's arm model
(:class:`daemon.arm.thermal.ArmThermalModel`) keeps its structure; a few physically meaningful
groups of its parameters (daemon/arm/identify_parameters.py: each joint's heat, convection,
alpha, the joints' capacity, the bending share, the IR offsets) are fitted to what a calibration
cycle (compensation off) measured: the 3-D displacement of the tool's markers at each measured
pose of the cycle (daemon.vision.multiview, several cameras) and the IR region temperatures on
several links.

``scipy.optimize.least_squares`` with a robust loss, two passes (the second weighs markers and
temperatures by their own residual RMS); standard errors, correlations and what is not
identifiable from ``J`` at the solution exactly as daemon.model.identify reports them (its
:func:`~daemon.model.identify.uncertainty`: normalised J^T J, near-singular directions,
|correlation| > 0.995, relative SE > 0.5, parameters at a bound), and beyond them a multiple
correlation with the other parameters together > 0.995 (daemon/arm/identify_groups.py: a
trade-off among three or more, which no pair shows).

Speed (issue 29: an 8-hour cycle took 2-13 minutes by finite differences of whole simulations):
the model is linear between changes of the network's factors, so the fit's Jacobian is
analytic in the heats (their own responses), alpha (the prediction itself) and the offsets (1),
and only a network factor (convection, capacity, share) needs new responses: one pass of the
network's modes on the measured outputs alone (daemon/arm/identify_response.py), cached per
factor set, forward differences of those while the fit iterates and central ones at the
solution (its covariance). The markers' displacement is linear in each link's
strain and bend (daemon/arm/response.py marker_sensitivity).

A run whose displacements are relative to one camera measurement of each pose
(``ArmRunData.reference_fitted``) has that reference's error fitted (response.PoseReferences).

:func:`daemon.arm.identify_final.identify_arm_final` is the calibration's whole fit: every
parameter, then the identifiable ones refitted until the refit's own report says each is
identified; the flags come from that FINAL fit, and a parameter dropped on the way keeps its
prior and says why.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from daemon.arm.identify_groups import entangled_reasons, groups
from daemon.arm.identify_parameters import (
    ArmParameter,
    ArmScales,
    apply_values,
    default_parameters,
    initial_values,
    parse_parameters,
)
from daemon.arm.identify_response import (
    NetworkFactors,
    OutputResponses,
    output_responses,
)
from daemon.arm.response import (
    SENSITIVITY_STRAIN,
    ArmModelSpec,
    ArmRunData,
    PoseReferences,
    Responses,
    marker_sensitivity,
    responses,
)
from daemon.arm.types import FloatArray
from daemon.model.blas import one_blas_thread
from daemon.model.identify import (
    LOSS,
    LOSS_SCALE,
    FittedParameter,
    IdentificationError,
    conditioning,
    find_parameter,
    parameters_report,
    residual_variance,
    rms,
    uncertainty,
)

#: The step of the central differences in a network factor (fitted units: a log factor or a
#: share): the responses are smooth in them, and 1e-4 keeps rounding far below the signal.
NETWORK_STEP = 1e-4
#: Network factor sets whose responses are kept (the current point and its differences).
CACHE_SIZE = 64


#: Reports the fit's progress (one line: pass, evaluations, cost).
Progress = Callable[[str], None]


# -- the fit -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ArmFitQuality:
    marker_rms_mm: float | None
    temperature_rms_c: float | None
    marker_samples: int
    temperature_samples: int


@dataclass(frozen=True)
class ArmIdentification:
    parameters: tuple[FittedParameter, ...]
    correlation: FloatArray
    scales: ArmScales
    fit: ArmFitQuality
    values: FloatArray
    specs: tuple[ArmParameter, ...]
    conditioning: float  # largest / smallest singular value of the normalised J^T J
    success: bool
    message: str
    warnings: tuple[str, ...] = ()
    evaluations: int = 0  # network passes (new responses) the fit took
    #: parameters told only in combination with others (identify_groups; no other reason)
    entangled: tuple[str, ...] = ()
    #: the direction the data see least, one component per parameter (identify_groups)
    weakest: tuple[float, ...] = ()

    def parameter(self, name: str) -> FittedParameter:
        return find_parameter(self.parameters, name)

    def to_dict(self) -> dict[str, Any]:
        return {
            **parameters_report(self.parameters, self.correlation),
            "heat_scales": self.scales.heat.tolist(),
            "convection_scale": self.scales.convection,
            "alpha_scale": self.scales.alpha,
            "capacity_scale": self.scales.capacity,
            "bending_shares": None if self.scales.shares is None else list(self.scales.shares),
            "offsets_c": self.scales.offsets_c,
            "fit": dataclasses.asdict(self.fit),
            "conditioning": self.conditioning,
            "success": self.success,
            "message": self.message,
            "warnings": list(self.warnings),
        }


class _ArmProblem:
    """Weighted residuals of a calibration cycle for a parameter vector, and their Jacobian."""

    def __init__(self, run: ArmRunData, model: ArmModelSpec, specs: Sequence[ArmParameter]) -> None:
        self.run, self.model, self.specs = run, model, list(specs)
        self.joints = run.joint_heat_w.shape[1]
        self.region_names = [r for r in model.regions if r in run.region_c]
        self.regions = {r: model.regions[r] for r in self.region_names}
        self.prior_shares = tuple(joint.plus_share for joint in model.description.joints)
        self._cache: dict[tuple[float, ...], tuple[FloatArray, FloatArray]] = {}
        self.passes = 0
        displacement = run.marker_displacement_mm.reshape(run.time_s.size, -1)
        self.measured_markers = displacement
        self.marker_mask = np.isfinite(displacement)
        self.references = PoseReferences(run, self.marker_mask)
        self.measured_regions = (
            np.column_stack([run.region_c[r] for r in self.region_names])
            if self.region_names
            else np.zeros((run.time_s.size, 0))
        )
        self.region_mask = np.isfinite(self.measured_regions)
        self.sensitivity = np.stack([model.sensitivities[int(p)] for p in run.pose_index])
        self.alphas = np.array([link.alpha_per_c for link in model.description.links])
        self.marker_sigma_mm = 1.0
        self.temperature_sigma_c = 1.0
        self.network_specs = [k for k, spec in enumerate(self.specs) if spec.changes_network]

    # -- the model's parts for one network -----------------------------------------------------

    def _factors(self, scales: ArmScales) -> NetworkFactors:
        return NetworkFactors(scales.convection, scales.capacity, scales.shares)

    def _parts(self, factors: NetworkFactors) -> tuple[FloatArray, FloatArray]:
        """Each input's markers ((J+1) x K x 3M, per W or for the ambient, at alpha x1) and
        IR regions ((J+1) x K x R) for the network of ``factors`` (cached)."""
        key = (
            round(math.log(factors.convection), 12),
            round(math.log(factors.capacity), 12),
            *(round(v, 12) for v in factors.shares or ()),
        )
        cached = self._cache.get(key)
        if cached is None:
            if len(self._cache) >= CACHE_SIZE:
                self._cache.clear()
            outputs = output_responses(
                self.model.description,
                self.model.node_spacing_mm,
                factors,
                self.run,
                self.regions,
                across_link=self.model.across_link,
            )
            self.passes += 1
            cached = (self._markers(outputs), outputs.region_means)
            self._cache[key] = cached
        return cached

    def _markers(self, outputs: OutputResponses) -> FloatArray:
        strains = outputs.link_means * self.alphas  # (J+1) x K x L
        gradients = outputs.link_gradients
        if gradients is not None:  # strain, alpha g_y, alpha g_z per link
            inputs, count, links = strains.shape
            bends = gradients.reshape(inputs, count, links, 2) * self.alphas[:, None]
            strains = np.concatenate([strains[..., None], bends], axis=3).reshape(inputs, count, -1)
        result: FloatArray = np.einsum("kml,ckl->ckm", self.sensitivity, strains)
        return result

    # -- predictions, residuals, Jacobian -------------------------------------------------------

    def scales(self, values: FloatArray) -> ArmScales:
        return apply_values(self.specs, values, self.joints, self.region_names, self.prior_shares)

    def _combine(
        self, scales: ArmScales, parts: tuple[FloatArray, FloatArray]
    ) -> tuple[FloatArray, FloatArray]:
        markers, regions = parts
        j = self.joints
        predicted_markers = scales.alpha * (np.tensordot(scales.heat, markers[:j], 1) + markers[j])
        predicted_regions = np.tensordot(scales.heat, regions[:j], 1) + regions[j]
        offsets = np.array([scales.offsets_c[r] for r in self.region_names])
        return predicted_markers, predicted_regions + offsets

    def predictions(self, values: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The markers (K x 3M) and IR regions (K x R) the model predicts for ``values``."""
        scales = self.scales(values)
        return self._combine(scales, self._parts(self._factors(scales)))

    def _weigh(self, markers: FloatArray, regions: FloatArray) -> FloatArray:
        return np.concatenate(
            [
                self.references.centred(markers)[self.marker_mask] / self.marker_sigma_mm,
                regions[self.region_mask] / self.temperature_sigma_c,
            ]
        )

    def raw(self, values: FloatArray) -> tuple[FloatArray, FloatArray]:
        markers, regions = self.predictions(values)
        return (
            self.references.centred(markers - self.measured_markers)[self.marker_mask],
            (regions - self.measured_regions)[self.region_mask],
        )

    def weighted(self, values: FloatArray) -> FloatArray:
        markers, regions = self.predictions(values)
        return self._weigh(markers - self.measured_markers, regions - self.measured_regions)

    def jacobian(self, values: FloatArray, *, central: bool = True) -> FloatArray:
        """d weighted / d values: analytic for heats, alpha and offsets, differences of the
        network's responses for its factors (module docstring): central, or forward
        (``central=False``: one network pass per factor instead of two, from the point's own
        responses, which are cached; what the fit's iterations use)."""
        scales = self.scales(values)
        parts = self._parts(self._factors(scales))
        markers, regions = parts
        j = self.joints
        predicted_markers, _ = self._combine(scales, parts)
        columns = []
        for k, spec in enumerate(self.specs):
            if spec.kind == "heat":
                chosen = list(spec.indices)
                weights = scales.heat[chosen]
                d_markers = scales.alpha * np.tensordot(weights, markers[chosen], 1)
                d_regions = np.tensordot(weights, regions[chosen], 1)
            elif spec.kind == "alpha":
                d_markers, d_regions = predicted_markers, np.zeros_like(regions[j])
            elif spec.kind == "offset":
                d_markers = np.zeros_like(predicted_markers)
                d_regions = np.zeros_like(regions[j])
                for region in spec.targets:
                    d_regions[:, self.region_names.index(region)] = 1.0
            elif central:
                up, down = values.copy(), values.copy()
                up[k] += NETWORK_STEP
                down[k] -= NETWORK_STEP
                plus_m, plus_r = self.predictions(up)
                minus_m, minus_r = self.predictions(down)
                d_markers = (plus_m - minus_m) / (2.0 * NETWORK_STEP)
                d_regions = (plus_r - minus_r) / (2.0 * NETWORK_STEP)
            else:
                up = values.copy()
                up[k] += NETWORK_STEP
                plus_m, plus_r = self.predictions(up)
                here_m, here_r = self._combine(scales, parts)
                d_markers = (plus_m - here_m) / NETWORK_STEP
                d_regions = (plus_r - here_r) / NETWORK_STEP
            columns.append(self._weigh(d_markers, d_regions))
        return np.column_stack(columns)

    def quality(self, values: FloatArray) -> ArmFitQuality:
        marker, temperature = self.raw(values)
        return ArmFitQuality(rms(marker), rms(temperature), marker.size, temperature.size)


def _checked_specs(
    run: ArmRunData, model: ArmModelSpec, parameters: Sequence[str] | None
) -> list[ArmParameter]:
    joints = run.joint_heat_w.shape[1]
    used = {r: nodes for r, nodes in model.regions.items() if r in run.region_c}
    names = parameters or default_parameters(joints, used, model.across_link)
    specs = parse_parameters(names, joints, used, model.across_link)
    if len(model.sensitivities) <= int(run.pose_index.max()):
        raise IdentificationError(f"{run.name}: a measurement names a pose with no sensitivity")
    return specs


def identify_arm(
    run: ArmRunData,
    model: ArmModelSpec,
    parameters: Sequence[str] | None = None,
    *,
    marker_sigma_mm: float = 0.005,
    temperature_sigma_c: float = 0.1,
    progress: Progress | None = None,
) -> ArmIdentification:
    """Fit ``parameters`` (default: identify_parameters.default_parameters) of the arm model
    to ``run``; ``progress`` hears one line per Jacobian of the fit. One BLAS thread
    (daemon/model/blas.py: a threaded eigendecomposition of an arm's ~100-node network on a
    loaded 2-core machine took 0.7 s instead of 2 ms)."""
    with one_blas_thread():
        return _identify_arm(
            run,
            model,
            parameters,
            marker_sigma_mm=marker_sigma_mm,
            temperature_sigma_c=temperature_sigma_c,
            progress=progress,
        )


def _identify_arm(
    run: ArmRunData,
    model: ArmModelSpec,
    parameters: Sequence[str] | None = None,
    *,
    marker_sigma_mm: float = 0.005,
    temperature_sigma_c: float = 0.1,
    progress: Progress | None = None,
) -> ArmIdentification:
    """Fit ``parameters`` (default: identify_parameters.default_parameters) of the arm model
    to ``run``; ``progress`` hears one line per Jacobian of the fit."""
    specs = _checked_specs(run, model, parameters)
    problem = _ArmProblem(run, model, specs)
    count = int(problem.marker_mask.sum() + problem.region_mask.sum())
    unknowns = len(specs) + problem.references.count
    if count <= unknowns:
        raise IdentificationError(f"{count} measurements cannot fit {unknowns} unknowns")
    lower = np.array([s.bounds[0] for s in specs])
    upper = np.array([s.bounds[1] for s in specs])
    values = np.clip(initial_values(specs, problem.prior_shares), lower, upper)
    sigmas = (marker_sigma_mm, temperature_sigma_c)
    result: Any = None
    for attempt in range(2):  # the second pass weighs each kind by its own residual RMS
        problem.marker_sigma_mm, problem.temperature_sigma_c = sigmas
        evaluations = [0]

        def jacobian(
            x: FloatArray, *_: object, _pass: int = attempt + 1, _count: list[int] = evaluations
        ) -> FloatArray:
            _count[0] += 1
            if progress is not None:
                cost = float(np.sum(problem.weighted(x) ** 2)) / 2.0
                progress(
                    f"{len(specs)} parameters, pass {_pass}/2, iteration {_count[0]}, "
                    f"cost {cost:.4g}, {problem.passes} network passes"
                )
            # forward differences while iterating (half the network passes: issue 29's
            # 30-s target); the covariance below takes central ones at the solution
            return problem.jacobian(x, central=False)

        result = least_squares(
            problem.weighted,
            values,
            jac=jacobian,
            bounds=(lower, upper),
            loss=LOSS,
            f_scale=LOSS_SCALE,
            x_scale=1.0,
            max_nfev=100 * len(specs),
        )
        values = np.asarray(result.x, dtype=np.float64)
        quality = problem.quality(values)
        sigmas = (
            max(quality.marker_rms_mm or marker_sigma_mm, 1e-6),
            max(quality.temperature_rms_c or temperature_sigma_c, 1e-4),
        )
    jacobian_at = problem.jacobian(values)
    variance = residual_variance(problem.weighted(values), unknowns)
    fitted, correlation, warnings = uncertainty(specs, values, jacobian_at, variance)
    fitted, warnings, entangled = _with_groups(fitted, warnings, jacobian_at, correlation)
    return ArmIdentification(
        parameters=tuple(fitted),
        correlation=correlation,
        scales=problem.scales(values),
        fit=problem.quality(values),
        values=values,
        specs=tuple(specs),
        conditioning=conditioning(jacobian_at),
        success=bool(result.success),
        message=str(result.message),
        warnings=tuple(warnings),
        evaluations=problem.passes,
        entangled=entangled,
        weakest=tuple(float(v) for v in groups(jacobian_at).weakest),
    )


def _with_groups(
    fitted: list[FittedParameter],
    warnings: list[str],
    jacobian: FloatArray,
    correlation: FloatArray,
) -> tuple[list[FittedParameter], list[str], tuple[str, ...]]:
    """The fit's report with the group check (identify_groups) added: a parameter told only
    in combination with the others is not identified; the names of those flagged by a
    correlation alone (pairwise or with the group: no bound, no large error), which pooling
    or a prior can untangle (identify_final)."""
    names = [p.name for p in fitted]
    reasons = entangled_reasons(names, jacobian, correlation)
    out, entangled = [], []
    for reported in fitted:
        parameter = reported
        reason = reasons.get(parameter.name)
        if reason is not None and "|correlation|" not in parameter.reason:
            joined = "; ".join(r for r in (parameter.reason, reason) if r)
            warnings.append(f"{parameter.name} is not identifiable from these data: {reason}")
            parameter = dataclasses.replace(parameter, identifiable=False, reason=joined)
        only_correlated = all(
            part.startswith(("|correlation|", "multiple correlation"))
            for part in parameter.reason.split("; ")
        )
        if not parameter.identifiable and only_correlated:
            entangled.append(parameter.name)
        out.append(parameter)
    return out, warnings, tuple(entangled)


def evaluate_arm(
    identification: ArmIdentification | None, run: ArmRunData, model: ArmModelSpec
) -> ArmFitQuality:
    """How well ``identification``'s parameters (None: the preset's, every factor 1 and no IR
    offset) predict another recorded run of the same arm: the residual RMS of its tool
    translation and IR regions, nothing refitted (the arm's analogue of
    :func:`daemon.model.identify.evaluate`). An offset of a region the run did not record is
    left out; a region it recorded with no identified offset is predicted with none."""
    used = [r for r in model.regions if r in run.region_c]
    if identification is None:
        specs: list[ArmParameter] = []
        values = np.zeros(0)
    else:
        pairs = [
            (spec, value)
            for spec, value in zip(identification.specs, identification.values, strict=True)
            if spec.kind != "offset" or set(spec.targets) <= set(used)
        ]
        specs = [spec for spec, _ in pairs]
        values = np.array([value for _, value in pairs], dtype=np.float64)
    if len(model.sensitivities) <= int(run.pose_index.max()):
        raise IdentificationError(f"{run.name}: a measurement names a pose with no sensitivity")
    # as measured: a validation refits nothing, not even its references' errors
    exact = dataclasses.replace(run, reference_fitted=False)
    return _ArmProblem(exact, model, specs).quality(values)


__all__ = [
    "SENSITIVITY_STRAIN",
    "ArmFitQuality",
    "ArmIdentification",
    "ArmModelSpec",
    "ArmRunData",
    "ArmScales",
    "IdentificationError",
    "Responses",
    "apply_values",
    "default_parameters",
    "evaluate_arm",
    "identify_arm",
    "marker_sensitivity",
    "parse_parameters",
    "responses",
]
