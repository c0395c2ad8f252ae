"""Time stepping of a thermal network, on demand, and the deformation it predicts.

The network is linear and time-invariant between parameter changes:
``dT/dt = A T + C^-1 b`` with ``A = -C^-1 K`` and ``b = q + g_amb T_amb`` constant while the
heat inputs and ambient stay put. Every stepper therefore reduces one step to
``T <- M T + c`` (or a sparse solve) with ``M`` computed once per step length, and ``c``
recomputed only when ``b`` changes:

* ``explicit``: Eq. 5.1 exactly (``M = I - dt C^-1 K``, ``c = dt C^-1 b``); it refuses a ``dt``
  above the bound ``min C_i / sum_j 1/R_ij`` (thesis 5.4) unless asked to sub-step;
* ``exact``: the zero-order hold, ``M = e^{A dt}``, ``c = (int_0^dt e^{As} ds) C^-1 b``, both
  read off the matrix exponential of the augmented system (DESIGN.md "Eq. 5.1"): stable and
  exact for any ``dt``;
* ``implicit``: backward Euler with a sparse LU factorisation of ``C/dt + K`` computed once,
  for networks of thousands of nodes.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from typing import Literal, Protocol

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.linalg import expm
from scipy.sparse.linalg import splu

from daemon.model.network import FloatArray, ThermalNetwork, positivity_bound_s

logger = logging.getLogger(__name__)

Stepper = Literal["exact", "explicit", "implicit"]
STEPPERS: tuple[Stepper, ...] = ("exact", "explicit", "implicit")

#: The exact stepper builds dense (2N x 2N) exponentials; beyond this, use ``implicit``.
EXACT_NODE_LIMIT = 2000
#: Up to this size the exact step comes from scipy's expm of the augmented system; beyond, from
#: the network's modes (the same matrices, far cheaper to compute for hundreds of nodes).
EXPM_NODE_LIMIT = 200
#: Networks up to this size step with dense matrices (faster than sparse for small N).
DENSE_STEP_LIMIT = 400
#: Partial step lengths whose discretisation stays cached besides the main dt's.
CACHED_STEP_LENGTHS = 8
#: Relative tolerance on time: a remainder below this fraction of dt is rounding, not a step.
TIME_TOLERANCE = 1e-9


class ModelError(ValueError):
    """A model cannot do what was asked (dt above the explicit bound, time going back...)."""


class _Discretisation(Protocol):
    def set_input(self, drive_w: FloatArray) -> None: ...

    def advance(self, temperatures: FloatArray, steps: int) -> FloatArray: ...


class _AffineStep:
    """``T <- M T + c`` with a dense or sparse ``M``; ``input_matrix`` maps ``b`` to ``c``."""

    def __init__(
        self,
        transition: FloatArray | sp.csr_matrix,
        input_matrix: FloatArray | sp.dia_matrix,
        substeps: int = 1,
    ) -> None:
        self._transition = transition
        self._input_matrix = input_matrix
        self._substeps = substeps
        size = transition.shape[0]
        self._offset = np.zeros(size)
        self._dense = isinstance(transition, np.ndarray)
        self._spare = np.empty(size)

    def set_input(self, drive_w: FloatArray) -> None:
        self._offset = np.asarray(self._input_matrix @ drive_w, dtype=np.float64)

    def advance(self, temperatures: FloatArray, steps: int) -> FloatArray:
        current, spare, offset = temperatures, self._spare, self._offset
        transition = self._transition
        if self._dense:
            dot = np.dot
            for _ in range(steps * self._substeps):
                dot(transition, current, out=spare)  # no allocation per step
                spare += offset
                current, spare = spare, current
        else:
            for _ in range(steps * self._substeps):
                current = transition @ current
                current += offset
        self._spare = spare
        return current


class _BackwardEulerStep:
    """``(C/dt + K) T' = (C/dt) T + b``, factorised once."""

    def __init__(self, network: ThermalNetwork, dt_s: float) -> None:
        self._capacitance_per_dt = network.capacitance_j_per_c / dt_s
        system = sp.diags(self._capacitance_per_dt) + network.conductance_matrix
        self._factor = splu(sp.csc_matrix(system))
        self._drive = np.zeros(network.node_count)

    def set_input(self, drive_w: FloatArray) -> None:
        self._drive = drive_w.copy()

    def advance(self, temperatures: FloatArray, steps: int) -> FloatArray:
        current = temperatures
        for _ in range(steps):
            current = self._factor.solve(self._capacitance_per_dt * current + self._drive)
        return current


