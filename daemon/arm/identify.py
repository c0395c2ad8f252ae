"""Grey-box identification of the arm's thermal model from a calibration cycle (issue 20).

The arm generalisation of :mod:`daemon.model.identify`: the controller's arm model
(:class:`daemon.arm.thermal.ArmThermalModel`) keeps its structure; a few physically meaningful
groups of its parameters are scaled to fit what a calibration cycle (compensation off)
measured: the 3-D displacement of the tool's markers at each measured pose of the cycle
(daemon.vision.multiview, several cameras) and the IR region temperatures on several links.

Parameters (names as in the two-link identification):

* ``heat:J`` (joint J, 1-based) or ``heat`` (every joint, one factor): the heat really released
  in the joint per watt the motor model predicts from the motion;
* ``convection``: h of every surface (links and joint housings), ArmThermalModel's
  ``convection_scale``;
* ``alpha``: the expansion coefficient of every link;
* ``offset`` (one for every IR region) or ``offset:REGION``: an additive IR offset (degC).

Scale factors are fitted as logarithms within [1/10, 10], offsets within +-5 degC, with
``scipy.optimize.least_squares`` and a robust loss, two passes (the second weighs markers and
temperatures by their own residual RMS); standard errors, correlations and what is not
identifiable from ``J`` at the solution exactly as daemon.model.identify reports them (its
:func:`~daemon.model.identify.uncertainty`: normalised J^T J, near-singular directions,
|correlation| > 0.995, relative SE > 0.5, parameters at a bound).

The forward model (:mod:`daemon.arm.response`) is cheap because the arm's network is linear
and a link's growth tiny: every input's response in one pass of the network's modes, and the
markers' displacement linear in each link's strain and bend.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from daemon.arm.response import (
    SENSITIVITY_STRAIN,
    ArmModelSpec,
    ArmRunData,
    Responses,
    marker_sensitivity,
    responses,
)
from daemon.arm.types import FloatArray
from daemon.model.identify import (
    LOSS,
    LOSS_SCALE,
    FittedParameter,
    IdentificationError,
    Parameter,
    central_jacobian,
    conditioning,
    find_parameter,
    parameters_report,
    residual_variance,
    rms,
    uncertainty,
)

#: The step of the central differences of the reported Jacobian (absolute: the fitted vector
#: is log scales and offsets of order 1).
JACOBIAN_STEP = 1e-5


# -- parameters ----------------------------------------------------------------------------------


def default_parameters(joints: int, regions: Mapping[str, Sequence[int]]) -> list[str]:
    """Each joint's heat, convection, alpha and (with IR regions) one common IR offset."""
    names = [*(f"heat:{j + 1}" for j in range(joints)), "convection", "alpha"]
    return [*names, "offset"] if regions else names


def parse_parameters(
    names: Sequence[str], joints: int, regions: Mapping[str, Sequence[int]]
) -> list[Parameter]:
    """The parameters from their names (module docstring); raises IdentificationError."""
    parsed: list[Parameter] = []
    for raw in names:
        spec = raw.strip()
        kind, _, argument = spec.partition(":")
        if kind == "heat":
            if argument:
                if not argument.isdigit() or not 1 <= int(argument) <= joints:
                    raise IdentificationError(f"{spec!r}: joints are numbered 1..{joints}")
                indices: tuple[int, ...] = (int(argument) - 1,)
            else:
                indices = tuple(range(joints))
            parsed.append(Parameter(spec, "heat", (), indices))
        elif kind in ("convection", "alpha"):
            if argument:
                raise IdentificationError(f"{spec!r}: {kind} takes no argument")
            parsed.append(Parameter(spec, kind, ()))  # type: ignore[arg-type]
        elif kind == "offset":
            if not regions:
                raise IdentificationError(f"{spec!r}: the run has no IR region")
            if argument and argument not in regions:
                raise IdentificationError(f"{spec!r}: unknown region {argument!r}")
            parsed.append(Parameter(spec, "offset", (argument,) if argument else tuple(regions)))
        else:
            raise IdentificationError(
                f"unknown parameter {spec!r}; kinds: heat[:J], convection, alpha, offset[:R]"
            )
    if len({p.name for p in parsed}) != len(parsed):
        raise IdentificationError("a parameter is given twice")
    if not parsed:
        raise IdentificationError("no parameter to fit")
    return parsed


