"""A measurement error budget in the shape of thesis Table 4.5 (issue 32). Pure.

Chapter 4 named the measurement's sources of error (Table 4.1), put a number on each,
``δL``, the extra deformation it makes the measurement see, compared it with the deformation
the measurement must see (``ΔL``, 45 µm in the single-link case, 4.2) and ranked them with the
change to the apparatus each called for (Table 4.5); the improved set-up was trusted to
±5 µm (4.11). A :class:`Budget` is that table for a configured set-up: every source with its
``δL`` (µm along the measured deformation), how it was obtained, what it does and what would
reduce it, ranked, and whether the set-up can resolve its compensation target.

How the numbers combine (stated so a reader can redo it): a random source (a scatter) counts
at the thesis's 95 % level, twice its 1-sigma (``COVERAGE``, thesis chapter 2 footnote 1); an
analytic source is the thesis's worst case; a drift is its whole change. The set-up's
resolution is their root sum of squares, the sources being independent. A *conditional*
source (the diode tipping in its expanded hole happens only when something disturbs it,
4.5.3) is a bound, not a certainty: it is ranked and named, and left out of the resolution
with a warning when it alone exceeds the target.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

#: Coverage factor of a 1-sigma scatter: the thesis's 95 % level (chapter 2, footnote 1).
COVERAGE = 2.0
#: The thesis's expected single-link deformation (µm, 4.2) and the resolution the improved
#: measurement was trusted to (µm, 4.11): the defaults of a budget with nothing configured.
THESIS_EXPECTED_UM = 45.0
THESIS_RESOLUTION_UM = 5.0

Evidence = Literal["analytic", "measured", "model", "not quantified", "not applicable"]


@dataclass(frozen=True)
class Source:
    """One row of the budget (one source of Table 4.1)."""

    key: str  # machine name: "bending", "misalignment-z", "camera-drift", ...
    name: str  # "Cantilever bending"
    section: str  # the thesis's section, "4.3"
    evidence: Evidence
    delta_l_um: float | None  # at the 95 % level or the worst case; None: not quantified
    effect: str  # what it does to the measurement
    remedy: str  # the change that would reduce it (Table 4.5's last column)
    basis: str = ""  # how the number was obtained, with its inputs
    conditional: str = ""  # non-empty: it happens only then (a bound, not in the resolution)
    detail: Mapping[str, float | str | None] = field(default_factory=dict)

    @property
    def quantified(self) -> bool:
        return self.delta_l_um is not None and math.isfinite(self.delta_l_um)

    def to_dict(self) -> dict[str, object]:
        return {
            "key": self.key,
            "name": self.name,
            "section": self.section,
            "evidence": self.evidence,
            "delta_l_um": self.delta_l_um,
            "effect": self.effect,
            "remedy": self.remedy,
            "basis": self.basis,
            "conditional": self.conditional or None,
            "detail": dict(self.detail),
        }


@dataclass(frozen=True)
class PoseBudget:
    """An arm's measured pose: the drift expected there and the 3-D measurement's and the
    identified model's uncertainty of it (µm at the 95 % level, tool position)."""

    pose: str
    expected_um: float
    measurement_um: float | None  # 3-D measurement of the drift (camera geometry, markers)
    model_um: float | None = None  # identification's parameter uncertainty at the tool
    cameras_seeing: int | None = None

    def to_dict(self) -> dict[str, object]:
        return {
            "pose": self.pose,
            "expected_um": self.expected_um,
            "measurement_um": self.measurement_um,
            "model_um": self.model_um,
            "cameras_seeing": self.cameras_seeing,
        }


def root_sum_square(values: Sequence[float]) -> float:
    return math.sqrt(sum(v * v for v in values))