class NetworkModes:
    """The network's modes, for exact steps of any length without a new exponential:
    ``C^-1/2 K C^-1/2 = V diag(lam) V^T`` (symmetric positive definite), so with
    ``z = V^T C^1/2 T`` each mode obeys ``dz/dt = -lam z + g``, ``g = V^T C^-1/2 b``, and the
    zero-order hold over ``tau`` is ``z <- e^{-lam tau} z + (1 - e^{-lam tau}) / lam g``: the
    same solution as the matrix exponential, computed once per network."""

    def __init__(self, network: ThermalNetwork) -> None:
        self.root_c = np.sqrt(network.capacitance_j_per_c)
        symmetric = network.conductance_matrix.toarray() / np.outer(self.root_c, self.root_c)
        self.rates, self.vectors = np.linalg.eigh(symmetric)
        self.forcing = np.zeros(network.node_count)

    def set_input(self, drive_w: FloatArray) -> None:
        self.forcing = self.vectors.T @ (drive_w / self.root_c)


class _ModalStep:
    """One exact step of length ``tau`` through :class:`NetworkModes` (for advance_to's remainders:
    two mat-vecs instead of a new exponential per remainder length)."""

    def __init__(self, modes: NetworkModes, tau_s: float) -> None:
        self._modes = modes
        self._decay = np.exp(-modes.rates * tau_s)
        self._gain = -np.expm1(-modes.rates * tau_s) / modes.rates

    def set_input(self, drive_w: FloatArray) -> None:
        pass  # the shared modes hold the input

    def advance(self, temperatures: FloatArray, steps: int) -> FloatArray:
        modes = self._modes
        z = modes.vectors.T @ (modes.root_c * temperatures)
        for _ in range(steps):
            z = self._decay * z + self._gain * modes.forcing
        result: FloatArray = (modes.vectors @ z) / modes.root_c
        return result


