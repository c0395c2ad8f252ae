"""Online adaptation of the arm model's identifiable factors during a run (issue 29), as the
two-link model has (daemon/model/adaptation.py): each joint's heat, alpha, convection and the
bending share, estimated from the measured tool displacement and the IR regions while the arm
works, starting from the preset's or an identified model's values as the prior, with their
uncertainty.

Estimator: the maximum a posteriori fit of everything measured so far, ``min |r(theta)|^2 +
|(theta - theta_0) / sigma_0|^2`` (the identification's weighted residuals, daemon/arm/
identify.py, plus the prior), advanced by a few Gauss-Newton steps at each new measurement
from the last estimate, its covariance ``(J^T J + P_0^-1)^-1``. Why not the two-link's
augmented EKF on the node temperatures: the arm's factors act on the network itself
(convection, shares) and its heat inputs per joint, and the tool's displacement is a sum over
six links at poses that change: the identification's forward model (one pass of the network's
modes on the measured outputs, tens of milliseconds for 8 hours: daemon/arm/
identify_response.py) already gives the residuals and their exact Jacobian, so a growing-batch
MAP estimate costs a few passes per measurement and has no linearisation drift. With a
Gaussian prior and Gaussian noise it is the same estimate a Kalman filter on the constant
parameters converges to (Simon 2006, *Optimal State Estimation*, 3.3: recursive least squares
and the batch solution agree).

The compensation uses the adapted model's links (:meth:`ArmAdaptation.link_states`): their
mean rise and gradient now, from the heat record with the current estimate.

Pure: no I/O; the caller feeds the heat of each step (the motor model's, as the controller
uses) and each measurement.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from daemon.arm.identify import _ArmProblem
from daemon.arm.identify_parameters import (
    ArmParameter,
    apply_values,
    initial_values,
    parse_parameters,
)
from daemon.arm.identify_response import NetworkFactors, output_responses
from daemon.arm.response import ArmModelSpec, ArmRunData
from daemon.arm.types import FloatArray, LinkThermalState
from daemon.model.blas import one_blas_thread

#: Prior 1-sigma of a log factor with no identified value (a factor 1.65 either way: the
#: two-link adaptation's PRIOR_LOG_SIGMA) and of a bending share (absolute).
PRIOR_LOG_SIGMA = 0.5
PRIOR_SHARE_SIGMA = 0.15
#: Gauss-Newton steps per update (the estimate moves little between two of them), and the
#: least arm time between two updates (s): a measurement every minute or two would cost a few
#: network passes each; the links' time constants are tens of minutes.
STEPS_PER_UPDATE = 2
UPDATE_EVERY_S = 600.0
#: What is adapted by default: each joint's heat, alpha, convection and (across the links)
#: the bending share.
DEFAULT_KINDS = ("heat", "alpha", "convection", "share")


def adapted_names(joints: int, across_link: bool) -> list[str]:
    names = [*(f"heat:{j + 1}" for j in range(joints)), "alpha", "convection"]
    return [*names, "share"] if across_link else names


def ir_observed_names(
    joints: int, across_link: bool, regions: Sequence[str], seen_links: Sequence[int]
) -> list[str]:
    """What the IR alone can teach (prediction ``model+ir`` without the tool): the heat of
    each joint at an end of a link a region sees (``seen_links``: their indices; joint ``k``
    joins link ``k - 1`` to link ``k``, arm_network.build_arm_network), the convection, the
    bending share (across the links) and each region's offset. Not the expansion, which
    changes no temperature, nor the heat of a joint far from every region: the IR barely
    sees it, and a fit free to move it uses it to absorb what the model's structure misses
    at the regions (issue 29, corner-high task A, identified + IR: the wrist's heats moved
    from 1 to 0.4-0.8 and 95.0 % of the drift was removed where the identified model alone
    removed 97.3 %)."""
    near = sorted({j for link in seen_links for j in (link, link + 1) if 0 <= j < joints})
    names = [*(f"heat:{j + 1}" for j in near), "convection"]
    if across_link:
        names.append("share")
    return [*names, *(f"offset:{region}" for region in regions)]


@dataclass(frozen=True)
class AdaptedEstimate:
    """One factor now: its value (a factor or a share), its 1-sigma and its prior."""

    name: str
    value: float
    sigma: float
    prior: float


class ArmAdaptation:
    """The arm model's factors estimated during a run (module docstring).

    ``spec``: the controller's model as identification sees it (its description, the IR
    regions' nodes, the tool's sensitivity at each measured pose); ``priors``: name -> (value,
    1-sigma of the fitted number: the log for factors, absolute for a share), default the
    preset's (1 or the description's share, PRIOR_LOG_SIGMA / PRIOR_SHARE_SIGMA);
    ``marker_sigma_mm`` and ``temperature_sigma_c``: the meter's and the IR's noise.
    """

    def __init__(
        self,
        spec: ArmModelSpec,
        heat_step_s: float,
        ambient_c: float,
        names: Sequence[str] | None = None,
        priors: Mapping[str, tuple[float, float]] | None = None,
        *,
        marker_sigma_mm: float = 0.005,
        temperature_sigma_c: float = 0.1,
        update_every_s: float = UPDATE_EVERY_S,
    ) -> None:
        joints = len(spec.description.joints)
        self.spec = spec
        self.heat_step_s = float(heat_step_s)
        self.ambient_c = float(ambient_c)
        self.specs: list[ArmParameter] = parse_parameters(
            names or adapted_names(joints, spec.across_link),
            joints,
            spec.regions,
            spec.across_link,
        )
        shares = tuple(joint.plus_share for joint in spec.description.joints)
        prior = initial_values(self.specs, shares)
        sigma = np.array(
            [PRIOR_SHARE_SIGMA if s.kind == "share" else PRIOR_LOG_SIGMA for s in self.specs]
        )
        for k, spec_k in enumerate(self.specs):
            if priors and spec_k.name in priors:
                value, spread = priors[spec_k.name]
                prior[k] = math.log(value) if spec_k.is_log else float(value)
                sigma[k] = float(spread)
        if not np.all(sigma > 0):
            raise ValueError("every adapted parameter's prior needs a positive 1-sigma")
        self.prior = prior
        self.prior_sigma = sigma
        self.values = prior.copy()
        self.covariance = np.diag(sigma**2)
        self.marker_sigma_mm = float(marker_sigma_mm)
        self.temperature_sigma_c = float(temperature_sigma_c)
        self.update_every_s = float(update_every_s)
        self._updated_s = -math.inf
        self.updates = 0
        self._heat: list[FloatArray] = []
        #: the air over each heat step (a room thermometer's, else ``ambient_c`` throughout):
        #: a model holding a constant room soaks a warming or cooling room into the factors
        self._ambient: list[float] = []
        self._times: list[float] = []
        self._poses: list[int] = []
        self._markers: list[FloatArray] = []
        self._regions: dict[str, list[float]] = {name: [] for name in spec.regions}

    @property
    def names(self) -> tuple[str, ...]:
        """The adapted parameters' names."""
        return tuple(spec.name for spec in self.specs)

    # -- inputs ---------------------------------------------------------------------------------

    @property
    def time_s(self) -> float:
        """The end of the heat record (s from the cold start)."""
        return len(self._heat) * self.heat_step_s

    def add_heat(
        self, joint_heat_w: Sequence[float] | FloatArray, ambient_c: float | None = None
    ) -> None:
        """The motor model's mean heat per joint (W) over the next heat step, and the air's
        mean temperature over it (None: the constructor's ``ambient_c``; the first step's is
        the cold arm's temperature)."""
        heat = np.asarray(joint_heat_w, dtype=np.float64).reshape(-1)
        if heat.size != len(self.spec.description.joints) or not np.all(np.isfinite(heat)):
            raise ValueError(f"expected {len(self.spec.description.joints)} finite joint heats")
        air = self.ambient_c if ambient_c is None else float(ambient_c)
        if not math.isfinite(air):
            raise ValueError(f"the ambient must be finite, got {ambient_c}")
        self._heat.append(heat)
        self._ambient.append(air)

    def observe(
        self,
        pose_index: int,
        displacement_mm: Sequence[float] | FloatArray,
        regions_c: Mapping[str, float] | None = None,
    ) -> None:
        """A measurement now (at the end of the heat record): the tool's displacement from
        its cold pose at measured pose ``pose_index`` (NaN where missing) and the IR regions'
        means; then, at most every ``update_every_s`` of arm time, the estimate moves
        (STEPS_PER_UPDATE Gauss-Newton steps on everything measured so far)."""
        if not 0 <= pose_index < len(self.spec.sensitivities):
            raise ValueError(f"no measured pose {pose_index}")
        self._times.append(self.time_s)
        self._poses.append(int(pose_index))
        self._markers.append(np.asarray(displacement_mm, dtype=np.float64).reshape(-1))
        for name, values in self._regions.items():
            values.append(float((regions_c or {}).get(name, math.nan)))
        if len(self._times) >= 2 and self.time_s - self._updated_s >= self.update_every_s:
            self._updated_s = self.time_s
            self._update()
            self.updates += 1

    # -- the estimate ---------------------------------------------------------------------------

    def _run(self, times: Sequence[float], markers: FloatArray, poses: Sequence[int]) -> ArmRunData:
        heat = np.array(self._heat)
        return ArmRunData(
            heat_step_s=self.heat_step_s,
            joint_heat_w=heat,
            ambient_c=np.array(self._ambient),
            time_s=np.asarray(times, dtype=np.float64),
            pose_index=np.array(poses, dtype=np.intp),
            marker_displacement_mm=markers.reshape(len(times), -1, 3),
            region_c={
                name: np.array(values[: len(times)])
                if len(values) >= len(times)
                else np.full(len(times), math.nan)
                for name, values in self._regions.items()
            },
            name="adaptation",
        )

    def _update(self) -> None:
        with one_blas_thread():
            self._gauss_newton()

    def _gauss_newton(self) -> None:
        problem = _ArmProblem(
            self._run(self._times, np.array(self._markers), self._poses), self.spec, self.specs
        )
        problem.marker_sigma_mm = self.marker_sigma_mm
        problem.temperature_sigma_c = self.temperature_sigma_c
        information = np.diag(1.0 / self.prior_sigma**2)
        lower = np.array([s.bounds[0] for s in self.specs])
        upper = np.array([s.bounds[1] for s in self.specs])
        values = self.values
        jacobian = problem.jacobian(values)
        for _ in range(STEPS_PER_UPDATE):
            residual = problem.weighted(values)
            jacobian = problem.jacobian(values)
            normal = jacobian.T @ jacobian + information
            gradient = jacobian.T @ residual + information @ (values - self.prior)
            values = np.clip(values - np.linalg.solve(normal, gradient), lower, upper)
        self.values = values
        self.covariance = np.linalg.inv(jacobian.T @ jacobian + information)

    def estimates(self) -> list[AdaptedEstimate]:
        """Each adapted factor now, with its 1-sigma (delta method for the log factors)."""
        sigma = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return [
            AdaptedEstimate(
                spec.name,
                spec.value(float(value)),
                float(spec.value(float(value)) * s) if spec.is_log else float(s),
                spec.value(float(prior)),
            )
            for spec, value, s, prior in zip(
                self.specs, self.values, sigma, self.prior, strict=True
            )
        ]

    def link_states(self) -> tuple[LinkThermalState, ...]:
        """Each link's mean rise and gradient now (the end of the heat record) by the model
        with the current estimate, alpha included (kinematics.tool_error's input)."""
        with one_blas_thread():
            return self._link_states()

    def _link_states(self) -> tuple[LinkThermalState, ...]:
        description = self.spec.description
        if not self._heat:
            return tuple(
                LinkThermalState(link.name, 0.0, link.alpha_per_c) for link in description.links
            )
        run = self._run([self.time_s, self.time_s], np.zeros((2, 3)), [0, 0])
        shares = tuple(joint.plus_share for joint in description.joints)
        scales = apply_values(self.specs, self.values, len(shares), list(self.spec.regions), shares)
        outputs = output_responses(
            description,
            self.spec.node_spacing_mm,
            NetworkFactors(scales.convection, scales.capacity, scales.shares),
            run,
            {},
            across_link=self.spec.across_link,
        )
        combined = (
            np.tensordot(scales.heat, outputs.per_input[:-1, 0], 1) + outputs.per_input[-1, 0]
        )
        links = outputs.links
        states = []
        for k, link in enumerate(description.links):
            gradient = (
                (float(combined[links + 2 * k]), float(combined[links + 2 * k + 1]))
                if outputs.gradients
                else (0.0, 0.0)
            )
            states.append(
                LinkThermalState(
                    link.name, float(combined[k]), link.alpha_per_c * scales.alpha, gradient
                )
            )
        return tuple(states)


__all__ = [
    "DEFAULT_KINDS",
    "PRIOR_LOG_SIGMA",
    "PRIOR_SHARE_SIGMA",
    "AdaptedEstimate",
    "ArmAdaptation",
    "adapted_names",
    "ir_observed_names",
]
