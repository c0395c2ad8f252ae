"""Materials of the links, shafts and diode (thesis Table 3.1) and the rule of mixtures
(thesis 5.4.1, Eqs. 5.2-5.5).

DESIGN.md: Table 5.2's k, rho and c fit about 5 % steel by volume, not the 2 % the text
states, and its alpha fits neither; so the code follows the equations, and the presets that
need Table 5.2's numbers carry them as printed.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Material:
    """Bulk properties in SI units (Table 3.1's columns)."""

    name: str
    conductivity_w_per_mk: float
    density_kg_per_m3: float
    specific_heat_j_per_kgk: float
    expansion_per_k: float
    youngs_modulus_pa: float
    poisson_ratio: float
    emissivity: float

    @property
    def volumetric_heat_capacity_j_per_m3k(self) -> float:
        return self.density_kg_per_m3 * self.specific_heat_j_per_kgk

    @property
    def diffusivity_m2_per_s(self) -> float:
        """Thermal diffusivity ``alpha_d = k / (rho c)`` (thesis 3.3)."""
        return self.conductivity_w_per_mk / self.volumetric_heat_capacity_j_per_m3k


#: Table 3.1. Young's modulus of 6061-T6 is 70 GPa (DESIGN.md: 4.3.2's "MPa" is a misprint).
MATERIALS: dict[str, Material] = {
    "6061-T6": Material("6061-T6", 167.0, 2713.0, 892.0, 23.6e-6, 7e10, 0.33, 0.95),
    "430 SS": Material("430 SS", 26.1, 7800.0, 460.0, 10.25e-6, 20e10, 0.285, 0.85),
    "ABS": Material("ABS", 0.27, 1180.0, 1424.0, 53e-6, 0.23e10, 0.3, 0.91),
}


def material(name: str) -> Material:
    """The Table 3.1 material called ``name`` (case and spaces/dashes do not matter)."""

    def key(text: str) -> str:
        return "".join(ch for ch in text.lower() if ch.isalnum())

    for known in MATERIALS.values():
        if key(known.name) == key(name):
            return known
    raise ValueError(f"unknown material {name!r}; known: {', '.join(MATERIALS)}")


def rule_of_mixtures(fibre: Material, matrix: Material, fibre_volume_fraction: float) -> Material:
    """The composite of ``fibre`` (volume fraction ``V_f``) in ``matrix`` (``V_m = 1 - V_f``).

    Eqs. 5.2-5.5 (thesis 5.4.1): density and longitudinal conductivity by volume, specific
    heat by mass, expansion weighted by stiffness. Young's modulus and Poisson's ratio use the
    same longitudinal (Voigt) rule, which the thesis does not state; emissivity is the
    matrix's, because the matrix is what the surface shows.
    """
    if not 0.0 <= fibre_volume_fraction <= 1.0:
        raise ValueError(f"fibre volume fraction {fibre_volume_fraction} is not within [0, 1]")
    v_f, v_m = fibre_volume_fraction, 1.0 - fibre_volume_fraction
    density = v_f * fibre.density_kg_per_m3 + v_m * matrix.density_kg_per_m3  # Eq. 5.2
    specific_heat = (
        v_f * fibre.density_kg_per_m3 * fibre.specific_heat_j_per_kgk
        + v_m * matrix.density_kg_per_m3 * matrix.specific_heat_j_per_kgk
    ) / density  # Eq. 5.3
    conductivity = v_f * fibre.conductivity_w_per_mk + v_m * matrix.conductivity_w_per_mk  # 5.4
    stiffness = v_f * fibre.youngs_modulus_pa + v_m * matrix.youngs_modulus_pa
    expansion = (
        v_f * fibre.youngs_modulus_pa * fibre.expansion_per_k
        + v_m * matrix.youngs_modulus_pa * matrix.expansion_per_k
    ) / stiffness  # Eq. 5.5
    return Material(
        name=f"{fibre_volume_fraction:g} {fibre.name} in {matrix.name}",
        conductivity_w_per_mk=conductivity,
        density_kg_per_m3=density,
        specific_heat_j_per_kgk=specific_heat,
        expansion_per_k=expansion,
        youngs_modulus_pa=stiffness,
        poisson_ratio=v_f * fibre.poisson_ratio + v_m * matrix.poisson_ratio,
        emissivity=matrix.emissivity,
    )
