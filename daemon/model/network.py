"""The thermal resistance-capacitance network of thesis 5.4 and the facts that follow from it.

A node has a capacitance ``C_i`` (J/°C), a position along the link, an expansion coefficient,
and paths to ambient: ``R_inf,i`` (convection from its faces along the link) and, for the
nodes at the bar's ends, an end-face resistance (Table 5.1's ``R-`` of node 1 and ``R+`` of
node 17). Resistances ``R_ij`` join nodes. Ambient is a node of fixed temperature (DESIGN.md,
Eq. 5.1), so the network is ``C dT/dt = -K T + q + g_amb T_amb`` with ``K`` the conductance
matrix (the graph Laplacian of ``1/R_ij`` plus ``g_amb`` on the diagonal).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.sparse.csgraph import connected_components

from config.inputs import InputError
from daemon.model.calibration import Calibration
from daemon.model.spectrum import largest_eigenvalue, smallest_eigenvalue

FloatArray = NDArray[np.float64]

UM_PER_MM = 1000.0

#: Up to this many nodes the dense eigen-solver gives the network facts.
DENSE_LIMIT = 2000
#: Most nodes a network may have (issue 26): a run steps up to this many with the implicit
#: stepper; beyond, one file (a 0.0001 mm node spacing) took minutes and gigabytes to build.
MAX_NETWORK_NODES = 10_000
#: An error naming a network's nodes lists at most this many of them (a 2 mm geometry network
#: has ~300), then the count.
LISTED_NODES = 24


class NetworkError(InputError):
    """An invalid thermal network or an unknown node; the message names the node."""


@dataclass(frozen=True, slots=True)
class Resistance:
    """A thermal resistance ``r_c_per_w`` between nodes ``a`` and ``b`` (0-based indices)."""

    a: int
    b: int
    r_c_per_w: float


def _frozen(values: ArrayLike, count: int, what: str) -> FloatArray:
    array = np.array(values, dtype=np.float64).reshape(-1)
    if array.shape != (count,):
        raise NetworkError(f"{what}: expected {count} values, got {array.size}")
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class ThermalNetwork:
    """A validated network. Build it with the constructor; every array is read-only.

    ``r_ambient_c_per_w`` / ``r_end_c_per_w`` hold ``inf`` where a node has no such path.
    ``bar_ends_mm`` bound the first and last control volumes (DESIGN.md "Deformation");
    by default the outermost node centres. ``heat_w`` is each node's heat input ``q_i`` as
    the network defines it (a model starts from it; ``ThermalModel.set_heat`` replaces it).
    """

    name: str
    node_names: tuple[str, ...]
    positions_mm: FloatArray
    capacitance_j_per_c: FloatArray
    alpha_per_c: FloatArray
    r_ambient_c_per_w: FloatArray
    r_end_c_per_w: FloatArray
    resistances: tuple[Resistance, ...]
    reference_nodes: tuple[str, str]
    heater_nodes: tuple[str, ...] = ()
    direction: FloatArray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    bar_ends_mm: tuple[float, float] | None = None
    description: str = ""
    heat_w: FloatArray = field(default_factory=lambda: np.zeros(0))  # q_i (W); empty: zero
    # Issue 20: the link each node belongs to and its 3-D position (mm, N x 3); empty / None
    # for a one-dimensional network (every node on one straight bar along ``direction``).
    node_links: tuple[str, ...] = ()
    positions_3d_mm: FloatArray | None = None
    #: What identification found beyond the node values (daemon.model.calibration.Calibration:
    #: source runs, parameter uncertainties, IR offsets); None for a network nobody identified.
    calibration: Calibration | None = None
    _index: dict[str, int] = field(init=False, repr=False, default_factory=dict)

    def __post_init__(self) -> None:
        count = len(self.node_names)
        if count == 0:
            raise NetworkError(f"network {self.name!r} has no nodes")
        if count > MAX_NETWORK_NODES:
            raise NetworkError(
                f"network {self.name!r} has {count} nodes: at most {MAX_NETWORK_NODES}"
            )
        set_ = object.__setattr__  # frozen: normalise the arrays once, here
        set_(self, "node_names", tuple(str(n) for n in self.node_names))
        if np.size(self.heat_w) == 0:
            set_(self, "heat_w", np.zeros(count))
        for attr in (
            "positions_mm",
            "capacitance_j_per_c",
            "alpha_per_c",
            "r_ambient_c_per_w",
            "r_end_c_per_w",
            "heat_w",
        ):
            set_(self, attr, _frozen(getattr(self, attr), count, attr))
        direction = np.array(self.direction, dtype=np.float64).reshape(-1)
        norm = float(np.linalg.norm(direction)) if direction.shape == (3,) else 0.0
        if not math.isfinite(norm) or norm == 0.0:
            raise NetworkError(f"direction {self.direction!r} is not a non-zero 3-vector")
        direction = direction / norm
        direction.setflags(write=False)
        set_(self, "direction", direction)
        set_(self, "node_links", tuple(str(link) for link in self.node_links))
        if self.node_links and len(self.node_links) != count:
            raise NetworkError(
                f"node_links: expected {count} link names, got {len(self.node_links)}"
            )
        if self.positions_3d_mm is not None:
            spatial = np.array(self.positions_3d_mm, dtype=np.float64)
            if spatial.shape != (count, 3) or not np.all(np.isfinite(spatial)):
                raise NetworkError(
                    f"positions_3d_mm: expected {count} finite 3-D positions, got shape "
                    f"{spatial.shape}"
                )
            spatial.setflags(write=False)
            set_(self, "positions_3d_mm", spatial)
        self._index.update({name: i for i, name in enumerate(self.node_names)})
        self._validate()
        if self.bar_ends_mm is None:
            set_(
                self,
                "bar_ends_mm",
                (float(self.positions_mm.min()), float(self.positions_mm.max())),
            )

    # -- validation ---------------------------------------------------------------------------

    def _validate(self) -> None:
        names = self.node_names
        seen: set[str] = set()
        for name in names:
            if name in seen:
                raise NetworkError(f"node {name!r} is defined twice")
            seen.add(name)
        for i, name in enumerate(names):
            c = self.capacitance_j_per_c[i]
            if not math.isfinite(c) or c <= 0.0:
                raise NetworkError(f"node {name!r}: capacitance must be positive, got {c}")
            for label, value in (
                ("position_mm", self.positions_mm[i]),
                ("alpha_per_c", self.alpha_per_c[i]),
                ("heat_w", self.heat_w[i]),
            ):
                if not math.isfinite(value):
                    raise NetworkError(f"node {name!r}: {label} is {value}")
            for label, r in (
                ("ambient resistance", self.r_ambient_c_per_w[i]),
                ("end-face resistance", self.r_end_c_per_w[i]),
            ):
                if math.isnan(r) or r <= 0.0:
                    raise NetworkError(f"node {name!r}: {label} must be positive, got {r}")
        for res in self.resistances:
            for end in (res.a, res.b):
                if not 0 <= end < len(names):
                    raise NetworkError(f"resistance joins unknown node index {end}")
            where = f"resistance between nodes {names[res.a]!r} and {names[res.b]!r}"
            if res.a == res.b:
                raise NetworkError(f"{where}: a node cannot be joined to itself")
            if not math.isfinite(res.r_c_per_w) or res.r_c_per_w <= 0.0:
                raise NetworkError(f"{where}: must be positive and finite, got {res.r_c_per_w}")
        for name in (*self.reference_nodes, *self.heater_nodes):
            self.node_index(name)
        self._check_paths_to_ambient()

    def _check_paths_to_ambient(self) -> None:
        """Every node must reach ambient, else its temperature grows without bound."""
        count, labels = connected_components(self.between_nodes_matrix, directed=False)
        grounded = np.zeros(count, dtype=bool)
        grounded[labels[self.ambient_conductance_w_per_c > 0.0]] = True
        if not grounded.all():
            stranded = [n for n, label in zip(self.node_names, labels, strict=True)
                        if not grounded[label]]  # fmt: skip
            raise NetworkError(
                f"node {stranded[0]!r} has no path to ambient"
                + (f" (nor {len(stranded) - 1} other node(s))" if len(stranded) > 1 else "")
            )

    # -- lookup -------------------------------------------------------------------------------

    @property
    def node_count(self) -> int:
        return len(self.node_names)

    def node_index(self, name_or_number: str | int) -> int:
        """0-based index of a node given by name, or by its 1-based number (thesis numbering).

        A name wins over a number, so geometry networks can name nodes "left-shaft" and still
        be addressed by number.
        """
        key = str(name_or_number).strip()
        if key in self._index:
            return self._index[key]
        if key.isdigit() and 1 <= int(key) <= self.node_count:
            return int(key) - 1
        raise NetworkError(
            f"unknown node {key!r} in network {self.name!r} (names or numbers 1..{self.node_count})"
        )

    @property
    def is_spatial(self) -> bool:
        """True when every node carries its link and 3-D position (issue 20)."""
        return bool(self.node_links) and self.positions_3d_mm is not None

    def one_dimensional_problem(self) -> str | None:
        """Why this network cannot be read as one straight bar, or None if it can.

        A 1-D network puts every node on one line (``positions_mm`` along ``direction``), so
        it must be a chain whose neighbours follow that line: no node joined to three or more
        others (a branch), no neighbour on the same side twice (a link folding back). Such a
        network needs each node's link and 3-D position; without them it would silently treat
        a perpendicular link as collinear (issue 20).
        """
        if self.is_spatial:
            return None
        between = self.between_nodes_matrix.tocsr()
        for i, name in enumerate(self.node_names):
            neighbours = between.indices[between.indptr[i] : between.indptr[i + 1]]
            if len(neighbours) >= 3:
                return f"node {name!r} joins {len(neighbours)} nodes (a branched network)"
            if len(neighbours) == 2:
                sides = np.sign(self.positions_mm[neighbours] - self.positions_mm[i])
                if sides[0] == sides[1] != 0.0:
                    joined = ", ".join(repr(self.node_names[j]) for j in neighbours)
                    return (
                        f"node {name!r} joins {joined}, both on the same side of it along the bar"
                    )
        return None

    def node_named(self, name: str, what: str = "heat input") -> int:
        """0-based index of the node called ``name``, by name only (issue 19: a heat input
        "2" must not heat whatever node happens to be the second); a name naming no node is a
        :class:`NetworkError` of one line naming ``what``, the key and the network's nodes."""
        key = str(name).strip()
        if key in self._index:
            return self._index[key]
        raise NetworkError(
            f"{what} {key!r} names no node of network {self.name!r} "
            f"(its nodes: {self.listed_node_names()})"
        )

    def listed_node_names(self) -> str:
        """The node names, comma-separated; of a long network the first few, the last, the
        count and the nodes named other than by number (holes: shaft, diode)."""
        names = self.node_names
        if len(names) <= LISTED_NODES:
            return ", ".join(names)
        named = [name for name in names if not name.isdigit()][:LISTED_NODES]
        listed = f"{', '.join(names[:4])}, ..., {names[-1]} ({len(names)} nodes"
        return listed + (f"; named: {', '.join(named)})" if named else ")")

    def heat_by_name(self, heat_w: Mapping[str, float]) -> FloatArray:
        """The heat vector (W per node) of inputs keyed by node name (see :meth:`node_named`)."""
        vector = np.zeros(self.node_count)
        for node, watts in heat_w.items():
            vector[self.node_named(node)] += watts
        return vector

    def own_heat_w(self) -> dict[str, float]:
        """The network's own heat inputs (file ``heat_w`` of its nodes), by node name."""
        return {
            name: float(watts)
            for name, watts in zip(self.node_names, self.heat_w, strict=True)
            if watts != 0.0
        }

    # -- matrices -----------------------------------------------------------------------------

    @property
    def ambient_conductance_w_per_c(self) -> FloatArray:
        """Sum of the conductances from each node to ambient (convection + end face)."""
        return 1.0 / self.r_ambient_c_per_w + 1.0 / self.r_end_c_per_w

    @cached_property
    def between_nodes_matrix(self) -> sp.csr_matrix:
        """Symmetric matrix of ``1/R_ij`` (parallel resistances add up), zero diagonal.
        Computed once; do not modify it."""
        n = self.node_count
        if not self.resistances:
            return sp.csr_matrix((n, n))
        a = np.array([r.a for r in self.resistances])
        b = np.array([r.b for r in self.resistances])
        g = np.array([1.0 / r.r_c_per_w for r in self.resistances])
        rows, cols = np.concatenate([a, b]), np.concatenate([b, a])
        return sp.csr_matrix((np.concatenate([g, g]), (rows, cols)), shape=(n, n))

    @cached_property
    def conductance_matrix(self) -> sp.csr_matrix:
        """``K`` with ``C dT/dt = -K T + q + g_amb T_amb``: symmetric positive definite.
        Computed once; do not modify it."""
        between = self.between_nodes_matrix
        degree = np.asarray(between.sum(axis=1)).reshape(-1)
        matrix = sp.diags(degree + self.ambient_conductance_w_per_c) - between
        return sp.csr_matrix(matrix)

    def resistance_between(self, a: str | int, b: str | int) -> float:
        """The resistance joining two nodes (parallel ones combined); ``inf`` if none."""
        i, j = self.node_index(a), self.node_index(b)
        conductance = float(self.between_nodes_matrix[i, j])
        return math.inf if conductance == 0.0 else 1.0 / conductance

    # -- deformation --------------------------------------------------------------------------

    def control_volume_bounds_mm(self) -> tuple[FloatArray, FloatArray]:
        """(lower, upper) edge of each node's control volume along the link: the midpoints
        between neighbouring node centres, and the bar's ends (DESIGN.md "Deformation")."""
        order = np.argsort(self.positions_mm, kind="stable")
        sorted_x = self.positions_mm[order]
        start, end = self.bar_ends_mm or (float(sorted_x[0]), float(sorted_x[-1]))
        mids = (sorted_x[1:] + sorted_x[:-1]) / 2.0
        lower_sorted = np.concatenate([[min(start, sorted_x[0])], mids])
        upper_sorted = np.concatenate([mids, [max(end, sorted_x[-1])]])
        lower, upper = np.empty_like(lower_sorted), np.empty_like(upper_sorted)
        lower[order], upper[order] = lower_sorted, upper_sorted
        return lower, upper

    def deformation_weights_um_per_c(
        self, reference_nodes: Sequence[str] | None = None
    ) -> FloatArray:
        """``w_i = alpha_i l_i`` in µm/°C, so that the growth of the distance between the two
        reference nodes is ``w . (T - T_ref)``; ``l_i`` is the part of node i's control volume
        between the reference nodes' centres."""
        first, second = reference_nodes or self.reference_nodes
        xa = self.positions_mm[self.node_index(first)]
        xb = self.positions_mm[self.node_index(second)]
        low, high = min(xa, xb), max(xa, xb)
        lower, upper = self.control_volume_bounds_mm()
        inside_mm = np.clip(np.minimum(upper, high) - np.maximum(lower, low), 0.0, None)
        weights: FloatArray = self.alpha_per_c * inside_mm * UM_PER_MM
        return weights