class ThermalModel:
    """A network's temperatures, advanced on demand (thesis 6.4.1: "computed on demand at
    each time step"), and the deformation between two reference nodes.

    ``time_s`` starts at 0 with every node at ``initial_c`` (default: ambient);
    ``reference_c`` is the temperature of zero deformation (default: the initial one).
    """

    def __init__(
        self,
        network: ThermalNetwork,
        stepper: Stepper = "exact",
        dt_s: float = 1.0,
        ambient_c: float = 22.0,
        *,
        initial_c: float | ArrayLike | None = None,
        reference_c: float | ArrayLike | None = None,
        reference_nodes: Sequence[str] | None = None,
        direction: ArrayLike | None = None,
        allow_substeps: bool = False,
    ) -> None:
        if stepper not in STEPPERS:
            raise ModelError(f"unknown stepper {stepper!r}; choose one of {', '.join(STEPPERS)}")
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ModelError(f"dt must be a positive number of seconds, got {dt_s}")
        if not math.isfinite(ambient_c):
            raise ModelError(f"ambient temperature must be finite, got {ambient_c}")
        count = network.node_count
        if stepper == "exact" and count > EXACT_NODE_LIMIT:
            raise ModelError(
                f"the exact stepper is dense and limited to {EXACT_NODE_LIMIT} nodes; "
                f"network {network.name!r} has {count}: use the implicit stepper"
            )
        self.network = network
        self.stepper: Stepper = stepper
        self.dt_s = float(dt_s)
        self.allow_substeps = allow_substeps
        self._ambient_c = float(ambient_c)
        self._heat_w = np.array(network.heat_w, dtype=np.float64)
        self._temperatures = self._per_node(ambient_c if initial_c is None else initial_c)
        self._reference_c = (
            self._temperatures.copy() if reference_c is None else self._per_node(reference_c)
        )
        self._weights = network.deformation_weights_um_per_c(reference_nodes)
        axis = network.direction if direction is None else np.asarray(direction, np.float64)
        norm = float(np.linalg.norm(axis))
        if axis.shape != (3,) or not math.isfinite(norm) or norm == 0.0:
            raise ModelError(f"direction {direction!r} is not a non-zero 3-vector")
        self._direction = axis / norm
        self._time_s = 0.0
        self._positivity_bound_s = positivity_bound_s(network)
        self._partial_steps: OrderedDict[float, _Discretisation] = OrderedDict()
        self._modes: NetworkModes | None = None  # built on the first partial exact step
        self._main_step = self._build(self.dt_s)  # fails now if the explicit bound refuses dt
        self._main_step.set_input(self._drive_w())

    def _per_node(self, value: float | ArrayLike) -> FloatArray:
        array = np.broadcast_to(np.asarray(value, dtype=np.float64), (self.network.node_count,))
        if not np.all(np.isfinite(array)):
            raise ModelError("temperatures must be finite")
        return array.astype(np.float64, copy=True)

    # -- state --------------------------------------------------------------------------------

    @property
    def time_s(self) -> float:
        return self._time_s

    @property
    def temperatures_c(self) -> FloatArray:
        return self._temperatures.copy()

    @property
    def heat_w(self) -> FloatArray:
        return self._heat_w.copy()

    @property
    def ambient_c(self) -> float:
        return self._ambient_c

    @property
    def positivity_bound_s(self) -> float:
        return self._positivity_bound_s

    def set_heat(self, heat_w: Mapping[str, float]) -> None:
        """Heat input per node in W, keyed by node NAME (issue 19: never by number); replaces
        all inputs, effective from the current time on (zero-order hold)."""
        for node, watts in heat_w.items():
            if not math.isfinite(watts):
                raise ModelError(f"node {node!r}: heat input must be finite, got {watts}")
        self._set_heat_vector(self.network.heat_by_name(heat_w))

    def set_heat_at_position(self, heat_w_by_position_mm: Mapping[float, float]) -> None:
        """Heat inputs given where they enter the link (mm); replaces all inputs.

        A source between two node centres is shared between them in proportion to
        proximity (linear interpolation), so that moving a source by less than one node
        spacing changes the result smoothly; beyond the outermost nodes it goes to the
        outermost node."""
        positions = self.network.positions_mm
        order = np.argsort(positions, kind="stable")
        sorted_x = positions[order]
        heat = np.zeros(self.network.node_count)
        for position, watts in heat_w_by_position_mm.items():
            if not (math.isfinite(position) and math.isfinite(watts)):
                raise ModelError(f"heat {watts} W at {position} mm: values must be finite")
            upper = int(np.searchsorted(sorted_x, position))
            if upper == 0 or upper == len(sorted_x):
                heat[order[min(upper, len(sorted_x) - 1)]] += watts
                continue
            x0, x1 = sorted_x[upper - 1], sorted_x[upper]
            share = (position - x0) / (x1 - x0) if x1 > x0 else 1.0
            heat[order[upper - 1]] += watts * (1.0 - share)
            heat[order[upper]] += watts * share
        self._set_heat_vector(heat)

    def set_ambient(self, ambient_c: float) -> None:
        if not math.isfinite(ambient_c):
            raise ModelError(f"ambient temperature must be finite, got {ambient_c}")
        self._ambient_c = float(ambient_c)
        self._refresh_inputs()

    def set_temperatures(self, temperatures_c: float | ArrayLike) -> None:
        """Overwrite the state (e.g. from a measurement); the time does not change."""
        self._temperatures = self._per_node(temperatures_c)

    def _set_heat_vector(self, heat: FloatArray) -> None:
        self._heat_w = heat
        self._refresh_inputs()

    def _drive_w(self) -> FloatArray:
        """``b = q + g_amb T_amb``: everything that drives the network but its own state."""
        drive: FloatArray = self._heat_w + self.network.ambient_conductance_w_per_c * (
            self._ambient_c
        )
        return drive

    def _refresh_inputs(self) -> None:
        drive = self._drive_w()
        self._main_step.set_input(drive)
        if self._modes is not None:
            self._modes.set_input(drive)
        for discretisation in self._partial_steps.values():
            discretisation.set_input(drive)

    # -- stepping -----------------------------------------------------------------------------

    def _discretisation(self, dt_s: float) -> _Discretisation:
        """The step of length ``dt_s``: the main one, or a partial one built once and cached
        (advance_to's partial steps are as exact as the full ones)."""
        if dt_s == self.dt_s:
            return self._main_step
        cached = self._partial_steps.get(dt_s)
        if cached is not None:
            self._partial_steps.move_to_end(dt_s)
            return cached
        if self.stepper == "exact":
            built: _Discretisation = _ModalStep(self._ensure_modes(), dt_s)
        else:
            built = self._build(dt_s)
            built.set_input(self._drive_w())
        self._partial_steps[dt_s] = built
        if len(self._partial_steps) > CACHED_STEP_LENGTHS:
            self._partial_steps.popitem(last=False)
        return built

    def _ensure_modes(self) -> NetworkModes:
        if self._modes is None:
            self._modes = NetworkModes(self.network)
            self._modes.set_input(self._drive_w())
        return self._modes

    def _build(self, dt_s: float) -> _Discretisation:
        logger.debug(
            "discretising %s (%d nodes, %s) for dt = %g s",
            self.network.name,
            self.network.node_count,
            self.stepper,
            dt_s,
        )
        network = self.network
        count = network.node_count
        inverse_c = 1.0 / network.capacitance_j_per_c
        if self.stepper == "implicit":
            return _BackwardEulerStep(network, dt_s)
        if self.stepper == "explicit":
            bound = self._positivity_bound_s
            substeps = 1
            if dt_s > bound * (1.0 + 1e-12):
                if not self.allow_substeps:
                    raise ModelError(
                        f"explicit step dt = {dt_s:g} s exceeds the bound min C_i / sum_j "
                        f"1/R_ij = {bound:.6g} s of network {network.name!r} (thesis 5.4); "
                        "use a smaller dt, sub-steps, or the exact stepper"
                    )
                substeps = math.ceil(dt_s / bound * (1.0 - 1e-12))
            h = dt_s / substeps
            # Eq. 5.1: T' = T + h/C (q + sum_j (T_j - T_i)/R_ij + (T_amb - T_i)/R_inf).
            transition = (
                sp.identity(count, format="csr")
                - sp.diags(h * inverse_c) @ network.conductance_matrix
            )
            input_matrix = sp.diags(h * inverse_c)
            if count <= DENSE_STEP_LIMIT:
                return _AffineStep(transition.toarray(), input_matrix.toarray(), substeps)
            return _AffineStep(sp.csr_matrix(transition), sp.dia_matrix(input_matrix), substeps)
        if count > EXPM_NODE_LIMIT:
            # The same two matrices from the modes: O(N^3) once instead of a (2N)^3 exponential.
            modes = self._ensure_modes()
            left = modes.vectors / modes.root_c[:, None]  # C^-1/2 V
            decay = np.exp(-modes.rates * dt_s)
            gain = -np.expm1(-modes.rates * dt_s) / modes.rates
            transition_modal = (left * decay) @ (modes.vectors.T * modes.root_c)
            input_modal = (left * gain) @ left.T
            return _AffineStep(transition_modal, input_modal)
        # exact: expm([[A, C^-1], [0, 0]] dt) = [[e^{A dt}, int_0^dt e^{As} ds C^-1], [0, I]].
        augmented = np.zeros((2 * count, 2 * count))
        augmented[:count, :count] = -(inverse_c[:, None] * network.conductance_matrix.toarray())
        augmented[:count, count:] = np.diag(inverse_c)
        exponential = expm(augmented * dt_s)
        transition_dense = np.ascontiguousarray(exponential[:count, :count])
        input_dense = np.ascontiguousarray(exponential[:count, count:])
        return _AffineStep(transition_dense, input_dense)

    def advance_to(self, t_s: float) -> None:
        """Advance from ``time_s`` to ``t_s`` in steps of ``dt_s`` and one exact partial step
        for the remainder. ``t_s`` earlier than ``time_s`` is an error."""
        dt_s = self.dt_s
        span = t_s - self._time_s
        if not span > -TIME_TOLERANCE * dt_s:  # also catches NaN
            if not math.isfinite(t_s):
                raise ModelError(f"time must be finite, got {t_s}")
            raise ModelError(f"cannot go back in time: model at {self._time_s} s, asked {t_s} s")
        if math.isinf(t_s):
            raise ModelError(f"time must be finite, got {t_s}")
        steps = math.floor(span / dt_s + TIME_TOLERANCE)
        remainder = span - steps * dt_s
        temperatures = self._temperatures
        if steps > 0:
            temperatures = self._main_step.advance(temperatures, steps)
        if remainder > TIME_TOLERANCE * dt_s:
            temperatures = self._discretisation(remainder).advance(temperatures, 1)
        # The dense steppers swap our array with their spare one: every buffer stays distinct,
        # so no step allocates.
        self._temperatures = temperatures
        if t_s > self._time_s:
            self._time_s = float(t_s)

    def step(self, count: int = 1) -> None:
        """``count`` full steps of ``dt_s``."""
        self.advance_to(self._time_s + count * self.dt_s)

    # -- deformation --------------------------------------------------------------------------

    def deformation_um_scalar(self) -> float:
        """Growth of the distance between the reference nodes (µm): ``sum alpha_i (T_i -
        T_ref,i) l_i`` (DESIGN.md "Deformation")."""
        return float(self._weights @ (self._temperatures - self._reference_c))

    def deformation_um(self) -> FloatArray:
        """The deformation as a 3-vector along the link's direction (µm)."""
        vector: FloatArray = self.deformation_um_scalar() * self._direction
        return vector


__all__ = ["EXACT_NODE_LIMIT", "STEPPERS", "ModelError", "Stepper", "ThermalModel"]
