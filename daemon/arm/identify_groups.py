"""Parameters a cycle tells only in combination with others (issue 29).

The pairwise check (daemon.model.identify_uncertainty: |correlation| > 0.995 between two
parameters) misses a trade-off among three or more: on a UR5e task the base's and the
shoulder's motors heat the same link, the elbow's the next, and the joints' capacity and the
convection shape the same transient; no two of them correlate beyond 0.93, yet each is told
only through the others. The fitted values then follow whatever the model gets wrong (the
controller's 50-mm network against the truth's, the room), not the data's noise: on the
default truth task A gave heat 1 at 1.34 (truth 1.10, "relative standard error 0.04"), heat 2
at 0.61 (0.84), capacity 0.86 (1.10), and task B the same bias, so a model calibrated on one
task removed 82-92 % of the other's drift where the calibration program's model removed 97 %.

The measure: each parameter's multiple correlation with all the others together, ``R_k``,
from the normalised information ``N`` = J^T J scaled to a unit diagonal: the variance
inflation ``[N^-1]_kk = 1 / (1 - R_k^2)`` (e.g. Seber & Wild, Nonlinear Regression, 1989,
sec. 3.4 on ill-conditioning). Past MULTIPLE_CORRELATION_LIMIT (0.9966, an inflation of 150)
a parameter's information is over 99.3 % shared with the others: an error of the model's own
along the trade-off moves it twelve times further than the data's noise says. Measured on the
UR5e default truth (section means): task A's heats 1 and 2 at R 0.9985 and 0.9992 (inflation
336 and 634), heat 3 and the convection 0.9970-0.9976; the calibration program's largest 0.988.

What the fit then does (identify_final.untangle): the direction the data see least (the
eigenvector of ``N``'s smallest eigenvalue) names the trade-off; the joint heats loading it
(|component| >= LOADING, two or more) are pooled into one factor (the cycle fixes their sum,
not their split) and refitted unless the data reject the pool (identify_final.POOL_COST_RISE);
what is still flagged after that is kept and reported fitted in combination
(identify_final._combined).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from daemon.arm.types import FloatArray

#: A parameter whose multiple correlation with the others exceeds this is not identified: a
#: variance inflation of 150 (module docstring). Measured on the UR5e's truths (section means):
#: the base's and the shoulder's heats on a task 156-634 (their values biased 20-30 %); on the
#: calibration program 36 at most on the default truth, but 161 for the shoulder's heat on the
#: corner-low truth (pooled with the elbow's there although its value, 0.59 on 0.6, was
#: right): an inflation does not tell a biased value from a good one, only how much the
#: model's own errors are amplified along the trade-off.
MULTIPLE_CORRELATION_LIMIT = 0.9966
#: A parameter takes part in the least-seen direction when its component of that unit
#: eigenvector is at least this (a fifth of that direction's variance: 0.45^2).
LOADING = 0.45
#: How a reason of this check begins.
GROUP_REASON = "multiple correlation"
#: How many partners a reason names (the largest pairwise |correlations|).
PARTNERS = 3


@dataclass(frozen=True)
class Groups:
    """Each parameter's multiple correlation with the others, and the least-seen direction
    (unit vector over the parameters, in the normalised information's coordinates)."""

    multiple_correlation: FloatArray
    weakest: FloatArray


def normalised_information(jacobian: FloatArray) -> FloatArray:
    """J^T J scaled to a unit diagonal (a column the data never see is kept at zero)."""
    information = jacobian.T @ jacobian
    scale = np.sqrt(np.clip(np.diag(information), 1e-300, None))
    normalised: FloatArray = information / np.outer(scale, scale)
    return normalised


def groups(jacobian: FloatArray) -> Groups:
    """The multiple correlations and the least-seen direction of the fit's ``jacobian``.
    A near-singular information (the other check's business) gives R = 1."""
    normalised = normalised_information(jacobian)
    values, vectors = np.linalg.eigh(normalised)
    floor = max(float(values[-1]), 1e-300) * 1e-12
    inverse_diagonal = (vectors**2 / np.clip(values, floor, None)).sum(axis=1)
    inflation = np.clip(inverse_diagonal, 1.0, None)
    correlation = np.sqrt(1.0 - 1.0 / inflation)
    return Groups(correlation, vectors[:, 0])


def entangled_reasons(
    names: Sequence[str], jacobian: FloatArray, correlation: FloatArray
) -> dict[str, str]:
    """The parameters (name -> reason) whose multiple correlation with the others exceeds
    MULTIPLE_CORRELATION_LIMIT, each with its closest partners (the fit's ``correlation``)."""
    found = groups(jacobian)
    reasons = {}
    for k, name in enumerate(names):
        r = float(found.multiple_correlation[k])
        if r <= MULTIPLE_CORRELATION_LIMIT:
            continue
        order = [j for j in np.argsort(-np.abs(correlation[k])) if j != k][:PARTNERS]
        partners = ", ".join(f"{names[j]} ({correlation[k, j]:+.2f})" for j in order)
        reasons[name] = (
            f"{GROUP_REASON} {r:.4f} > {MULTIPLE_CORRELATION_LIMIT} with the other "
            f"parameters together (variance inflation {1.0 / max(1.0 - r * r, 1e-300):.0f}): "
            f"the cycle tells it only in combination, most with {partners}"
        )
    return reasons


__all__ = [
    "GROUP_REASON",
    "LOADING",
    "MULTIPLE_CORRELATION_LIMIT",
    "PARTNERS",
    "Groups",
    "entangled_reasons",
    "groups",
    "normalised_information",
]