@dataclass(frozen=True, slots=True)
class NetworkFacts:
    """What `thermocomp model info` reports (thesis 5.4; DESIGN.md "Eq. 5.1")."""

    node_count: int
    positivity_bound_s: float  # Eq. 5.1's bound: min C_i / sum_j 1/R_ij
    stability_limit_s: float  # the true explicit limit: 2 / spectral radius of C^-1 K
    slowest_time_constant_s: float
    fastest_time_constant_s: float
    steady_deformation_um_per_w: dict[str, float]  # per watt into each node, at steady state


def positivity_bound_s(network: ThermalNetwork) -> float:
    """Largest explicit ``dt`` keeping every coefficient of Eq. 5.1 non-negative (thesis 5.4)."""
    total_conductance = network.conductance_matrix.diagonal()
    return float(np.min(network.capacitance_j_per_c / total_conductance))


def decay_rates_per_s(
    network: ThermalNetwork, dense_limit: int = DENSE_LIMIT
) -> tuple[float, float]:
    """(smallest, largest) eigenvalue of ``C^-1 K``; real and positive because
    ``C^-1/2 K C^-1/2`` is symmetric positive definite. Dense up to ``dense_limit`` nodes,
    sparse solvers above (daemon/model/spectrum.py: seconds at 10,000 nodes)."""
    scale = 1.0 / np.sqrt(network.capacitance_j_per_c)
    symmetric = sp.diags(scale) @ network.conductance_matrix @ sp.diags(scale)
    if network.node_count <= dense_limit:
        eigenvalues = np.linalg.eigvalsh(symmetric.toarray())
        return float(eigenvalues[0]), float(eigenvalues[-1])
    # sparse: shift-invert for the slowest, inertia bisection for the fastest (spectrum.py)
    return smallest_eigenvalue(symmetric), largest_eigenvalue(symmetric)


