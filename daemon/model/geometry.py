"""Thermal networks from a link's geometry: segments of bar, and holes (shafts, the diode)
placed as nodes of their own.

Thesis 5.4: one-dimensional nodes along the link, temperature uniform over the cross-section,
``R = dx / (k A)`` between neighbouring nodes, ``R_inf = 1 / (h A_s)`` to ambient from each
node's surface and ``C = rho c dV``. Control volumes are bounded by the midpoints between node
centres and by the bar's ends (DESIGN.md "Deformation"); each end node also loses heat through
its end face, like Table 5.1's ``R-`` of node 1 and ``R+`` of node 17.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from daemon.model.materials import Material, material
from daemon.model.network import (
    MAX_NETWORK_NODES,
    FloatArray,
    NetworkError,
    Resistance,
    ThermalNetwork,
)

MM = 1e-3  # m per mm


@dataclass(frozen=True, slots=True)
class Segment:
    """A straight piece of bar of rectangular cross-section."""

    length_mm: float
    width_mm: float
    thickness_mm: float
    material: Material
    node_spacing_mm: float
    h_w_per_m2k: float

    @property
    def area_m2(self) -> float:
        return self.width_mm * self.thickness_mm * MM * MM

    @property
    def perimeter_m(self) -> float:
        return 2.0 * (self.width_mm + self.thickness_mm) * MM


@dataclass(frozen=True, slots=True)
class Hole:
    """A named node at ``position_mm``: a hole of ``diameter_mm`` through the bar, optionally
    filled by an insert (shaft, laser diode) of ``insert_material`` over ``insert_length_mm``
    (default: the bar's thickness, as thesis 5.4.1 counts the shafts' volume). The hole takes
    its bar material's heat capacity away from the node and the insert adds its own.
    ``diameter_mm = 0`` makes a plain reference point."""

    name: str
    position_mm: float
    diameter_mm: float = 0.0
    insert_material: Material | None = None
    insert_length_mm: float | None = None


def _node_positions(
    segments: Sequence[Segment], holes: Sequence[Hole]
) -> tuple[FloatArray, list[str | None]]:
    """Evenly spaced nodes within each segment (bar ends and segment joints included), with
    each hole replacing the grid node within a quarter spacing of it, or added."""
    grid: list[float] = [0.0]
    spacing_at: list[float] = []
    start = 0.0
    for segment in segments:
        intervals = max(1, math.ceil(segment.length_mm / segment.node_spacing_mm - 1e-9))
        step = segment.length_mm / intervals
        spacing_at.extend([step] * intervals)
        grid.extend(start + step * j for j in range(1, intervals + 1))
        start += segment.length_mm
    positions = list(grid)
    labels: list[str | None] = [None] * len(positions)
    total = start
    for hole in sorted(holes, key=lambda h: h.position_mm):
        if not 0.0 <= hole.position_mm <= total:
            raise NetworkError(
                f"node {hole.name!r}: position {hole.position_mm} mm is off the bar "
                f"(0 to {total} mm)"
            )
        nearest = int(np.argmin([abs(x - hole.position_mm) for x in positions]))
        if abs(positions[nearest] - hole.position_mm) < 1e-9 and labels[nearest] is not None:
            raise NetworkError(
                f"node {hole.name!r}: at {hole.position_mm} mm, where {labels[nearest]!r} is"
            )
        local = spacing_at[min(nearest, len(spacing_at) - 1)]
        movable = labels[nearest] is None and positions[nearest] not in (0.0, total)
        if abs(positions[nearest] - hole.position_mm) < 0.25 * local and movable:
            positions[nearest] = hole.position_mm
            labels[nearest] = hole.name
        elif abs(positions[nearest] - hole.position_mm) < 1e-9 and labels[nearest] is None:
            labels[nearest] = hole.name  # exactly on a bar end
        else:
            insert_at = int(np.searchsorted(positions, hole.position_mm))
            positions.insert(insert_at, hole.position_mm)
            labels.insert(insert_at, hole.name)
    return np.array(positions), labels


def _overlaps(segments: Sequence[Segment], low: float, high: float) -> list[tuple[Segment, float]]:
    """(segment, length in mm) of each segment's part within [low, high]."""
    parts: list[tuple[Segment, float]] = []
    start = 0.0
    for segment in segments:
        end = start + segment.length_mm
        length = min(end, high) - max(start, low)
        if length > 0.0:
            parts.append((segment, length))
        start = end
    return parts


def _segment_at(segments: Sequence[Segment], position_mm: float) -> Segment:
    start = 0.0
    for segment in segments:
        start += segment.length_mm
        if position_mm <= start:
            return segment
    return segments[-1]


