"""Issue 29: an arm run adapts by itself when its model says it holds only for another cycle.

``arm.adapt`` unset (the default): an arm run whose arm model was calibrated on another duty
cycle and is not fully calibrated (what its cycle could not teach is kept at the preset,
pooled or fitted in combination: the model's warning) adapts its factors online from that
model (daemon/run/arm/setup.py ``adapts``); a model calibrated for this run's cycle, a fully
calibrated one and the preset do not; ``arm.adapt = true`` / ``false`` is obeyed either way.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from config import Settings
from daemon.arm.arm_model import ArmModel
from daemon.run.arm.setup import adapts, default_arm_setup
from daemon.run.states import RunParameters
from tests.test_arm_identify_cli import save_model

TASK_A, TASK_B = "a465-pick-and-place", "a465-machine-tending"


def model(duty_cycle: str, not_identified: tuple[str, ...]) -> ArmModel:
    return ArmModel(
        name="task-model",
        arm="CRS A465",
        heat_scales=(1.2, 0.9, 1.1, 1.0, 1.0, 1.0),
        duty_cycle=duty_cycle,
        not_identified=not_identified,
    )


UNCALIBRATED_ON_A = model(TASK_A, ("heat:5",))


@pytest.mark.parametrize(
    ("setting", "arm_model", "run_cycle", "adapt"),
    [
        (None, UNCALIBRATED_ON_A, TASK_B, True),  # another cycle, holds only for its own
        (None, UNCALIBRATED_ON_A, TASK_A, False),  # its own cycle: what it is calibrated for
        (None, model(TASK_A, ()), TASK_B, False),  # fully calibrated: its factors hold
        (None, None, TASK_B, False),  # the preset
        (False, UNCALIBRATED_ON_A, TASK_B, False),  # the lab's choice is obeyed
        (True, None, TASK_B, True),
    ],
)
def test_when_an_arm_run_adapts(
    setting: bool | None, arm_model: ArmModel | None, run_cycle: str, adapt: bool
) -> None:
    decided, reason = adapts(setting, arm_model, run_cycle)
    assert decided is adapt
    assert ("arm.adapt = " in reason) is (setting is not None)
    if setting is None and adapt:
        assert TASK_A in reason and TASK_B in reason


def plan(data_dir: Path, duty_cycle: str, **arm: Any) -> Any:
    settings = Settings.model_validate(
        {
            "storage": {"data_dir": str(data_dir)},
            "arm": {"enabled": True, "duty_cycle": duty_cycle, **arm},
        }
    )
    parameters = RunParameters.from_settings(
        settings, time_scale=240.0, step_s=10.0, arm_model="task-model"
    )
    return default_arm_setup(settings, parameters)


def test_a_run_of_another_task_adapts_from_the_model_and_records_why(tmp_path: Path) -> None:
    save_model(tmp_path, UNCALIBRATED_ON_A)
    other = plan(tmp_path, TASK_B)
    assert other.predictor.adapting
    assert other.snapshot["adapt"] is True and TASK_A in other.snapshot["adapt_reason"]
    own = plan(tmp_path, TASK_A)
    assert not own.predictor.adapting and own.snapshot["adapt"] is False
    refused = plan(tmp_path, TASK_B, adapt=False)
    assert not refused.predictor.adapting and refused.snapshot["adapt_reason"] == (
        "arm.adapt = false"
    )
