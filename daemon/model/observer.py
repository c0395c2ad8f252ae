"""Online correction of the thermal model from the IR camera: a Kalman filter (issue 9).

The network is linear (thesis 5.4; DESIGN.md "Eq. 5.1"), so between two readings the node
temperatures obey the model's exact zero-order hold ``T(k+1) = Ad T(k) + Bd b``. The mean is
advanced by the :class:`ThermalModel` itself (so with no measurement the filter IS the open-loop
model, bit for bit), and the covariance by the same ``Ad``:
``P <- Ad P Ad^T + Q tau`` (process noise ``Q`` per node, degC^2/s, for what the model gets
wrong: heat input, convection). An IR region measures the mean of the node(s) it covers plus
its sensor offset: ``z = H T + o + v``, ``v ~ N(0, R)``, R from the IR noise. The offsets
(the FLIR's +-2 degC accuracy, thesis 3.2.2) are part of the state, constant, and learnt from
the readings: the run starts at a known ambient (P = 0 on the nodes), so the first readings
teach the offsets and later ones the temperatures.

Deformation is linear in T, ``d = w^T (T - T_ref)``, so its variance is ``w^T P_TT w``.
The normalised innovation squared (NIS, chi-squared with one degree per region when the model
is right) and a moving mean of each region's normalised innovation detect a persistent bias:
"model drifting: consider identification".

With ``adapt`` (issue 19, :mod:`daemon.model.adaptation`) the state also carries the log of a few
scale factors of the model (heat input, convection), estimated online with the temperatures by
an augmented-state extended Kalman filter: a run with a wrong model converges without a
calibration run, and the factors' 1-sigma comes from the same covariance.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from daemon.model.adaptation import (
    LOG_BOUNDS,
    RANDOM_WALK_LOG2_PER_S,
    AdaptedParameter,
    ParameterResponse,
)
from daemon.model.blas import one_blas_thread
from daemon.model.covariance import joseph_update, propagate_nodes
from daemon.model.identify import observation_matrix
from daemon.model.model import ModelError, NetworkModes, ThermalModel
from daemon.model.network import FloatArray

logger = logging.getLogger(__name__)

DRIFT_WARNING = "model drifting: consider identification"
#: Default process noise (degC^2/s per node): a node may wander ~0.5 degC in 15 min from what
#: the model predicts, the size of a 30 % heat-input error early in a warm-up.
PROCESS_NOISE_C2_PER_S = 3e-4
#: Prior standard deviation of an IR offset: the FLIR A40M's +-2 degC accuracy (thesis 3.2.2).
OFFSET_SIGMA_C = 2.0
#: Prior 1-sigma of the camera stand's warm-up drift amplitude (µm on the chip): the thesis
#: measured a few µm (4.8).
STAND_DRIFT_SIGMA_UM = 5.0
#: Bias detector: window of normalised innovations per region, and the threshold on their
#: mean in units of its own standard deviation 1/sqrt(window) under a right model.
BIAS_WINDOW = 60
BIAS_THRESHOLD_SIGMA = 5.0


class IrRegionLike(Protocol):
    """What the filter needs of config.settings.IrRegion (the pure core does not import it)."""

    @property
    def name(self) -> str: ...

    @property
    def node(self) -> str | None: ...


def regions_to_nodes(regions: Sequence[IrRegionLike]) -> dict[str, tuple[str, ...]]:
    """IR regions tied to a node (IrRegion.node), as ``{region: (node,)}``; others are left
    out (they measure no model node)."""
    return {region.name: (region.node,) for region in regions if region.node}


@dataclass(frozen=True)
class Innovation:
    """One update: per-region innovation (degC), its variance, and the NIS of the reading."""

    time_s: float
    innovation_c: dict[str, float]
    variance_c2: dict[str, float]
    nis: float
    degrees_of_freedom: int


class IrObserver:
    """A Kalman filter fusing IR region temperatures into a :class:`ThermalModel`.

    ``regions`` ties each region to the node(s) it covers (:func:`regions_to_nodes`);
    ``ir_noise_c`` is the 1-sigma noise of a region's mean (one value, or one per region;
    ``inf`` ignores the region); ``offsets_c`` are the known IR offsets (e.g. identified) and
    ``offset_sigma_c`` their prior uncertainty (0: trust them; the offsets are then fixed).
    ``reference_nodes`` must be the model's (ThermalModel's argument; default the network's).
    ``adapt``: the scale factors estimated online with their priors
    (:func:`daemon.model.adaptation.adapted_parameters`; empty: none, the plain filter), each
    a random walk of ``parameter_random_walk`` (log^2 / s).
    The model is corrected in place: after ``update`` its temperatures are the estimate.
    """

    def __init__(
        self,
        model: ThermalModel,
        regions: Mapping[str, Sequence[str]],
        ir_noise_c: float | Mapping[str, float] = 0.1,
        *,
        process_noise_c2_per_s: float | Sequence[float] = PROCESS_NOISE_C2_PER_S,
        offsets_c: Mapping[str, float] | None = None,
        offset_sigma_c: float = OFFSET_SIGMA_C,
        initial_sigma_c: float = 0.0,
        bias_window: int = BIAS_WINDOW,
        bias_threshold_sigma: float = BIAS_THRESHOLD_SIGMA,
        reference_nodes: Sequence[str] | None = None,
        adapt: Sequence[AdaptedParameter] = (),
        parameter_random_walk: float = RANDOM_WALK_LOG2_PER_S,
        stand_drift_tau_s: float | None = None,
        stand_drift_sigma_um: float = STAND_DRIFT_SIGMA_UM,
    ) -> None:
        network = model.network
        self.model = model
        self.regions = {name: tuple(nodes) for name, nodes in regions.items()}
        self._region_names = tuple(self.regions)
        rows = observation_matrix(network, self.regions)
        count, measured = network.node_count, len(self._region_names)
        self._nodes = count
        self._modes = NetworkModes(network)
        self._response = ParameterResponse(network, self._modes, adapt) if adapt else None
        self._theta = np.array([p.prior_log for p in adapt], dtype=np.float64)
        if not (math.isfinite(parameter_random_walk) and parameter_random_walk >= 0):
            raise ModelError("the parameters' random walk must be finite and >= 0")
        self._theta_walk = float(parameter_random_walk)
        alpha = [k for k, p in enumerate(adapt) if p.kind == "alpha"]
        # the state index of the deformation gain (adapted "alpha"), if any
        self._alpha: int | None = count + measured + alpha[0] if alpha else None
        self._alpha_prior_log = adapt[alpha[0]].prior_log if alpha else 0.0
        self._thetas = slice(count + measured, count + measured + len(adapt))
        # With alpha, the camera stand's warm-up drift (thesis 4.8) as a known shape
        # ``A (1 - e^{-t/tau})`` of unknown amplitude A (µm on the chip): in the measured
        # drift, not in the link, so never compensated (update_deformation).
        if stand_drift_tau_s is not None and not (
            math.isfinite(stand_drift_tau_s) and stand_drift_tau_s > 0
        ):
            raise ModelError("the stand drift's time constant must be > 0")
        self._stand_tau_s = stand_drift_tau_s if alpha else None
        self._stand: int | None = self._thetas.stop if self._stand_tau_s is not None else None
        self._stand_um = 0.0
        size = self._thetas.stop + (self._stand is not None)
        # State: node temperatures, one offset per region, the adapted log scales, and the
        # stand drift's amplitude if any.
        self._h = np.zeros((measured, size))
        for k, name in enumerate(self._region_names):
            self._h[k, :count] = rows[name]
            self._h[k, count + k] = 1.0
        self._noise_c2 = np.array(
            [_per_region(ir_noise_c, name) ** 2 for name in self._region_names]
        )
        if np.any(np.isnan(self._noise_c2)) or np.any(self._noise_c2 < 0):
            raise ModelError("IR noise must be >= 0 (inf: ignore the region)")
        self._offsets = np.array([(offsets_c or {}).get(n, 0.0) for n in self._region_names])
        q = np.broadcast_to(np.asarray(process_noise_c2_per_s, dtype=np.float64), (count,))
        if not np.all(np.isfinite(q)) or np.any(q < 0):
            raise ModelError("process noise must be finite and >= 0")
        self._q = q.copy()
        self._p = np.zeros((size, size))
        self._p[:count, :count] = np.eye(count) * initial_sigma_c**2
        offsets = slice(count, count + measured)
        self._p[offsets, offsets] = np.eye(measured) * offset_sigma_c**2
        thetas = self._thetas
        self._p[thetas, thetas] = np.diag([p.prior_log_sigma**2 for p in adapt])
        if self._stand is not None:
            self._p[self._stand, self._stand] = stand_drift_sigma_um**2
        self._start_c = model.temperatures_c  # the mean at the covariance's time
        self._covariance_time_s = model.time_s
        self._transitions: dict[float, FloatArray] = {}
        # The model's own deformation weights (its reference nodes): d = w^T (T - T_ref).
        self._weights = network.deformation_weights_um_per_c(reference_nodes)
        self._window: dict[str, deque[float]] = {
            name: deque(maxlen=bias_window) for name in self._region_names
        }
        self._bias_threshold = bias_threshold_sigma / math.sqrt(bias_window)
        self.last_innovation: Innovation | None = None
        self.drifting = False
        self.biased_regions: tuple[str, ...] = ()
        self.updates = 0

    # -- state ----------------------------------------------------------------------------------

    @property
    def time_s(self) -> float:
        return self.model.time_s

    @property
    def temperatures_c(self) -> FloatArray:
        return self.model.temperatures_c

    @property
    def covariance_c2(self) -> FloatArray:
        """Covariance of the node temperatures (degC^2)."""
        covariance: FloatArray = self._p[: self._nodes, : self._nodes].copy()
        return covariance

    @property
    def adapted(self) -> tuple[AdaptedParameter, ...]:
        return () if self._response is None else self._response.parameters

    def parameter_estimates(self) -> dict[str, tuple[float, float]]:
        """Each adapted factor's estimate and 1-sigma (``s = e^theta``, sigma ``s sigma_theta``
        to first order), and each IR offset's (degC) and 1-sigma."""
        estimates: dict[str, tuple[float, float]] = {}
        tail = self._nodes + len(self._region_names)
        for k, parameter in enumerate(self.adapted):
            scale = math.exp(float(self._theta[k]))
            estimates[parameter.name] = (
                scale,
                scale * math.sqrt(max(self._p[tail + k, tail + k], 0)),
            )
        if self._stand is not None:
            variance = max(float(self._p[self._stand, self._stand]), 0.0)
            estimates["stand_drift_um"] = (self._stand_um, math.sqrt(variance))
        for k, name in enumerate(self._region_names):
            index = self._nodes + k
            estimates[f"offset:{name}"] = (
                float(self._offsets[k]),
                math.sqrt(max(float(self._p[index, index]), 0.0)),
            )
        return estimates

    @property
    def offsets_c(self) -> dict[str, float]:
        """The current estimate of each region's IR offset (degC)."""
        return {n: float(v) for n, v in zip(self._region_names, self._offsets, strict=True)}

    @property
    def deformation_gain(self) -> float:
        """The ``alpha`` factor applied to the model's deformation (1 without it): the
        estimate shrunk towards its prior by ``u^2 / (u^2 + sigma^2)`` (``u`` the estimate's
        departure from the prior, in the log), the weight that minimises the expected squared
        error of applying it (Wiener's); early in a run, while the camera has seen little
        deformation and cannot yet tell the stand from the link, a barely known factor is not
        applied. Once known (1-sigma << departure) it is the estimate."""
        if self._alpha is None:
            return 1.0
        departure = float(self._theta[self._alpha - self._thetas.start]) - self._alpha_prior_log
        variance = max(float(self._p[self._alpha, self._alpha]), 0.0)
        total = departure * departure + variance
        weight = departure * departure / total if total > 0.0 else 1.0
        return math.exp(self._alpha_prior_log + weight * departure)

    def _deformation_gradient(self, applied: bool = True) -> tuple[float, FloatArray]:
        """The corrected deformation ``s_a w^T (T - T_ref)`` and its gradient over the state;
        ``s_a``: the factor applied (:attr:`deformation_gain`), or (``applied=False``, for the
        camera's measurement model) the estimate itself."""
        if applied or self._alpha is None:
            gain = self.deformation_gain
        else:
            gain = math.exp(float(self._theta[self._alpha - self._thetas.start]))
        deformation = gain * self.model.deformation_um_scalar()
        gradient = np.zeros(self._p.shape[0])
        gradient[: self._nodes] = gain * self._weights
        if self._alpha is not None:
            gradient[self._alpha] = deformation  # d/d(log s_a)
        return deformation, gradient

    def corrected_deformation_um(self) -> tuple[float, float]:
        """The corrected deformation along the link (µm) and its 1-sigma, ``sqrt(g^T P g)``
        (``g`` its gradient: ``w`` on the temperatures, and the deformation itself on the log
        of an adapted ``alpha``)."""
        deformation, gradient = self._deformation_gradient()
        variance = float(gradient @ self._p @ gradient)
        return deformation, math.sqrt(max(variance, 0.0))

    def update_deformation(
        self, measured_um: float, noise_um: float, scale: float = 1.0
    ) -> float | None:
        """Fuse one measured deformation (µm along the link, unscaled: the spot drift with the
        commanded compensation taken out, divided by the deformation scale) of 1-sigma
        ``noise_um``, into the adapted ``alpha`` ONLY: the gain of every other state is set
        to zero (a partial update, the "consider" idea of the Schmidt-Kalman filter), so the
        camera calibrates the expansion factor and never steers the temperatures to the
        measured drift, which a camera-stand drift would otherwise enter one for one. The
        Joseph form keeps the covariance right for this suboptimal gain. With a stand drift
        state (``stand_drift_tau_s``) the reading is ``s_a d + A (1 - e^{-t/tau}) / scale``
        (``scale``: the run's deformation scale; the stand moves the chip, not the link) and
        updates A too: a drift of the stand's shape is then not taken for expansion. Returns
        the normalised innovation, or None when nothing was fused (no adapted alpha, a
        non-finite value)."""
        if self._alpha is None or not (math.isfinite(measured_um) and noise_um > 0):
            return None
        predicted, row = self._deformation_gradient(applied=False)
        chosen = [self._alpha]
        if self._stand is not None and self._stand_tau_s is not None:
            shape = -math.expm1(-max(self.model.time_s, 0.0) / self._stand_tau_s) / scale
            row[self._stand] = shape
            predicted += self._stand_um * shape
            chosen.append(self._stand)
        innovation = measured_um - predicted
        variance = float(row @ self._p @ row) + noise_um**2
        gain = np.zeros(self._p.shape[0])
        gain[chosen] = (self._p[chosen] @ row) / variance
        self._theta = np.clip(self._theta + gain[self._thetas] * innovation, *LOG_BOUNDS)
        if self._stand is not None:
            self._stand_um += float(gain[self._stand]) * innovation
        identity_minus = np.eye(gain.size) - np.outer(gain, row)
        self._p = identity_minus @ self._p @ identity_minus.T + np.outer(gain, gain) * noise_um**2
        return innovation / math.sqrt(variance)

    @property
    def warning(self) -> str | None:
        return DRIFT_WARNING if self.drifting else None

    # -- the filter -----------------------------------------------------------------------------

    def _transition(self, tau_s: float) -> FloatArray:
        """``Ad = e^{A tau}`` from the network's modes: ``C^-1/2 V e^{-lam tau} V^T C^1/2``."""
        cached = self._transitions.get(tau_s)
        if cached is None:
            modes = self._modes
            left = modes.vectors / modes.root_c[:, None]
            right = modes.vectors.T * modes.root_c
            cached = (left * np.exp(-modes.rates * tau_s)) @ right
            if len(self._transitions) > 8:
                self._transitions.clear()
            self._transitions[tau_s] = cached
        return cached

    def predict(self, t_s: float) -> None:
        """Advance the estimate to ``t_s``: the model's own exact step for the mean, ``Ad`` for
        the covariance (offsets are constant). The caller may also advance the model itself
        (e.g. to switch a heater at its exact time): the covariance catches up here, from the
        time it was last propagated to."""
        self.model.advance_to(t_s)
        tau = self.model.time_s - self._covariance_time_s
        self._covariance_time_s = self.model.time_s
        if tau <= 0.0:
            return
        n = self._nodes
        transition = self._transition(tau)
        with one_blas_thread(self._p.shape[0]):  # daemon/model/blas.py: 16 ms each threaded
            if self._response is not None:
                self._predict_adapted(tau, transition)
                self._start_c = self.model.temperatures_c
                return
            p = self._p
            p[:n, :n] = transition @ p[:n, :n] @ transition.T + np.diag(self._q * tau)
            p[:n, n:] = transition @ p[:n, n:]
            p[n:, :n] = p[:n, n:].T
        self._start_c = self.model.temperatures_c

    def _predict_adapted(self, tau: float, transition: FloatArray) -> None:
        """The adapted step (module docstring of daemon.model.adaptation): the model's nominal
        step, corrected by ``Gamma db``; the covariance by the EKF's Jacobian."""
        assert self._response is not None
        n, thetas = self._nodes, self._thetas
        model = self.model
        nominal = model.temperatures_c
        gain = self._response.gain(tau)
        drive, columns, d_temperature = self._response.drive(
            self._theta, model.heat_w, model.ambient_c, 0.5 * (self._start_c + nominal)
        )
        model.set_temperatures(nominal + gain @ drive)
        # the Jacobian [[a, b], [0, I]]: the offsets and log factors are constants
        a = transition + gain * d_temperature  # Gamma diag(d db / dT)
        b = np.zeros((n, self._p.shape[0] - n))
        b[:, thetas.start - n : thetas.stop - n] = gain @ columns
        noise = np.zeros(self._p.shape[0])
        noise[:n] = self._q * tau
        noise[thetas] = self._theta_walk * tau
        if self._alpha is not None:
            # alpha is a constant: with a random walk the camera's every reading would move
            # it, and it would follow the measured drift (a stand drift too) within seconds,
            # a camera servo rather than a model; constant, it is the least-squares gain of
            # the whole run so far
            noise[self._alpha] = 0.0
        self._p = propagate_nodes(self._p, n, a, b, noise)

    def update(self, measurements_c: Mapping[str, float]) -> Innovation | None:
        """Fuse one IR reading (region -> mean degC; unknown regions, NaN values and regions of
        infinite noise are ignored). Returns the innovation statistics (None: nothing used)."""
        used = [
            k
            for k, name in enumerate(self._region_names)
            if name in measurements_c
            and math.isfinite(measurements_c[name])
            and math.isfinite(self._noise_c2[k])
        ]
        if not used:
            return None
        n = self._nodes
        h = self._h[used]
        stand = [self._stand_um] if self._stand is not None else []
        state = np.concatenate([self.model.temperatures_c, self._offsets, self._theta, stand])
        z = np.array([measurements_c[self._region_names[k]] for k in used])
        innovation = z - h @ state
        with one_blas_thread(self._p.shape[0]):  # daemon/model/blas.py
            hp = h @ self._p
            s = hp @ h.T + np.diag(self._noise_c2[used])
            gain = np.asarray(np.linalg.solve(s, hp).T, dtype=np.float64)
            state = state + gain @ innovation
            # the Joseph form (right for any gain, not only the optimal one), expanded by
            # its rank: m readings, products of rank m (daemon/model/covariance.py)
            self._p = joseph_update(self._p, gain, h, hp, self._noise_c2[used])
        measured = len(self._region_names)
        self.model.set_temperatures(state[:n])
        self._start_c = state[:n].copy()
        self._offsets = state[n : n + measured]
        # a factor's log stays within identification's bounds (1/10 .. 10): a wild first
        # innovation must not send the model somewhere it cannot come back from
        self._theta = np.clip(state[self._thetas], *LOG_BOUNDS)
        if self._stand is not None:
            self._stand_um = float(state[self._stand])
        nis = float(innovation @ np.linalg.solve(s, innovation))
        variances = np.diag(s)
        names = [self._region_names[k] for k in used]
        for name, value, variance in zip(names, innovation, variances, strict=True):
            self._window[name].append(float(value / math.sqrt(variance)))
        self._check_bias()
        self.updates += 1
        self.last_innovation = Innovation(
            time_s=self.model.time_s,
            innovation_c={k: float(v) for k, v in zip(names, innovation, strict=True)},
            variance_c2={k: float(v) for k, v in zip(names, variances, strict=True)},
            nis=nis,
            degrees_of_freedom=len(used),
        )
        return self.last_innovation

    def _check_bias(self) -> None:
        """A persistent bias: over a full window, the mean normalised innovation of a region
        lies beyond the threshold (its standard deviation is 1/sqrt(window) when the model and
        the noise levels are right). The flag latches (logged once): the run's model is
        suspect from then on; ``biased_regions`` says where it is biased now."""
        self.biased_regions = tuple(
            name
            for name, window in self._window.items()
            if len(window) == window.maxlen and abs(float(np.mean(window))) > self._bias_threshold
        )
        if self.biased_regions and not self.drifting:
            logger.warning(
                "%s (IR innovations biased in %s)", DRIFT_WARNING, ", ".join(self.biased_regions)
            )
            self.drifting = True

    def step(self, t_s: float, measurements_c: Mapping[str, float] | None) -> tuple[float, float]:
        """One control step: predict to ``t_s``, fuse the reading if any, and return the
        corrected deformation (µm) and its 1-sigma."""
        self.predict(t_s)
        if measurements_c:
            self.update(measurements_c)
        return self.corrected_deformation_um()


def _per_region(value: float | Mapping[str, float], region: str) -> float:
    if isinstance(value, Mapping):
        return float(value.get(region, math.inf))
    return float(value)


__all__ = [
    "DRIFT_WARNING",
    "Innovation",
    "IrObserver",
    "IrRegionLike",
    "regions_to_nodes",
]