def _disc_area_between_mm2(radius_mm: float, low_mm: float, high_mm: float) -> float:
    """Area of a disc of ``radius_mm`` centred at 0 between the lines x = low and x = high."""

    def primitive(x: float) -> float:  # integral of the chord 2 sqrt(r^2 - x^2)
        x = min(max(x, -radius_mm), radius_mm)
        if radius_mm == 0.0:
            return 0.0
        return x * math.sqrt(radius_mm**2 - x**2) + radius_mm**2 * math.asin(x / radius_mm)

    return max(0.0, primitive(high_mm) - primitive(low_mm))


def build_geometry_network(
    name: str,
    segments: Sequence[Segment],
    holes: Sequence[Hole] = (),
    *,
    reference_nodes: tuple[str, str] | None = None,
    heater_nodes: Sequence[str] = (),
    direction: Sequence[float] = (1.0, 0.0, 0.0),
    convection_scale: float = 1.0,
    end_faces: bool = True,
    description: str = "",
) -> ThermalNetwork:
    """The network of a bar made of ``segments`` laid end to end from 0 mm.

    Nodes are named by their 1-based number, holes by their own name. ``convection_scale``
    multiplies every ``h`` (the bench uses it to make its truth differ from the model);
    ``end_faces=False`` makes the bar's end faces adiabatic.
    Default reference nodes: the first and last hole (or bar ends without holes).
    """
    if not segments:
        raise NetworkError(f"network {name!r}: a geometry needs at least one segment")
    for index, segment in enumerate(segments, start=1):
        for label, value in (
            ("length_mm", segment.length_mm),
            ("width_mm", segment.width_mm),
            ("thickness_mm", segment.thickness_mm),
            ("node_spacing_mm", segment.node_spacing_mm),
        ):
            if not (math.isfinite(value) and value > 0.0):
                raise NetworkError(f"segment {index}: {label} must be positive, got {value}")
        if not (math.isfinite(segment.h_w_per_m2k) and segment.h_w_per_m2k >= 0.0):
            raise NetworkError(f"segment {index}: h must be >= 0, got {segment.h_w_per_m2k}")
    if not (math.isfinite(convection_scale) and convection_scale > 0.0):
        raise NetworkError(f"convection scale must be positive, got {convection_scale}")
    planned = len(holes) + 1
    for index, segment in enumerate(segments, start=1):
        # counted before any node is made: a tiny spacing would allocate for minutes (issue 26)
        planned += math.ceil(min(segment.length_mm / segment.node_spacing_mm, 1e18))
        if planned > MAX_NETWORK_NODES:
            raise NetworkError(
                f"segment {index}: node_spacing_mm {segment.node_spacing_mm:g} over "
                f"{segment.length_mm:g} mm makes over {MAX_NETWORK_NODES} nodes in the network: "
                "use a coarser spacing"
            )

    positions, labels = _node_positions(segments, holes)
    total = float(sum(s.length_mm for s in segments))
    count = len(positions)
    mids = (positions[1:] + positions[:-1]) / 2.0
    lower = np.concatenate([[0.0], mids])
    upper = np.concatenate([mids, [total]])

    capacitance = np.zeros(count)
    alpha = np.zeros(count)
    ambient_conductance = np.zeros(count)
    for i in range(count):
        parts = _overlaps(segments, lower[i], upper[i])
        length = sum(part for _, part in parts)
        expansions = {segment.material.expansion_per_k for segment, _ in parts}
        # One material: its alpha exactly (uniform dT must give exactly alpha L dT).
        alpha[i] = (
            expansions.pop()
            if len(expansions) == 1
            else sum(segment.material.expansion_per_k * part for segment, part in parts) / length
        )
        for segment, part in parts:
            volume = segment.area_m2 * part * MM
            capacitance[i] += segment.material.volumetric_heat_capacity_j_per_m3k * volume
            ambient_conductance[i] += (
                convection_scale * segment.h_w_per_m2k * segment.perimeter_m * part * MM
            )
    end_conductance = np.zeros(count)
    for node, segment in ((0, segments[0]), (count - 1, segments[-1])) if end_faces else ():
        end_conductance[node] += convection_scale * segment.h_w_per_m2k * segment.area_m2

    names = [label if label is not None else str(i + 1) for i, label in enumerate(labels)]
    for hole in holes:
        # The hole's disc replaces bar by insert wherever it lies, which may be several control
        # volumes when the nodes are finer than the hole (a 19 mm diode hole, 2 mm nodes).
        segment = _segment_at(segments, hole.position_mm)
        insert_heat_per_m2 = 0.0
        if hole.insert_material is not None:
            insert_length_mm = hole.insert_length_mm or segment.thickness_mm
            insert_heat_per_m2 = (
                hole.insert_material.volumetric_heat_capacity_j_per_m3k * insert_length_mm * MM
            )
        bar_heat_per_m2 = (
            segment.material.volumetric_heat_capacity_j_per_m3k * segment.thickness_mm * MM
        )
        radius_mm = hole.diameter_mm / 2.0
        for i in range(count):
            area_m2 = _disc_area_between_mm2(
                radius_mm, lower[i] - hole.position_mm, upper[i] - hole.position_mm
            ) * (MM * MM)
            capacitance[i] += (insert_heat_per_m2 - bar_heat_per_m2) * area_m2

    resistances = []
    for i in range(count - 1):
        r = sum(
            part * MM / (segment.material.conductivity_w_per_mk * segment.area_m2)
            for segment, part in _overlaps(segments, positions[i], positions[i + 1])
        )
        resistances.append(Resistance(i, i + 1, r))

    with np.errstate(divide="ignore"):
        r_ambient = 1.0 / ambient_conductance
        r_end = 1.0 / end_conductance
    if reference_nodes is None:
        named = [label for label in labels if label is not None]
        reference_nodes = (named[0], named[-1]) if named else (names[0], names[-1])
    return ThermalNetwork(
        name=name,
        node_names=tuple(names),
        positions_mm=positions,
        capacitance_j_per_c=capacitance,
        alpha_per_c=alpha,
        r_ambient_c_per_w=r_ambient,
        r_end_c_per_w=r_end,
        resistances=tuple(resistances),
        reference_nodes=reference_nodes,
        heater_nodes=tuple(heater_nodes),
        direction=np.asarray(direction, dtype=np.float64),
        bar_ends_mm=(0.0, total),
        description=description,
    )