@dataclass(frozen=True)
class ArmScales:
    """A parameter vector applied: heat factor per joint, convection and alpha factors, IR
    offset per region."""

    heat: FloatArray
    convection: float
    alpha: float
    offsets_c: dict[str, float]


def apply_values(
    specs: Sequence[Parameter], values: FloatArray, joints: int, regions: Sequence[str]
) -> ArmScales:
    heat = np.ones(joints)
    convection = alpha = 1.0
    offsets = dict.fromkeys(regions, 0.0)
    for spec, value in zip(specs, values, strict=True):
        if spec.kind == "heat":
            heat[list(spec.node_indices)] *= math.exp(value)
        elif spec.kind == "convection":
            convection *= math.exp(value)
        elif spec.kind == "alpha":
            alpha *= math.exp(value)
        else:
            for region in spec.targets:
                offsets[region] += float(value)
    return ArmScales(heat, convection, alpha, offsets)


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
    specs: tuple[Parameter, ...]
    conditioning: float  # largest / smallest singular value of the normalised J^T J
    success: bool
    message: str
    warnings: tuple[str, ...] = ()

    def parameter(self, name: str) -> FittedParameter:
        return find_parameter(self.parameters, name)

    def to_dict(self) -> dict[str, Any]:
        return {
            **parameters_report(self.parameters, self.correlation),
            "heat_scales": self.scales.heat.tolist(),
            "convection_scale": self.scales.convection,
            "alpha_scale": self.scales.alpha,
            "offsets_c": self.scales.offsets_c,
            "fit": dataclasses.asdict(self.fit),
            "conditioning": self.conditioning,
            "success": self.success,
            "message": self.message,
            "warnings": list(self.warnings),
        }


class _ArmProblem:
    """Weighted residuals of a calibration cycle for a parameter vector."""

    def __init__(self, run: ArmRunData, model: ArmModelSpec, specs: Sequence[Parameter]) -> None:
        self.run, self.model, self.specs = run, model, list(specs)
        self.joints = run.joint_heat_w.shape[1]
        self.region_names = [r for r in model.regions if r in run.region_c]
        self._cache: dict[float, Responses] = {}
        displacement = run.marker_displacement_mm.reshape(run.time_s.size, -1)
        self.measured_markers = displacement
        self.marker_mask = np.isfinite(displacement)
        self.region_masks = {r: np.isfinite(run.region_c[r]) for r in self.region_names}
        self.sensitivity = np.stack([model.sensitivities[int(p)] for p in run.pose_index])
        self.marker_sigma_mm = 1.0
        self.temperature_sigma_c = 1.0

    def _responses(self, convection: float) -> Responses:
        key = round(math.log(convection), 12)
        cached = self._cache.get(key)
        if cached is None:
            if len(self._cache) > 64:
                self._cache.clear()
            cached = responses(
                self.model.description,
                self.model.node_spacing_mm,
                convection,
                self.run,
                self.model.across_link,
            )
            self._cache[key] = cached
        return cached

    def predictions(self, values: FloatArray) -> tuple[FloatArray, dict[str, FloatArray]]:
        scales = apply_values(self.specs, values, self.joints, self.region_names)
        response = self._responses(scales.convection)
        temperatures = response.ambient + np.einsum("j,jkn->kn", scales.heat, response.per_joint)
        rise = temperatures - response.reference_c
        alphas = scales.alpha * np.array(
            [link.alpha_per_c for link in self.model.description.links]
        )
        strains = rise @ response.link_rows.T * alphas  # K x L
        if response.gradient_rows is not None:  # strain, alpha g_y, alpha g_z per link
            bends = (rise @ response.gradient_rows.T).reshape(rise.shape[0], -1, 2)
            strains = np.concatenate(
                [strains[:, :, None], bends * alphas[None, :, None]], axis=2
            ).reshape(rise.shape[0], -1)
        markers = np.einsum("kml,kl->km", self.sensitivity, strains)
        regions = {
            name: temperatures[:, list(self.model.regions[name])].mean(axis=1)
            + scales.offsets_c[name]
            for name in self.region_names
        }
        return markers, regions

    def raw(self, values: FloatArray) -> tuple[FloatArray, FloatArray]:
        markers, regions = self.predictions(values)
        marker = (markers - self.measured_markers)[self.marker_mask]
        temperature = [
            (regions[r] - self.run.region_c[r])[self.region_masks[r]] for r in self.region_names
        ]
        return marker, np.concatenate(temperature) if temperature else np.zeros(0)

    def weighted(self, values: FloatArray) -> FloatArray:
        marker, temperature = self.raw(values)
        return np.concatenate(
            [marker / self.marker_sigma_mm, temperature / self.temperature_sigma_c]
        )

    def quality(self, values: FloatArray) -> ArmFitQuality:
        marker, temperature = self.raw(values)
        return ArmFitQuality(rms(marker), rms(temperature), marker.size, temperature.size)


