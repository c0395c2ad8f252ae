"""Online adaptation of a few model parameters inside the IR observer (issue 19).

Identification (:mod:`daemon.model.identify`) fits scale factors of the network from a recorded
calibration run; adaptation estimates the identifiable ones *during* a run instead, together with
the node temperatures, so that a run with a wrong model converges without a calibration run.

Choice of estimator: an augmented-state extended Kalman filter (the unknown parameters appended
to the state with a random-walk model; Ljung 1979, "Asymptotic behavior of the extended Kalman
filter as a parameter estimator for linear systems", IEEE TAC 24(1); Simon 2006, *Optimal State
Estimation*, ch. 13). The network is linear in the temperatures for fixed parameters and the
parameters enter bilinearly, so one joint filter is the smallest change to the existing linear
filter: its covariance already carries temperatures and IR offsets, and the joint covariance
gives the parameters' uncertainty and their correlation with the temperatures for free. A dual
estimator (two filters) would lose that cross-covariance.

Parameters (the identification's names and meanings, fitted as logarithms so that they stay
positive):

* ``heat``: every heat input the model is given, times ``s_h = e^theta``;
* ``heat:NODE``: the heat input of that node only;
* ``convection``: every node's conductance to ambient ``g`` (faces and end faces) times
  ``s_c``;
* ``alpha``: the deformation the model predicts from its temperatures, times ``s_a`` (the
  effective expansion coefficient). The IR regions cannot see it; only the measured
  deformation (the camera's spot drift with the commanded compensation taken out) can, and it
  teaches this factor alone (IrObserver.update_deformation).

With ``C dT/dt = -K T + q + g T_amb`` the model's own nominal network, the adapted one is
``C dT/dt = -K T + q + g T_amb + db`` with ``db = (s_h - 1) q + (s_c - 1) g (T_amb - T)``.
The mean is advanced by the model itself (exact zero-order hold) and then corrected by the
response to ``db`` held over the step, ``dT = Gamma(tau) db`` with
``Gamma(tau) = int_0^tau e^{As} ds C^-1``, computed from the network's modes;
``T`` in ``db`` is the step's midpoint (trapezoid). The error of this splitting is second
order in ``tau (s_c - 1) g / C``, i.e. ~1e-7 of a step for the thesis network at 1 s (the
convection time constants are thousands of seconds). The Jacobian of the step with respect to
``theta`` is ``Gamma (s q)`` and ``Gamma (s_c g (T_amb - T))``: the EKF's linearisation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from daemon.model.calibration import Calibration
from daemon.model.model import ModelError, NetworkModes
from daemon.model.network import FloatArray, NetworkError, ThermalNetwork

AdaptedKind = Literal["heat", "convection", "alpha"]
#: What adaptation estimates by default: one heat factor and one convection factor (from the
#: IR regions) and the expansion factor (from the measured spot drift); the IR offsets are
#: always in the observer's state.
DEFAULT_ADAPTED: tuple[str, ...] = ("heat", "convection", "alpha")
#: Prior 1-sigma of a log scale factor with no identified value: 0.5, a factor 1.65 either
#: way (identification's RELATIVE_SE_LIMIT; the thesis's Table 5.1 gave a 4x wrong time
#: constant, DESIGN.md "Table 5.1", so the prior must be wide).
PRIOR_LOG_SIGMA = 0.5
#: Random walk of a log scale factor (1/s): the parameters are effective values of a model
#: coarser than the link and may wander slowly; 0.05 per hour keeps them nearly constant.
RANDOM_WALK_LOG2_PER_S = 0.05**2 / 3600.0
#: A log scale factor is kept within identification's bounds (factor 1/10 .. 10).
LOG_BOUNDS = (math.log(0.1), math.log(10.0))


@dataclass(frozen=True)
class AdaptedParameter:
    """One adapted factor: ``name`` (as in identification), its nodes and its prior (the log
    of the prior scale and the log's 1-sigma)."""

    name: str
    kind: AdaptedKind
    node_indices: tuple[int, ...]
    prior_log: float = 0.0
    prior_log_sigma: float = PRIOR_LOG_SIGMA


def adapted_parameters(
    network: ThermalNetwork,
    names: Sequence[str] = DEFAULT_ADAPTED,
    priors: Mapping[str, tuple[float, float]] | None = None,
) -> list[AdaptedParameter]:
    """Parse the adapted parameters; ``priors`` maps a name to (prior scale, prior relative
    1-sigma), e.g. identification's value and relative standard error. ModelError when a name
    is unknown or a prior is not positive."""
    every = tuple(range(network.node_count))
    parsed: list[AdaptedParameter] = []
    for raw in names:
        name = raw.strip()
        head, _, argument = name.partition(":")
        kind: AdaptedKind
        if head in ("convection", "alpha") and not argument:
            kind = "alpha" if head == "alpha" else "convection"
            nodes = every
        elif head == "heat":
            kind = "heat"
            try:
                nodes = (
                    (network.node_named(argument, f"adapted parameter {name!r}: node"),)
                    if argument
                    else every
                )
            except NetworkError as err:
                raise ModelError(str(err)) from err
        else:
            raise ModelError(
                f"unknown adapted parameter {name!r}: heat, heat:NODE, convection or alpha"
            )
        scale, sigma = (priors or {}).get(name, (1.0, PRIOR_LOG_SIGMA))
        if not (math.isfinite(scale) and scale > 0 and math.isfinite(sigma) and sigma >= 0):
            raise ModelError(f"adapted parameter {name!r}: prior ({scale}, {sigma}) not > 0")
        parsed.append(AdaptedParameter(name, kind, nodes, math.log(scale), float(sigma)))
    if len({p.name for p in parsed}) != len(parsed):
        raise ModelError(f"an adapted parameter is given twice: {', '.join(names)}")
    return parsed


def adaptation_priors(
    calibration: Calibration | None, names: Sequence[str], prior_sigma: float = PRIOR_LOG_SIGMA
) -> tuple[tuple[str, ...], dict[str, tuple[float, float]]]:
    """Which of ``names`` to adapt, and their priors for :func:`adapted_parameters`.

    With no identification, every one, ``1 +- prior_sigma`` (relative). An identified network
    already holds its identified values (its nodes' convection, its own heat), so a factor's
    prior is 1 with identification's relative standard error (``heat`` takes the largest of
    the heat parameters it covers); a factor identification flagged as not identifiable (or
    with an unbounded error) is left out: it stays as the file has it, since the same kind of
    data did not determine it (issue 19). A factor identification did not fit keeps the
    default prior."""
    chosen: list[str] = []
    priors: dict[str, tuple[float, float]] = {}
    fitted = {p.name: p for p in calibration.parameters} if calibration is not None else {}
    for name in names:
        kind, _, argument = name.partition(":")
        if kind == "heat" and not argument:
            matching = [p for n, p in fitted.items() if n == "heat" or n.startswith("heat:")]
        else:
            matching = [p for n, p in fitted.items() if n in (name, kind)]
        if not matching:
            chosen.append(name)
            priors[name] = (1.0, prior_sigma)
            continue
        errors = [p.relative_error for p in matching]
        if not all(p.identifiable for p in matching) or any(
            e is None or not math.isfinite(e) for e in errors
        ):
            continue
        chosen.append(name)
        priors[name] = (1.0, max(e for e in errors if e is not None))
    return tuple(chosen), priors


class ParameterResponse:
    """The response of a network's temperatures to its adapted parameters over one step."""

    def __init__(
        self, network: ThermalNetwork, modes: NetworkModes, parameters: Sequence[AdaptedParameter]
    ) -> None:
        self.parameters = tuple(parameters)
        self._modes = modes
        self._conductance = network.ambient_conductance_w_per_c
        self._masks = [
            np.isin(np.arange(network.node_count), p.node_indices) for p in self.parameters
        ]
        self._gains: dict[float, FloatArray] = {}

    def gain(self, tau_s: float) -> FloatArray:
        """``Gamma(tau) = C^-1/2 V diag((1 - e^{-lam tau}) / lam) V^T C^-1/2``: temperature
        change per watt of input held over ``tau`` (a mode with ``lam = 0`` cannot occur: every
        network has a path to ambient, daemon.model.network)."""
        cached = self._gains.get(tau_s)
        if cached is None:
            modes = self._modes
            left = modes.vectors / modes.root_c[:, None]
            factor = -np.expm1(-modes.rates * tau_s) / modes.rates
            cached = (left * factor) @ left.T
            if len(self._gains) > 8:
                self._gains.clear()
            self._gains[tau_s] = cached
        return cached

    def drive(
        self, log_scales: FloatArray, heat_w: FloatArray, ambient_c: float, midpoint_c: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The extra input ``db`` (W per node), its derivative with respect to each log scale
        (columns), and the diagonal of its derivative with respect to the temperatures."""
        count = heat_w.size
        drive = np.zeros(count)
        columns = np.zeros((count, len(self.parameters)))
        d_temperature = np.zeros(count)
        for k, (parameter, mask) in enumerate(zip(self.parameters, self._masks, strict=True)):
            scale = math.exp(float(log_scales[k]))
            if parameter.kind == "alpha":  # no effect on the temperatures
                continue
            if parameter.kind == "heat":
                chosen = np.where(mask, heat_w, 0.0)
                drive += (scale - 1.0) * chosen
                columns[:, k] = scale * chosen
            else:
                chosen = np.where(mask, self._conductance, 0.0)
                drive += (scale - 1.0) * chosen * (ambient_c - midpoint_c)
                columns[:, k] = scale * chosen * (ambient_c - midpoint_c)
                d_temperature -= (scale - 1.0) * chosen
        return drive, columns, d_temperature


__all__ = [
    "DEFAULT_ADAPTED",
    "LOG_BOUNDS",
    "PRIOR_LOG_SIGMA",
    "RANDOM_WALK_LOG2_PER_S",
    "AdaptedParameter",
    "ParameterResponse",
    "adaptation_priors",
    "adapted_parameters",
]