#: Thesis 5.2 / 5.4: the two-link system as one bar of the links' cross-section
#: (25.4 mm x 6.35 mm, the area Table 5.1's resistances imply), 635 mm long, with the shafts
#: at 25.4 mm and 330.2 mm and the laser diode at 622.3 mm (DESIGN.md "Table 5.1").
TWO_LINK_LENGTH_MM = 635.0
TWO_LINK_WIDTH_MM = 25.4
TWO_LINK_THICKNESS_MM = 6.35
TWO_LINK_SHAFTS_MM = (25.4, 330.2)
TWO_LINK_DIODE_MM = 622.3
SHAFT_DIAMETER_MM = 8.0  # thesis 3.2.1, 5.2.1
DIODE_HOLE_DIAMETER_MM = 19.0  # thesis 3.2.1
#: Thesis 5.4 uses h = 2.5 W/m^2K for the finite-difference model (Table 5.1's R_inf).
TWO_LINK_H_W_PER_M2K = 2.5


def thesis_two_link_geometry_network(
    node_spacing_mm: float = 2.0, convection_scale: float = 1.0
) -> ThermalNetwork:
    """The two-link system from its geometry and Table 3.1's materials: 6061-T6 links,
    430 SS shafts and an ABS diode filling their holes (thesis 3.4.1, 5.3.3). A finer, more
    physical cousin of the Table 5.1 preset, with the same reference points: nodes
    "left-shaft" and "middle-shaft" (the heaters) and "diode"."""
    segment = Segment(
        length_mm=TWO_LINK_LENGTH_MM,
        width_mm=TWO_LINK_WIDTH_MM,
        thickness_mm=TWO_LINK_THICKNESS_MM,
        material=material("6061-T6"),
        node_spacing_mm=node_spacing_mm,
        h_w_per_m2k=TWO_LINK_H_W_PER_M2K,
    )
    steel, abs_plastic = material("430 SS"), material("ABS")
    holes = (
        Hole("left-shaft", TWO_LINK_SHAFTS_MM[0], SHAFT_DIAMETER_MM, steel),
        Hole("middle-shaft", TWO_LINK_SHAFTS_MM[1], SHAFT_DIAMETER_MM, steel),
        Hole("diode", TWO_LINK_DIODE_MM, DIODE_HOLE_DIAMETER_MM, abs_plastic),
    )
    return build_geometry_network(
        f"thesis-two-link-geometry({node_spacing_mm:g} mm)",
        [segment],
        holes,
        reference_nodes=("left-shaft", "diode"),
        heater_nodes=("left-shaft", "middle-shaft"),
        convection_scale=convection_scale,
        description="Two-link system from its geometry (thesis 5.2, Table 3.1 materials).",
    )
