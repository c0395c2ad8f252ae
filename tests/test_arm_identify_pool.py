"""Issue 29: a cycle that heats two joints together fixes their total heat, not its split. The
calibration pools the heats it cannot tell apart into one factor (daemon/arm/identify_final.py
``pooled_heat``) instead of leaving them at the preset's 1 for the other factors to absorb;
checked on data the forward model made at a known truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from daemon.arm.identify import _ArmProblem
from daemon.arm.identify_final import identify_arm_final
from daemon.arm.identify_parameters import heat_joints, parse_parameters, pooled_heat_name
from daemon.arm.response import ArmRunData
from daemon.arm.thermal import ArmThermalModel
from daemon.model.identify_parameters import IdentificationError
from tests.test_arm_identify_fast import (
    STEP_S,
    a465_description,
    a465_spec,
    phased_heat,
    regions_of,
)

#: The tool's 1-sigma per coordinate (mm), and no IR: joints 1 and 3 cannot be identified
#: alone on this cycle (relative errors 0.9 and 0.7), nor together beside joint 2.
NOISE_MM = 0.01


def test_a_pooled_heat_name_acts_on_its_joints() -> None:
    assert pooled_heat_name([3, 1, 2]) == "heat:1+2+3"
    assert heat_joints("heat:1+2+3") == (1, 2, 3)
    assert heat_joints("heat:4") == (4,)
    assert heat_joints("heat") == () and heat_joints("share:2") == ()
    (pool,) = parse_parameters(["heat:2+5"], 6, {})
    assert pool.kind == "heat" and pool.indices == (1, 4)
    with pytest.raises(IdentificationError, match="numbered"):
        parse_parameters(["heat:2+9"], 6, {})
    with pytest.raises(IdentificationError, match="numbered"):
        parse_parameters(["share:2+3"], 6, {})
    with pytest.raises(IdentificationError, match="twice"):
        parse_parameters(["heat:2", "heat:2+3"], 6, {})


@pytest.mark.slow
def test_heats_a_cycle_cannot_tell_apart_are_identified_together(
    noise_mm: float = NOISE_MM,
) -> None:
    # joints 2 and 3 heat in lockstep (one profile, scaled), the tool measured with noise:
    # the tool tells the joints' total heat, not its split
    steps = 900
    heat = phased_heat(steps)
    heat[:, 2] = 0.4 * heat[:, 1]
    truth = {"heat:1": 0.6, "heat:2": 0.6, "heat:3": 0.6, "alpha": 0.95, "convection": 1.2}
    model = ArmThermalModel(a465_description(), across_link=True)  # type: ignore[arg-type]
    spec = a465_spec(regions_of(model))
    times = np.arange(3, steps, 3, dtype=np.float64) * STEP_S
    blank = ArmRunData(
        STEP_S, heat, np.full(steps, 22.0), times, np.arange(times.size) % 2,
        np.zeros((times.size, 1, 3)), {"upper": np.zeros(times.size), "fore": np.zeros(times.size)},
    )  # fmt: skip
    problem = _ArmProblem(blank, spec, parse_parameters(list(truth), 6, spec.regions))
    markers, _ = problem.predictions(np.log(np.array(list(truth.values()))))
    rng = np.random.default_rng(3)
    run = dataclasses.replace(
        blank,
        marker_displacement_mm=(markers + rng.normal(0, NOISE_MM, markers.shape)).reshape(-1, 1, 3),
        region_c={},  # no IR: the IR by each link would tell the joints apart
    )
    calibration = identify_arm_final(run, spec, list(truth))
    flags = {p.name: p for p in calibration.parameters()}
    for name in ("heat:1", "heat:2", "heat:3"):
        assert not flags[name].identifiable and "pool heat:1+2+3" in flags[name].reason
    assert "heat:1+2+3" not in calibration.not_identified  # the pool itself is identified
    assert calibration.final is not None
    pool = calibration.final.parameter("heat:1+2+3")
    assert pool.identifiable
    assert abs(pool.value - 0.6) < 4 * pool.standard_error
    scales = calibration.final.scales
    assert scales.heat[:3] == pytest.approx([pool.value] * 3)
    # what the pool is for: the factors every cycle shares come out right instead of absorbing
    # the heat's error (before: joint 2 alone at 0.49, 6 standard errors off, alpha 0.87)
    for name, value in (("alpha", 0.95), ("convection", 1.2)):
        fitted = calibration.final.parameter(name)
        assert abs(fitted.value - value) < 3 * fitted.standard_error, fitted


def test_the_faces_join_the_fit_only_when_the_means_leave_much_heat_open() -> None:
    from types import SimpleNamespace
    from typing import Any, cast

    from daemon.arm.identify_final import ArmCalibration, faces_needed
    from daemon.model.identify import FittedParameter

    # task A of the A465 (the shoulder 83 % of the heat) and task B (the elbow 20 %)
    watts = np.array([2.4, 32.9, 3.7, 0.0, 0.4, 0.1])
    run = SimpleNamespace(joint_heat_w=np.tile(watts, (10, 1)))

    def calibration(missed: set[int]) -> ArmCalibration:
        fitted = [
            FittedParameter(f"heat:{j}", 1.0, 0.1, 0.1, j not in missed, "") for j in range(1, 7)
        ]
        full = cast(Any, SimpleNamespace(parameters=fitted))
        return ArmCalibration(tuple(p.name for p in fitted), full, None, {})

    heats = cast(Any, run)
    assert not faces_needed(heats, calibration(set()))
    assert not faces_needed(heats, calibration({1, 5, 6}))  # 6.9 % of the heat: the wrists'
    assert faces_needed(heats, calibration({2, 3}))  # the shoulder and the elbow
    assert faces_needed(heats, calibration({3, 5}))  # 9.8 + 1.0 % of the heat
    assert not faces_needed(heats, calibration({5, 6}))
