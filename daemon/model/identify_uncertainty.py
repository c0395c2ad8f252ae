"""The uncertainty report of an identification, shared by the two-link network's
(daemon/model/identify.py) and the arm's (daemon/arm/identify.py): the Jacobian by central
differences, standard errors and correlations from ``cov = s^2 (J^T J)^-1``, and which
parameters the data do not identify."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from daemon.model.network import FloatArray

#: A parameter is not identifiable when its relative standard error exceeds this (a log SE
#: of 0.5 is a factor e^0.5 = 1.65 either way), when an offset's SE exceeds OFFSET_SE_LIMIT_C,
#: when it loads a direction of J^T J that the data do not see (singular value ratio below
#: SINGULAR_RATIO), or when it correlates with another one beyond CORRELATION_LIMIT.
RELATIVE_SE_LIMIT = 0.5
OFFSET_SE_LIMIT_C = 1.0
SINGULAR_RATIO = 1e-7
CORRELATION_LIMIT = 0.995
#: Relative step of the central differences of the reported Jacobian.
JACOBIAN_STEP = 1e-5
#: A fitted value this close to a bound (in fitted units: log or linear) is AT the bound: the
#: optimiser stops a hair inside it (issue 29: a refit pinned at 0.10 passed for identified).
BOUND_TOLERANCE = 1e-4


class FitParameter(Protocol):
    """What the uncertainty report needs of a parameter (the two-link network's
    daemon.model.identify_parameters.Parameter, the arm's daemon.arm.identify_parameters)."""

    @property
    def name(self) -> str: ...

    @property
    def is_log(self) -> bool: ...

    @property
    def bounds(self) -> tuple[float, float]: ...

    @property
    def absolute_se_limit(self) -> float: ...

    @property
    def unit(self) -> str: ...


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
    specs: Sequence[FitParameter], values: FloatArray, jacobian: FloatArray, variance: float
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
            if standard_error > spec.absolute_se_limit:
                reasons.append(
                    f"standard error {standard_error:.3g}{spec.unit} > {spec.absolute_se_limit}"
                )
        low, high = spec.bounds
        at_bound = values[k] <= low + BOUND_TOLERANCE or values[k] >= high - BOUND_TOLERANCE
        if at_bound:
            reasons.append("at its bound")
        reason = "; ".join(reasons)
        if reason:
            warnings.append(f"{spec.name} is not identifiable from these data: {reason}")
        fitted.append(
            FittedParameter(spec.name, value, standard_error, relative, not reason, reason)
        )
    return fitted, correlation, warnings
