"""Issue 9 in the run loop: a `model+ir` run on the simulated bench, whose truth is hotter and
less cooled than the controller's model, follows the real link where the open loop cannot."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from pydantic import ValidationError

from config import Settings
from daemon.run.states import RunParameters
from daemon.service import Daemon

WRONG_MODEL_BENCH = {
    "clock": "virtual",
    "truth_network": "thesis-two-link",  # the controller's own network ...
    "truth_heat_scale": 1.3,  # ... with 30 % more heat
    "truth_convection_scale": 0.7,  # ... and 30 % less convection
    "stand_drift_um": 0.0,
}


def bench_settings(tmp_path: Path, prediction: str) -> Settings:
    return Settings.model_validate(
        {
            "bench": WRONG_MODEL_BENCH,
            "model": {"prediction": prediction},
            "scheduler": {"duration_s": 900.0, "step_s": 5.0},
            "storage": {"data_dir": str(tmp_path / prediction), "report_at_end": False},
        }
    )


async def run_steps(settings: Settings) -> list[dict[str, Any]]:
    async with Daemon(settings) as daemon:
        info = await daemon.start_run(RunParameters.from_settings(settings))
        await daemon.wait_run()
        assert daemon.recorder is not None
        return [step.as_dict() for step in daemon.recorder.steps(int(info["id"]))]


def rms(values: list[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values))


@pytest.mark.slow
async def test_model_plus_ir_follows_the_real_link(tmp_path: Path) -> None:
    open_loop = await run_steps(bench_settings(tmp_path, "model"))
    observed = await run_steps(bench_settings(tmp_path, "model+ir"))
    assert len(open_loop) == len(observed) == 180

    open_rms = rms([s["residual_um"] for s in open_loop])
    observed_rms = rms([s["residual_um"] for s in observed])
    assert open_rms > 5.0  # the wrong model really is wrong
    assert observed_rms < open_rms / 5

    # The open loop records no filter statistics; the observer records them every step.
    assert all(s["deformation_sigma_um"] is None for s in open_loop)
    sigmas = [s["deformation_sigma_um"] for s in observed]
    assert all(sigma is not None and math.isfinite(sigma) and sigma >= 0 for sigma in sigmas)
    assert all(s["innovation_nis"] is not None for s in observed)
    # A model this wrong biases the IR innovations: the run says so.
    assert any("model-drifting" in s["flags"] for s in observed)
    assert not any("model-drifting" in s["flags"] for s in open_loop)


def test_model_plus_ir_needs_real_time() -> None:
    with pytest.raises(ValidationError, match="model\\+ir needs time_scale 1"):
        RunParameters(prediction="model+ir", time_scale=10.0)
