"""Issue 19 in the run loop: with ``observer.adapt`` a `model+ir` run on a bench whose truth
has the controller's own network but 30 % more heat and 30 % less convection records its
estimates of the factors every step, and they reach the truth within their 1-sigma (the
expansion factor, learnt from the spot drift, stays 1)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from config import Settings
from config.settings import IrRegion
from daemon.model import ThermalModel, load_network
from daemon.run.setup import RunParameterError, build_observer
from daemon.run.states import RunParameters
from daemon.service import Daemon

TRUE_HEAT, TRUE_CONVECTION = 1.3, 0.7
WRONG_MODEL_BENCH = {
    "clock": "virtual",
    "truth_network": "thesis-two-link",  # the controller's own network ...
    "truth_heat_scale": TRUE_HEAT,
    "truth_convection_scale": TRUE_CONVECTION,
    "stand_drift_um": 0.0,
}


def bench_settings(tmp_path: Path, adapt: bool) -> Settings:
    return Settings.model_validate(
        {
            "bench": WRONG_MODEL_BENCH,
            "model": {"prediction": "model+ir"},
            "observer": {"adapt": adapt},
            "scheduler": {"duration_s": 900.0, "step_s": 5.0},
            "storage": {"data_dir": str(tmp_path / str(adapt)), "report_at_end": False},
        }
    )


async def run_steps(settings: Settings) -> list[dict[str, Any]]:
    async with Daemon(settings) as daemon:
        info = await daemon.start_run(RunParameters.from_settings(settings))
        await daemon.wait_run()
        assert daemon.recorder is not None
        return [step.as_dict() for step in daemon.recorder.steps(int(info["id"]))]


@pytest.mark.slow
async def test_an_adapting_run_records_factors_that_reach_the_truth(tmp_path: Path) -> None:
    adapted = await run_steps(bench_settings(tmp_path, adapt=True))
    assert len(adapted) == 180
    estimates = [json.loads(s["observer_json"]) for s in adapted if s["observer_json"]]
    assert len(estimates) == len(adapted)
    first, last = estimates[0], estimates[-1]
    for name, truth in (("heat", TRUE_HEAT), ("convection", TRUE_CONVECTION)):
        value, sigma = last[name]
        assert sigma < first[name][1] / 3  # it learnt
        assert abs(value - truth) <= 3 * sigma, (name, value, sigma)
    # the truth expands as the model believes: the camera's alpha stays 1 within its 1-sigma
    alpha, alpha_sigma = last["alpha"]
    assert alpha_sigma < first["alpha"][1] / 3
    assert abs(alpha - 1.0) <= 3 * alpha_sigma
    assert {k for k in last if k.startswith("offset:")}  # the IR offsets with their 1-sigma

    plain = await run_steps(bench_settings(tmp_path, adapt=False))
    plain_last = json.loads(plain[-1]["observer_json"])
    assert "heat" not in plain_last  # without adapt: only the offsets
    assert set(plain_last) == {k for k in last if k.startswith("offset:")}


def test_an_unknown_adapted_parameter_refuses_the_run() -> None:
    settings = Settings.model_validate(
        {"observer": {"adapt": True, "adapt_parameters": ["heat:nowhere"]}}
    )
    model = ThermalModel(load_network(settings.model.network))
    regions = (IrRegion(name="node-2", x=0, y=0, width=4, height=4, node="2"),)
    with pytest.raises(RunParameterError, match=r"observer\.adapt_parameters: .*heat:nowhere"):
        build_observer(settings, model, regions)
