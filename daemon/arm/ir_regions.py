"""Which nodes of the controller's arm model an IR region sees (issue 20): for identification
(daemon/commands/arm_identify.py) and the arm's IR observer (daemon/arm/controller.py). Pure.

A region is a point along a link: ``(link, fraction)`` from the link's proximal joint. The arm
bench's IR reader names its regions ``<link>-mid`` (the middle of the link,
drivers/sim/arm_devices.py); ``<link>@<fraction>`` names any other point. The region sees the
model's node(s) nearest that point (both rows of a link modelled across its section: their
mean), as benchmarks/bench_arm.py's controllers do.

A region may name one face of the link: ``<region>.plus`` (the face carrying the motor
housings) or ``<region>.minus`` (the opposite face), e.g. ``forearm-mid.plus``; it then sees
that face's row of the model (a chain model, which has one row, sees it whole). What bends a
link is the temperature difference across it (kinematics.bending_deflection); a region on each
face measures it, where a region seeing the section's mean cannot (issue 29: with the mean
alone, a bending share the model has wrong stays wrong, whatever the observer does).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from daemon.arm.thermal import FACES, ArmThermalModel

#: ``<link>-mid``: the middle of the link.
MID_SUFFIX = "-mid"
MID_FRACTION = 0.5
#: ``<link>@<fraction>``: a point along the link.
AT = "@"


def region_face(name: str) -> tuple[str, str | None]:
    """A region's name without its face suffix, and the face (``plus``, ``minus`` or None)."""
    base, dot, face = name.rpartition(".")
    if dot and face in FACES and base:
        return base, face
    return name, None


def region_name(link: str, fraction: float, face: str | None = None) -> str:
    """The name of the region at ``fraction`` along ``link`` (on ``face``, None: the section's
    mean), as :func:`region_point` and :func:`region_face` read it."""
    base = f"{link}{MID_SUFFIX}" if fraction == MID_FRACTION else f"{link}{AT}{fraction:g}"
    return base if face is None else f"{base}.{face}"


def region_point(name: str, links: Iterable[str]) -> tuple[str, float] | None:
    """The (link, fraction) a region's name says (a face suffix aside: :func:`region_face`),
    None when it names no link of the arm."""
    known = set(links)
    name, _ = region_face(name)
    if name.endswith(MID_SUFFIX) and name.removesuffix(MID_SUFFIX) in known:
        return name.removesuffix(MID_SUFFIX), MID_FRACTION
    link, at, fraction = name.rpartition(AT)
    if at and link in known:
        try:
            value = float(fraction)
        except ValueError:
            return None
        if 0.0 <= value <= 1.0:
            return link, value
    return None


def region_nodes(model: ArmThermalModel, names: Iterable[str]) -> dict[str, tuple[int, ...]]:
    """Each region (by name, see module docstring) that names a point of one of the model's
    links -> the indices of the nodes nearest it; other names are left out."""
    nodes: dict[str, tuple[int, ...]] = {}
    positions = model.network.positions_mm
    for name in names:
        point = region_point(name, model.link_names)
        if point is None:
            continue
        link, fraction = point
        face = region_face(name)[1]
        indices = np.asarray(model.link_face_node_indices(link, face), dtype=np.intp)
        along = positions[indices]
        target = along[0] + fraction * (along[-1] - along[0])
        distance = np.abs(along - target)
        nodes[name] = tuple(int(i) for i in indices[distance <= distance.min() + 1e-9])
    return nodes


def identification_regions(names: Iterable[str]) -> list[str]:
    """The regions identification fits first: the section means, not a face (the faces join
    only when the means leave the joints' heats open, identify_final.faces_needed). A face by
    a joint sits where the temperature across the link is steep and the controller's model
    has one 50-mm node; its mismatch (~0.2 degC) pulls the fitted factors (issue 29,
    hot-motors task A: 9.1 um, 3.0x the meter's sigma with the faces, 6.0 um, 2.0x without;
    the default bench's heat:2 14 standard errors off its truth). The tool, which
    identification fits too, sees the bend itself; the faces serve model+ir, which has no
    tool."""
    return [name for name in names if region_face(name)[1] is None]


__all__ = [
    "identification_regions",
    "region_face",
    "region_name",
    "region_nodes",
    "region_point",
]
