"""Joint temperatures as the arm model's thermal input (daemon/arm/joint_temperatures.py):
fed a truth's joint temperatures, the model follows a truth whose motors heat 60 % more than
it assumes, where the same model without them cannot; the tool error is the kinematics' at
any configuration."""

from __future__ import annotations

import numpy as np
import pytest

from daemon.arm.controller import ArmController, ArmModelOptions
from daemon.arm.controller_loading import load_controller
from daemon.arm.joint_temperatures import JointTemperatureError, JointTemperatureModel
from daemon.arm.kinematics import tool_error
from daemon.run.arm.setup import ARMS_DIR

ARM = ARMS_DIR / "ur5e.toml"
DUTY = "ur5e-pick-and-place"
OPTIONS = ArmModelOptions(model_dt_s=60.0)
Q = np.radians([20.0, -80.0, 90.0, -100.0, -90.0, 10.0])


def controller() -> ArmController:
    return load_controller(ARM, DUTY, OPTIONS)


def test_joint_temperatures_bring_the_model_to_a_truth_that_heats_more() -> None:
    truth, blind = controller(), controller()
    truth.heat_scales = np.full(6, 1.6)  # the truth's motors lose 60 % more than modelled
    model = JointTemperatureModel(controller(), sensor_noise_c=0.05)
    for t in np.arange(60.0, 3 * 3600.0 + 1.0, 60.0):
        for c in (truth, blind, model.controller):
            c.advance_to(float(t))
        model.observe(truth.thermal.joint_temperatures_c().tolist())
    true_error = np.array(tool_error(truth.arm, Q, truth.link_states()).translation_mm)
    followed = np.array(model.tool_error(Q).translation_mm)
    unobserved = np.array(tool_error(blind.arm, Q, blind.link_states()).translation_mm)
    assert np.linalg.norm(true_error) > 0.02  # a warm arm: tens of um at the tool
    miss_followed = np.linalg.norm(followed - true_error)
    miss_blind = np.linalg.norm(unobserved - true_error)
    assert miss_followed < 0.3 * miss_blind
    assert model.updates == 180


def test_a_cold_arm_has_no_error_and_a_wrong_reading_is_refused() -> None:
    model = JointTemperatureModel(controller(), sensor_noise_c=0.05)
    model.observe([OPTIONS.ambient_c] * 6)
    assert np.allclose(model.tool_error(Q).translation_mm, 0.0, atol=1e-9)
    with pytest.raises(JointTemperatureError):
        model.observe([22.0] * 5)