@dataclass(frozen=True)
class Budget:
    """The ranked table and its verdict (module docstring)."""

    setup: str  # "two-link bench", "arm crs-a465 (3 cameras)"
    expected_um: float  # ΔL: the deformation the measurement must see
    expected_basis: str
    target_um: float  # the compensation target: the error the run must stay within
    sources: tuple[Source, ...]
    poses: tuple[PoseBudget, ...] = ()
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not (math.isfinite(self.target_um) and self.target_um > 0):
            raise ValueError(f"the target must be a positive number of µm, got {self.target_um}")

    def ranked(self) -> list[Source]:
        """Largest ``δL`` first; the unquantified and inapplicable after, in their order."""
        quantified = sorted(
            (s for s in self.sources if s.quantified),
            key=lambda s: -(s.delta_l_um or 0.0),
        )
        return quantified + [s for s in self.sources if not s.quantified]

    def in_resolution(self) -> list[Source]:
        return [s for s in self.sources if s.quantified and not s.conditional]

    @property
    def resolution_um(self) -> float:
        """The set-up's resolution: root sum of squares of the unconditional sources (µm)."""
        return root_sum_square([s.delta_l_um or 0.0 for s in self.in_resolution()])

    @property
    def dominant(self) -> Source | None:
        ranked = [s for s in self.ranked() if s.quantified and not s.conditional]
        return ranked[0] if ranked else None

    @property
    def resolves(self) -> bool:
        return self.resolution_um <= self.target_um

    def warnings(self) -> list[str]:
        """Conditional sources over the target, and poses whose own budget misses it."""
        lines = [
            f"{s.name} ({s.section}) could add {s.delta_l_um:.3g} µm, over the target, "
            f"{s.conditional}: {s.remedy}"
            for s in self.sources
            if s.quantified and s.conditional and (s.delta_l_um or 0.0) > self.target_um
        ]
        for pose in self.poses:
            parts = [v for v in (pose.measurement_um, pose.model_um) if v is not None]
            if parts and root_sum_square(parts) > self.target_um:
                lines.append(
                    f"pose {pose.pose}: its measurement and model uncertainty "
                    f"({root_sum_square(parts):.3g} µm) exceed the target"
                )
        return lines

    def unmeasured(self) -> list[Source]:
        """The sources that apply but have no number (not recorded, not quantifiable)."""
        return [s for s in self.sources if s.evidence == "not quantified"]

    def verdict(self) -> str:
        resolution, target = self.resolution_um, self.target_um
        dominant = self.dominant
        lead = f"; {dominant.name} dominates ({dominant.remedy})" if dominant is not None else ""
        missing = self.unmeasured()
        if missing:
            lead += (
                f"; without {', '.join(s.name for s in missing)} (no number: the verdict "
                "covers the rest)"
            )
        if self.resolves:
            return (
                f"RESOLVES the target: resolution {resolution:.3g} µm <= target {target:g} µm "
                f"(expected deformation {self.expected_um:.3g} µm){lead}"
            )
        return (
            f"CANNOT RESOLVE the target: resolution {resolution:.3g} µm > target {target:g} µm "
            f"(expected deformation {self.expected_um:.3g} µm){lead}"
        )

    def to_dict(self) -> dict[str, object]:
        return {
            "setup": self.setup,
            "expected_um": self.expected_um,
            "expected_basis": self.expected_basis,
            "target_um": self.target_um,
            "resolution_um": self.resolution_um,
            "resolves": self.resolves,
            "verdict": self.verdict(),
            "coverage": COVERAGE,
            "sources": [s.to_dict() for s in self.ranked()],
            "poses": [p.to_dict() for p in self.poses],
            "warnings": self.warnings(),
            "notes": list(self.notes),
        }

    def to_text(self) -> str:
        """Table 4.5's shape: rank, source, δL, share of ΔL, evidence, remedy; then the
        verdict, the warnings, the poses and how each number was obtained."""
        lines = [
            f"Measurement error budget: {self.setup}",
            f"expected deformation ΔL = {self.expected_um:.3g} µm ({self.expected_basis}); "
            f"target {self.target_um:g} µm",
            "",
            f"{'#':>2}  {'source':<38}{'thesis':<8}{'δL µm':>10}{'% of ΔL':>9}  "
            f"{'evidence':<15}what would reduce it",
        ]
        for rank, source in enumerate(self.ranked(), start=1):
            if source.quantified:
                value = source.delta_l_um or 0.0
                amount = f"{value:>10.3g}"
                share = (
                    f"{100 * value / self.expected_um:>9.3g}" if self.expected_um > 0 else " " * 9
                )
            else:
                amount, share = f"{'-':>10}", f"{'-':>9}"
            mark = "*" if source.conditional else " "
            lines.append(
                f"{rank:>2}{mark} {source.name[:38]:<38}{source.section:<8}{amount}{share}  "
                f"{source.evidence:<15}{source.remedy}"
            )
        lines += ["", self.verdict()]
        if any(s.conditional for s in self.sources):
            lines.append("* a bound that needs a disturbance: ranked, not in the resolution")
        lines += [f"warning: {w}" for w in self.warnings()]
        if self.poses:
            lines += [
                "",
                f"{'pose':<18}{'expected µm':>12}{'3-D meas. µm':>14}{'model µm':>10}"
                f"{'cameras':>9}",
            ]
            for pose in self.poses:

                def cell(value: float | None, width: int) -> str:
                    return f"{value:>{width}.3g}" if value is not None else f"{'-':>{width}}"

                cameras = "-" if pose.cameras_seeing is None else str(pose.cameras_seeing)
                lines.append(
                    f"{pose.pose[:18]:<18}{pose.expected_um:>12.3g}"
                    f"{cell(pose.measurement_um, 14)}{cell(pose.model_um, 10)}{cameras:>9}"
                )
        lines += ["", "How each number was obtained:"]
        lines += [
            f"- {s.name}: {s.basis or s.effect}" for s in self.ranked() if s.basis or s.effect
        ]
        lines += [f"note: {note}" for note in self.notes]
        return "\n".join(lines)