def steady_state_c(network: ThermalNetwork, heat_w: ArrayLike, ambient_c: float) -> FloatArray:
    """Steady temperatures: the direct solution of ``K (T - T_amb) = q``."""
    from scipy.sparse.linalg import spsolve

    heat = np.asarray(heat_w, dtype=np.float64)
    rise = np.asarray(spsolve(sp.csc_matrix(network.conductance_matrix), heat), np.float64)
    return ambient_c + rise.reshape(-1)


def network_facts(network: ThermalNetwork) -> NetworkFacts:
    slow, fast = decay_rates_per_s(network)
    # Deformation per watt into node j is w . K^-1 e_j = (K^-1 w)_j since K is symmetric.
    from scipy.sparse.linalg import spsolve

    weights = network.deformation_weights_um_per_c()
    per_watt = np.asarray(
        spsolve(sp.csc_matrix(network.conductance_matrix), weights), np.float64
    ).reshape(-1)
    return NetworkFacts(
        node_count=network.node_count,
        positivity_bound_s=positivity_bound_s(network),
        stability_limit_s=2.0 / fast,
        slowest_time_constant_s=1.0 / slow,
        fastest_time_constant_s=1.0 / fast,
        steady_deformation_um_per_w={
            name: float(value) for name, value in zip(network.node_names, per_watt, strict=True)
        },
    )