def identify_arm(
    run: ArmRunData,
    model: ArmModelSpec,
    parameters: Sequence[str] | None = None,
    *,
    marker_sigma_mm: float = 0.005,
    temperature_sigma_c: float = 0.1,
) -> ArmIdentification:
    """Fit ``parameters`` (default :func:`default_parameters`) of the arm model to ``run``."""
    joints = run.joint_heat_w.shape[1]
    used = {r: nodes for r, nodes in model.regions.items() if r in run.region_c}
    specs = parse_parameters(parameters or default_parameters(joints, used), joints, used)
    if len(model.sensitivities) <= int(run.pose_index.max()):
        raise IdentificationError("a measurement names a pose with no sensitivity")
    problem = _ArmProblem(run, model, specs)
    count = int(problem.marker_mask.sum() + sum(m.sum() for m in problem.region_masks.values()))
    if count <= len(specs):
        raise IdentificationError(f"{count} measurements cannot fit {len(specs)} parameters")
    lower = np.array([s.bounds[0] for s in specs])
    upper = np.array([s.bounds[1] for s in specs])
    values = np.zeros(len(specs))
    sigmas = (marker_sigma_mm, temperature_sigma_c)
    result: Any = None
    for _ in range(2):  # the second pass weighs each kind by its own residual RMS
        problem.marker_sigma_mm, problem.temperature_sigma_c = sigmas
        result = least_squares(
            problem.weighted,
            values,
            bounds=(lower, upper),
            loss=LOSS,
            f_scale=LOSS_SCALE,
            x_scale=1.0,
            diff_step=1e-6,
            max_nfev=100 * len(specs),
        )
        values = np.asarray(result.x, dtype=np.float64)
        quality = problem.quality(values)
        sigmas = (
            max(quality.marker_rms_mm or marker_sigma_mm, 1e-6),
            max(quality.temperature_rms_c or temperature_sigma_c, 1e-4),
        )
    jacobian = central_jacobian(problem.weighted, values, JACOBIAN_STEP, relative=False)
    variance = residual_variance(problem.weighted(values), len(specs))
    fitted, correlation, warnings = uncertainty(specs, values, jacobian, variance)
    return ArmIdentification(
        parameters=tuple(fitted),
        correlation=correlation,
        scales=apply_values(specs, values, joints, problem.region_names),
        fit=problem.quality(values),
        values=values,
        specs=tuple(specs),
        conditioning=conditioning(jacobian),
        success=bool(result.success),
        message=str(result.message),
        warnings=tuple(warnings),
    )


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
        specs: list[Parameter] = []
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
    return _ArmProblem(run, model, specs).quality(values)


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
