"""Compensation maths (thesis 6.3, 6.4; DESIGN.md Scaling, Absolute location command)."""

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from daemon.model.compensation import (
    CompensationLimits,
    UnsafeTargetError,
    check_offset,
    check_scale,
    compensation_offset_mm,
    incremental_rounding,
    max_admissible_scale,
    smallest_working_scale,
)

LIMITS = CompensationLimits(max_step_change_mm=0.5, max_total_offset_mm=5.0)


def test_offset_is_the_negative_scaled_deformation_in_mm() -> None:
    # thesis 6.4.1: compensation = -y(t); 6.3: scaled by the deformation scale
    offset = compensation_offset_mm([150.0, -20.0, 0.0], deformation_scale=28.0)
    np.testing.assert_allclose(offset, [-4.2, 0.56, 0.0])


def test_zero_deformation_needs_no_offset() -> None:
    assert np.array_equal(compensation_offset_mm([0.0, 0.0, 0.0], 5.0), np.zeros(3))


def test_safe_offset_passes_unchanged() -> None:
    offset = check_offset([0.3, 0.0, -0.1], [0.0, 0.0, 0.0], LIMITS)
    np.testing.assert_array_equal(offset, [0.3, 0.0, -0.1])


@pytest.mark.parametrize(
    ("offset", "previous", "reason"),
    [
        ([math.nan, 0.0, 0.0], [0.0, 0.0, 0.0], "not finite"),
        ([math.inf, 0.0, 0.0], [0.0, 0.0, 0.0], "not finite"),
        ([0.0, 0.0, 0.0], [math.nan, 0.0, 0.0], "previous offset is not finite"),
        ([0.6, 0.0, 0.0], [0.0, 0.0, 0.0], "max_step_change_mm"),
        ([0.3, 0.3, 0.3], [0.0, 0.0, 0.0], "max_step_change_mm"),  # |change| = 0.52 mm
        ([5.1, 0.0, 0.0], [4.9, 0.0, 0.0], "max_total_offset_mm"),
        ([0.1, 0.2], [0.0, 0.0, 0.0], "3 components"),
    ],
)
def test_unsafe_offsets_are_refused_with_the_reason(
    offset: list[float], previous: list[float], reason: str
) -> None:
    with pytest.raises(UnsafeTargetError, match=reason):
        check_offset(offset, previous, LIMITS)


@given(
    st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), min_size=3, max_size=3),
    st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3),
)
def test_whatever_passes_the_check_is_within_every_limit(
    offset: list[float], previous: list[float]
) -> None:
    try:
        accepted = check_offset(offset, previous, LIMITS)
    except UnsafeTargetError:
        return
    assert np.all(np.isfinite(accepted))
    assert np.linalg.norm(accepted - np.asarray(previous)) <= LIMITS.max_step_change_mm
    assert np.linalg.norm(accepted) <= LIMITS.max_total_offset_mm


def test_admissible_scale_is_chip_width_less_spot_over_largest_deformation() -> None:
    # DESIGN.md: the thesis's 8,600 um chip allowed 28; with a 200 um spot and 300 um of
    # deformation along x: (8600 - 200) / 300 = 28.
    scale = max_admissible_scale(300.0, (1.0, 0.0, 0.0), (8600.0, 6000.0), 200.0)
    assert scale == pytest.approx(28.0)


def test_admissible_scale_takes_the_tighter_axis() -> None:
    # along the diagonal each axis sees deformation / sqrt(2); the 6000 um height is tighter
    largest = 300.0
    scale = max_admissible_scale(largest, (1.0, 1.0, 0.0), (8600.0, 6000.0), 200.0)
    assert scale == pytest.approx((6000.0 - 200.0) / (largest / math.sqrt(2)))


def test_deformation_along_the_optical_axis_never_leaves_the_chip() -> None:
    assert max_admissible_scale(300.0, (0.0, 0.0, 1.0), (8600.0, 6000.0), 200.0) == math.inf


def test_check_scale_names_the_largest_admissible_factor() -> None:
    check_scale(28.0, 300.0, (1.0, 0.0, 0.0), (8600.0, 6000.0), 200.0)
    with pytest.raises(ValueError, match=r"largest admissible scale is 28\.00"):
        check_scale(28.5, 300.0, (1.0, 0.0, 0.0), (8600.0, 6000.0), 200.0)


# --------------------------------------------------------------------------- incremental mode


def _linear(per_step_um: float, steps: int = 10) -> np.ndarray:
    """A deformation growing by ``per_step_um`` each step along x (0 at the goal)."""
    return np.array([[per_step_um * k, 0.0, 0.0] for k in range(1, steps + 1)])


def test_moves_under_half_the_resolution_are_all_lost() -> None:
    """0.4 um a step at scale 1: the console's 0.001 mm turns every move into none, so the
    whole 4 um deformation stays uncompensated (issue 19: the robot never moved)."""
    rounding = incremental_rounding(_linear(0.4), 1.0)
    assert rounding.lost_steps == 10 and rounding.steps == 10
    assert rounding.largest_move_um == pytest.approx(0.4)
    assert rounding.largest_error_um == pytest.approx(4.0)
    assert rounding.largest_deformation_um == pytest.approx(4.0)
    assert rounding.loss_fraction == pytest.approx(1.0) and not rounding.admissible


@pytest.mark.parametrize(
    ("scale", "error_um", "fraction"),
    [
        (2.0, 2.0, 0.25),  # 0.8 sent as 1: +0.2 a step, 10 steps, of 8 um
        (3.0, 2.0, 2.0 / 12.0),  # 1.2 sent as 1: -0.2 a step, of 12 um
        (4.0, 4.0, 0.25),  # 1.6 sent as 2: +0.4 a step, of 16 um
        (5.0, 0.0, 0.0),  # 2.0: exact
    ],
)
def test_rounding_errors_of_incremental_moves_add_up(
    scale: float, error_um: float, fraction: float
) -> None:
    rounding = incremental_rounding(_linear(0.4), scale)
    assert rounding.lost_steps == 0
    assert rounding.largest_error_um == pytest.approx(error_um, abs=1e-9)
    assert rounding.loss_fraction == pytest.approx(fraction, abs=1e-9)
    assert rounding.admissible == (fraction <= 0.1)


def test_the_smallest_working_scale_within_the_chip() -> None:
    assert smallest_working_scale(_linear(0.4), 28.0) == 5
    assert smallest_working_scale(_linear(0.4), 4.9) is None  # the chip admits only 4.9
    # 10.2 um a step: 0.2 lost each time, 2 of 102 um (2 %): scale 1 already works
    rounding = incremental_rounding(_linear(10.2), 1.0)
    assert rounding.loss_fraction == pytest.approx(2.0 / 102.0) and rounding.admissible
    assert smallest_working_scale(_linear(10.2), 28.0) == 1


def test_a_move_is_lost_only_when_every_axis_rounds_to_nothing() -> None:
    predicted = np.array([[0.3, 0.0, 0.0], [0.6, 0.7, 0.0]])  # moves (0.3, 0) then (0.3, 0.7)
    rounding = incremental_rounding(predicted, 1.0)
    assert rounding.lost_steps == 1
    assert rounding.largest_error_um == pytest.approx(0.6)  # x: both 0.3 moves lost
    assert incremental_rounding(np.zeros((5, 3)), 1.0).loss_fraction == 0.0
