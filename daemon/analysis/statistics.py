"""Error statistics of a compensation run, as thesis section 6.6 and appendix C computed them.

The sample is the error at each time step. Thesis 6.6 reports N, the mean, the standard
deviation S_x, the standard deviation of the mean S_x / sqrt(N) (its Eq. 6.1), and checks
normality with a chi-squared test over a histogram of K = 1.87 (N - 1)^0.40 + 1 equal
intervals, comparing the counts with those of a normal distribution with the sample's mean
and deviation (Eq. 6.2, nu = K - 2).

The thesis read the LOWER tail of the chi-squared distribution as its P (0.0425 for
chi-squared 5.66, nu 13) and called P < 0.05 a good fit. The goodness-of-fit p-value is the
UPPER tail (DESIGN.md "Statistics"): a small upper-tail p rejects normality. Both are
reported, the thesis's reading labelled as such.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats as scipy_stats

logger = logging.getLogger(__name__)

#: Parameters estimated from the data itself (mean and S_x): nu = K - 2 (thesis 6.6).
ESTIMATED_PARAMETERS = 2


def interval_count(n: int) -> int:
    """Number of histogram intervals K = 1.87 (N - 1)^0.40 + 1 (thesis 6.6, from its ref. [41]).

    The thesis rounds to the nearest integer (N = 143: 14.58 -> 15). The formula is meant for
    N > 40; for smaller samples it still gives a usable K, never below 1.
    """
    if n < 1:
        raise ValueError(f"need at least one sample, got N = {n}")
    return max(1, math.floor(1.87 * math.pow(n - 1, 0.40) + 1 + 0.5))


@dataclass(frozen=True)
class ChiSquaredTest:
    """Chi-squared goodness of fit of a histogram against a normal distribution (Eq. 6.2)."""

    edges: tuple[float, ...]  # K + 1 interval edges; interval j is [edges[j], edges[j+1])
    observed: tuple[int, ...]  # n_j
    expected: tuple[float, ...]  # n'_j = N P(edges[j] <= x < edges[j+1]) under the normal
    contributions: tuple[float, ...]  # (n_j - n'_j)^2 / n'_j
    chi_squared: float
    degrees_of_freedom: int  # nu = K - 2
    p_value: float  # upper tail P(chi2_nu >= chi_squared): the goodness-of-fit p-value
    thesis_lower_tail_p: float  # P(chi2_nu <= chi_squared): what thesis 6.6 reported as P


def chi_squared_against_normal(
    edges: ArrayLike, observed: ArrayLike, mean: float, std: float
) -> ChiSquaredTest:
    """Compare histogram counts with a normal distribution of the given mean and deviation.

    The expected count of interval j is N times the normal probability of exactly that
    interval (not open-ended tails): this is what reproduces Table C.4 of the thesis.
    """
    edge_array = np.asarray(edges, dtype=float)
    counts = np.asarray(observed)
    if edge_array.ndim != 1 or counts.ndim != 1 or edge_array.size != counts.size + 1:
        raise ValueError("need K + 1 edges for K counts")
    if np.any(np.diff(edge_array) <= 0):
        raise ValueError("interval edges must increase")
    if not std > 0:
        raise ValueError(f"standard deviation must be positive, got {std}")
    k = counts.size
    nu = k - ESTIMATED_PARAMETERS
    if nu < 1:
        raise ValueError(f"{k} intervals leave no degree of freedom (nu = K - 2 = {nu})")
    n = int(counts.sum())
    probabilities = np.diff(scipy_stats.norm.cdf(edge_array, loc=mean, scale=std))
    expected = n * probabilities
    if np.any(expected <= 0):
        raise ValueError("an interval lies so far in the tail that its expected count is 0")
    contributions = (counts - expected) ** 2 / expected
    chi2 = float(contributions.sum())
    return ChiSquaredTest(
        edges=tuple(float(e) for e in edge_array),
        observed=tuple(int(c) for c in counts),
        expected=tuple(float(e) for e in expected),
        contributions=tuple(float(c) for c in contributions),
        chi_squared=chi2,
        degrees_of_freedom=nu,
        p_value=float(scipy_stats.chi2.sf(chi2, nu)),
        thesis_lower_tail_p=float(scipy_stats.chi2.cdf(chi2, nu)),
    )


@dataclass(frozen=True)
class ErrorStatistics:
    """Table 6.1 of the thesis for one sample, with its histogram and chi-squared test."""

    n: int
    mean: float
    std: float  # S_x, sample standard deviation (N - 1)
    std_of_mean: float  # S_x / sqrt(N), Eq. 6.1
    minimum: float
    maximum: float
    max_abs: float
    intervals: int  # K
    chi_squared: ChiSquaredTest | None  # None when the sample cannot support the test
    note: str  # why the test is missing, or ""

    def to_dict(self) -> dict[str, object]:
        """Plain JSON-ready dictionary, with the p-values labelled."""
        result: dict[str, object] = {
            key: value for key, value in asdict(self).items() if key != "chi_squared"
        }
        test = self.chi_squared
        if test is not None:
            result["chi_squared"] = {
                "edges": list(test.edges),
                "observed": list(test.observed),
                "expected": list(test.expected),
                "contributions": list(test.contributions),
                "chi_squared": test.chi_squared,
                "degrees_of_freedom": test.degrees_of_freedom,
                "p_value_upper_tail": test.p_value,
                "thesis_lower_tail_p": test.thesis_lower_tail_p,
            }
        else:
            result["chi_squared"] = None
        return result


def error_statistics(samples: Sequence[float] | NDArray[np.float64]) -> ErrorStatistics:
    """N, mean, S_x, S_x/sqrt(N), and the chi-squared normality test of thesis 6.6.

    NaN samples (steps with no measurement) are dropped. The histogram spans the sample's
    minimum to maximum in K equal intervals, the last one closed, like Tables C.1 and C.2.
    """
    values = np.asarray(samples, dtype=float)
    values = values[np.isfinite(values)]
    n = int(values.size)
    if n < 2:
        raise ValueError(f"need at least two samples for a standard deviation, got {n}")
    mean = float(values.mean())
    std = float(values.std(ddof=1))
    k = interval_count(n)
    test: ChiSquaredTest | None = None
    note = ""
    if std == 0:
        note = "all samples are equal: no distribution to test"
    elif k - ESTIMATED_PARAMETERS < 1:
        note = f"N = {n} gives K = {k} intervals: too few for a chi-squared test"
    else:
        observed, edges = np.histogram(values, bins=k, range=(values.min(), values.max()))
        try:
            test = chi_squared_against_normal(edges, observed, mean, std)
        except ValueError as err:
            note = str(err)
    if note:
        logger.debug("no chi-squared test: %s", note)
    return ErrorStatistics(
        n=n,
        mean=mean,
        std=std,
        std_of_mean=std / math.sqrt(n),
        minimum=float(values.min()),
        maximum=float(values.max()),
        max_abs=float(np.abs(values).max()),
        intervals=k,
        chi_squared=test,
        note=note,
    )
