"""Error statistics of thesis 6.6: hand-computed values, scipy, and Tables C.2/C.4."""

import math

import numpy as np
import pytest
from scipy import integrate
from scipy import stats as scipy_stats

from daemon.analysis import chi_squared_against_normal, error_statistics, interval_count

# Thesis Table C.2: intervals and counts of the errors of the absolute location command.
TABLE_C2_EDGES = (-2.55, -2.18, -1.81, -1.44, -1.07, -0.7, -0.33, 0.04, 0.41, 0.78, 1.15,
                  1.52, 1.89, 2.26, 2.63, 3.0)  # fmt: skip
TABLE_C2_COUNTS = (1, 1, 5, 8, 15, 21, 22, 24, 19, 11, 8, 5, 2, 0, 1)
# Thesis Table C.4, expected counts n'_j as printed (interval 7 is misprinted, see below).
TABLE_C4_EXPECTED = (0.86, 2.21, 4.83, 9.01, 14.33, 19.43, 18.37, 22.15, 18.62, 13.35, 8.16,
                     4.25, 1.89, 0.72, 0.23)  # fmt: skip
# Thesis Table 6.1, absolute location command.
TABLE_61_MEAN, TABLE_61_STD = 0.007, 0.921


def test_interval_count_follows_the_thesis_formula() -> None:
    # K = 1.87 (N-1)^0.40 + 1: N = 143 gives 14.58, which the thesis rounds to 15.
    assert interval_count(143) == 15
    # 40^0.4 = 4.3734 -> 9.178 -> 9; 1^0.4 = 1 -> 2.87 -> 3; 0 -> 1.
    assert interval_count(41) == 9
    assert interval_count(2) == 3
    assert interval_count(1) == 1
    with pytest.raises(ValueError):
        interval_count(0)


def test_hand_computed_small_sample() -> None:
    """1..5: mean 3, S_x = sqrt(2.5), K = 4 intervals of width 1 with counts 1, 1, 1, 2.

    z of the edges = (e - 3)/sqrt(2.5) = -1.26491, -0.63246, 0, 0.63246, 1.26491, so the
    interval probabilities are 0.160593, 0.236455, 0.236455, 0.160593 (Phi by erf), the
    expected counts 5 times those, chi-squared 1.889056, and with nu = 2 the upper tail of
    chi-squared is exactly exp(-chi2/2) = 0.388863.
    """
    stats = error_statistics([3.0, 1.0, 5.0, 2.0, 4.0])
    assert stats.n == 5
    assert stats.mean == pytest.approx(3.0)
    assert stats.std == pytest.approx(math.sqrt(2.5))
    assert stats.std_of_mean == pytest.approx(math.sqrt(2.5) / math.sqrt(5))
    assert stats.intervals == 4
    test = stats.chi_squared
    assert test is not None
    assert test.edges == pytest.approx((1.0, 2.0, 3.0, 4.0, 5.0))
    assert test.observed == (1, 1, 1, 2)  # the last interval is closed: 5 counts
    assert test.expected == pytest.approx((0.802965, 1.182277, 1.182277, 0.802965), abs=1e-6)
    assert test.chi_squared == pytest.approx(1.889056, abs=1e-6)
    assert test.degrees_of_freedom == 2
    assert test.p_value == pytest.approx(math.exp(-1.889056 / 2), abs=1e-6)
    assert test.thesis_lower_tail_p == pytest.approx(1 - math.exp(-1.889056 / 2), abs=1e-6)


def test_table_c2_reproduces_table_c4_and_the_corrected_chi_squared() -> None:
    test = chi_squared_against_normal(TABLE_C2_EDGES, TABLE_C2_COUNTS, TABLE_61_MEAN, TABLE_61_STD)
    expected = np.array(test.expected)
    printed = np.array(TABLE_C4_EXPECTED)
    misprint = 6  # interval 7: the thesis printed 18.37; the normal gives 22.46
    others = np.arange(15) != misprint
    # Two decimals as printed (half a unit in the last place, plus the thesis's own rounding
    # of the rounded mean and deviation).
    assert np.all(np.abs(expected[others] - printed[others]) <= 0.01 + 1e-9)
    assert round(expected[misprint], 2) == 22.46
    assert sum(test.observed) == 143
    assert round(test.chi_squared, 2) == 4.95
    assert test.degrees_of_freedom == 13
    assert round(test.p_value, 3) == 0.976
    # The thesis's reading of its printed 5.66 was the lower tail, "P = 0.0425" (6.6).
    assert scipy_stats.chi2.cdf(5.66, 13) == pytest.approx(0.0425, abs=5e-4)
    assert test.thesis_lower_tail_p == pytest.approx(1 - test.p_value)


@pytest.mark.parametrize("seed", range(5))
def test_random_samples_agree_with_scipy(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(50, 400))
    sample = rng.normal(rng.normal(0, 2), rng.uniform(0.2, 3), n)
    stats = error_statistics(sample)
    assert stats.n == n
    assert stats.mean == pytest.approx(scipy_stats.tmean(sample))
    assert stats.std == pytest.approx(scipy_stats.tstd(sample))
    assert stats.std_of_mean == pytest.approx(scipy_stats.sem(sample))
    test = stats.chi_squared
    assert test is not None
    counts, edges = np.histogram(sample, bins=interval_count(n))
    assert test.observed == tuple(counts)
    # Expected counts by integrating the normal density over each interval.
    for j, expected in enumerate(test.expected):
        probability, _ = integrate.quad(
            scipy_stats.norm(stats.mean, stats.std).pdf, edges[j], edges[j + 1]
        )
        assert expected == pytest.approx(n * probability, rel=1e-7)
    chi2 = sum((o - e) ** 2 / e for o, e in zip(test.observed, test.expected, strict=True))
    assert test.chi_squared == pytest.approx(chi2)
    assert test.p_value == pytest.approx(scipy_stats.chi2.sf(chi2, len(counts) - 2))


def test_upper_tail_p_is_uniform_for_normal_data_and_small_for_skewed_data() -> None:
    """The upper tail is the goodness-of-fit p-value: it rejects a non-normal sample and
    rarely rejects normal ones (the lower tail would do the opposite)."""
    rng = np.random.default_rng(7)
    normal_p = []
    for _ in range(40):
        test = error_statistics(rng.normal(0, 1, 500)).chi_squared
        assert test is not None
        normal_p.append(test.p_value)
    assert np.mean(np.array(normal_p) < 0.05) < 0.2
    skewed = error_statistics(rng.exponential(1.0, 500)).chi_squared
    assert skewed is not None and skewed.p_value < 1e-6


def test_missing_values_are_dropped_and_degenerate_samples_are_explained() -> None:
    stats = error_statistics([1.0, math.nan, 2.0, 3.0])
    assert stats.n == 3
    constant = error_statistics([2.0] * 50)
    assert constant.std == 0 and constant.chi_squared is None
    assert "equal" in constant.note
    with pytest.raises(ValueError, match="at least two"):
        error_statistics([1.0, math.nan])
    with pytest.raises(ValueError, match="K \\+ 1 edges"):
        chi_squared_against_normal([0, 1], [1, 2], 0.0, 1.0)
