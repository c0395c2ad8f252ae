"""Closed-form results the thesis uses beside the finite-difference model.

* Eq. 3.7 exactly as printed, and the physically consistent semi-infinite-solid deformation
  (DESIGN.md "Eq. 3.7": the printed form falls as time grows, so both are given, labelled);
* the CTE estimate of Eqs. 2.1-2.3 (thesis 2.2.4).
"""

from __future__ import annotations

import math
from collections.abc import Sequence


def thesis_eq_3_7_deformation_m(
    *,
    alpha_per_k: float,
    length_m: float,
    delta_t_k: float,
    conductivity_w_per_mk: float,
    density_kg_per_m3: float,
    specific_heat_j_per_kgk: float,
    tau_s: float,
) -> float:
    """Thesis Eq. 3.7 AS PRINTED: ``dL = alpha L |dT| erf(sqrt(rho c / (k tau)) L)``.

    Kept to reproduce the thesis; it is not dimensionally a semi-infinite-solid result and it
    decreases as ``tau`` grows. Use :func:`semi_infinite_deformation_m` for predictions.
    """
    if tau_s <= 0.0:
        raise ValueError(f"tau must be positive, got {tau_s}")
    argument = math.sqrt(
        density_kg_per_m3 * specific_heat_j_per_kgk / (conductivity_w_per_mk * tau_s)
    )
    return alpha_per_k * length_m * abs(delta_t_k) * math.erf(argument * length_m)


def semi_infinite_deformation_m(
    *,
    alpha_per_k: float,
    length_m: float,
    delta_t_k: float,
    diffusivity_m2_per_s: float,
    tau_s: float,
) -> float:
    """Growth of the first ``length_m`` of a semi-infinite bar whose end is raised by
    ``delta_t_k`` at ``tau = 0`` (thesis 3.3, Eq. 3.3 integrated twice).

    The profile is ``dT erfc(x / (2 sqrt(a tau)))``; integrating ``alpha`` times it over
    ``[0, L]`` gives ``alpha dT 2 sqrt(a tau) [z erfc(z) + (1 - exp(-z^2)) / sqrt(pi)]`` with
    ``z = L / (2 sqrt(a tau))``: zero at ``tau = 0``, rising to ``alpha L dT``.
    """
    if tau_s < 0.0:
        raise ValueError(f"tau must not be negative, got {tau_s}")
    if tau_s == 0.0:
        return 0.0
    spread = 2.0 * math.sqrt(diffusivity_m2_per_s * tau_s)
    z = length_m / spread
    integral = spread * (z * math.erfc(z) + (-math.expm1(-z * z)) / math.sqrt(math.pi))
    return alpha_per_k * delta_t_k * integral


def projected_length_change_m(
    *,
    alpha_per_k: float,
    link_lengths_m: Sequence[float],
    link_angles_deg: Sequence[float],
    delta_t_k: Sequence[float],
    phi_deg: float,
    theta_deg: float,
) -> float:
    """Eq. 2.3: ``dl_x = alpha (sum_k l_k cos(a_k) dT_k) cos(phi) cos(theta)`` — the links'
    growth projected on the effective length (Eq. 2.2) and then on the camera axis."""
    if not len(link_lengths_m) == len(link_angles_deg) == len(delta_t_k):
        raise ValueError("one angle and one temperature change per link length")
    projected = sum(
        length * math.cos(math.radians(angle)) * rise
        for length, angle, rise in zip(link_lengths_m, link_angles_deg, delta_t_k, strict=True)
    )
    return (
        alpha_per_k
        * projected
        * math.cos(math.radians(phi_deg))
        * math.cos(math.radians(theta_deg))
    )


def cte_estimate_per_k(
    *,
    length_change_m: float,
    link_lengths_m: Sequence[float],
    link_angles_deg: Sequence[float],
    delta_t_k: Sequence[float],
    phi_deg: float,
    theta_deg: float,
) -> float:
    """Eqs. 2.1-2.3 solved for ``alpha`` from a measured ``dl_x`` (thesis 2.2.4)."""
    per_unit_alpha = projected_length_change_m(
        alpha_per_k=1.0,
        link_lengths_m=link_lengths_m,
        link_angles_deg=link_angles_deg,
        delta_t_k=delta_t_k,
        phi_deg=phi_deg,
        theta_deg=theta_deg,
    )
    if per_unit_alpha == 0.0:
        raise ValueError("the links' projected temperature-length product is zero")
    return length_change_m / per_unit_alpha
