"""The thermal model (thesis 5.4): networks, steppers, deformation, closed forms. Pure: no
I/O besides reading a network's TOML file on request, no clocks, no devices."""

from daemon.model.analytic import (
    cte_estimate_per_k,
    projected_length_change_m,
    semi_infinite_deformation_m,
    thesis_eq_3_7_deformation_m,
)
from daemon.model.geometry import (
    Hole,
    Segment,
    build_geometry_network,
    thesis_two_link_geometry_network,
)
from daemon.model.materials import MATERIALS, Material, material, rule_of_mixtures
from daemon.model.model import EXACT_NODE_LIMIT, STEPPERS, ModelError, Stepper, ThermalModel
from daemon.model.network import (
    NetworkError,
    NetworkFacts,
    Resistance,
    ThermalNetwork,
    decay_rates_per_s,
    network_facts,
    positivity_bound_s,
    steady_state_c,
)
from daemon.model.presets import available_presets, load_network, network_from_mapping

__all__ = [
    "EXACT_NODE_LIMIT",
    "MATERIALS",
    "STEPPERS",
    "Hole",
    "Material",
    "ModelError",
    "NetworkError",
    "NetworkFacts",
    "Resistance",
    "Segment",
    "Stepper",
    "ThermalModel",
    "ThermalNetwork",
    "available_presets",
    "build_geometry_network",
    "cte_estimate_per_k",
    "decay_rates_per_s",
    "load_network",
    "material",
    "network_facts",
    "network_from_mapping",
    "positivity_bound_s",
    "projected_length_change_m",
    "rule_of_mixtures",
    "semi_infinite_deformation_m",
    "steady_state_c",
    "thesis_eq_3_7_deformation_m",
    "thesis_two_link_geometry_network",
]
