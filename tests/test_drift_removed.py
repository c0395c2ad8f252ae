"""The dashboard's headline "drift removed so far" (issue 28): daemon/analysis/removed.py on
series with known answers, and GET /runs/{id}/drift-removed on the simulated bench, where it
must equal the end-of-run summary's own reduction once the run has ended."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path
from typing import Any

import httpx
import pytest

from api.app import create_app
from daemon.analysis.removed import drift_removed
from daemon.analysis.steps import RunSteps, steps_from_rows
from daemon.service import Daemon
from tests.test_api_runs import CONTROL_HEADERS, bench_settings, wait_state
from tests.test_api_server import serve


def two_link(run_id: int, residuals: list[float], offset_mm: float = 0.001) -> RunSteps:
    """Steps 1 s apart with these residuals, a prediction of 100 um along x."""
    return steps_from_rows(
        {
            "run_id": run_id,
            "step": k,
            "scheduled_s": float(k),
            "predicted_x_um": 100.0,
            "predicted_y_um": 0.0,
            "predicted_z_um": 0.0,
            "offset_x_mm": offset_mm,
            "offset_y_mm": 0.0,
            "offset_z_mm": 0.0,
            "residual_um": value,
            "deformation_scale": 1.0,
            "flags": "",
            "error": "",
        }
        for k, value in enumerate(residuals)
    )


def arm(run_id: int, drifts: list[float], sigma_um: float = 1.0) -> RunSteps:
    """An arm run's steps: drift along x only, so |drift| is each value."""
    return steps_from_rows(
        {
            "run_id": run_id,
            "step": k,
            "scheduled_s": 10.0 * k,
            "predicted_tx_um": 50.0,
            "predicted_ty_um": 0.0,
            "predicted_tz_um": 0.0,
            "measured_tx_um": value,
            "measured_ty_um": 0.0,
            "measured_tz_um": 0.0,
            "drift_3d_um": abs(value),
            "rotation_error_urad": 5.0,
            "measured_sigma_um": sigma_um,
            "measured_rotation_sigma_urad": 50.0,
            "flags": "",
            "error": "",
        }
        for k, value in enumerate(drifts)
    )


def test_against_a_measured_reference_over_the_time_both_cover() -> None:
    # the reference drifted 40 um by 3 s and 80 um later: only its first 4 steps count
    reference = two_link(1, [0.0, 10.0, 25.0, 40.0, 80.0, 90.0], offset_mm=0.0)
    run = two_link(2, [0.5, -1.0, 2.0, -4.0])
    figures = drift_removed(run, compensation="absolute", reference=reference, reference_run=1)
    assert figures["basis"] == "reference" and figures["kind"] == "two-link"
    assert figures["span_s"] == 3.0
    assert figures["residual_max_um"] == 4.0 and figures["reference_max_um"] == 40.0
    assert figures["removed_percent"] == pytest.approx(90.0)
    assert figures["headline"] == (
        "90 % of the measured drift removed so far: largest error 4.00 µm against 40.0 µm "
        "measured without compensation (run 1)."
    )


def test_a_residual_above_the_reference_is_said_in_words() -> None:
    reference = two_link(1, [0.0, 1.0, 2.0], offset_mm=0.0)
    run = two_link(2, [0.0, 3.0, 5.0])
    figures = drift_removed(run, compensation="absolute", reference=reference, reference_run=1)
    assert figures["removed_percent"] == pytest.approx(-150.0)  # the number, for scripts
    headline = str(figures["headline"])
    assert headline.startswith("Not removing drift so far")
    assert "%" not in headline


def test_without_a_reference_nothing_is_called_removed() -> None:
    figures = drift_removed(two_link(2, [1.0, 2.0]), compensation="absolute")
    assert figures["basis"] == "prediction" and figures["removed_percent"] is None
    assert figures["vs_prediction_percent"] == pytest.approx(98.0)
    assert "removed" not in str(figures["headline"]).split(".")[0]
    assert "No uncompensated reference run named" in str(figures["headline"])


def test_an_uncompensated_run_states_its_drift() -> None:
    figures = drift_removed(two_link(1, [0.0, 7.5], offset_mm=0.0), compensation="off")
    assert figures["basis"] == "drift"
    assert figures["headline"] == "Compensation off: the measured drift so far is 7.50 µm at most."


def test_arm_runs_use_the_3d_drift_and_say_when_the_reference_is_noise() -> None:
    reference = arm(1, [0.0, 30.0, 60.0], sigma_um=2.0)
    run = arm(2, [1.0, -3.0, 6.0], sigma_um=2.0)
    figures = drift_removed(run, compensation="absolute", reference=reference, reference_run=1)
    assert figures["kind"] == "arm" and figures["basis"] == "reference"
    assert figures["removed_percent"] == pytest.approx(90.0)
    assert str(figures["headline"]).startswith("90 % of the measured drift removed so far")
    rotation = figures["rotation"]
    assert isinstance(rotation, dict) and rotation["noise_urad"] == 50.0
    # a reference that has not drifted beyond twice the noise: no figure is claimed
    quiet = arm(1, [0.0, 1.0, 3.0], sigma_um=2.0)
    figures = drift_removed(run, compensation="absolute", reference=quiet, reference_run=1)
    assert "within the measurement noise" in str(figures["headline"])
    assert "%" not in str(figures["headline"])


async def _run(client: httpx.AsyncClient, **parameters: Any) -> dict[str, Any]:
    answer = await client.post("/api/v1/runs", json=parameters, headers=CONTROL_HEADERS)
    assert answer.status_code == 201, answer.text
    run_id = answer.json()["id"]
    await wait_state(client, "idle", timeout_s=60)
    async with asyncio.timeout(30):
        while True:
            run: dict[str, Any] = (await client.get(f"/api/v1/runs/{run_id}")).json()
            if run["summary"] is not None:
                return run
            await asyncio.sleep(0.05)


@pytest.mark.slow
async def test_the_endpoint_gives_the_summarys_reduction_at_the_end(tmp_path: Path) -> None:
    app = create_app(bench_settings(tmp_path / "data", clock="virtual"), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
    ):
        off = await _run(client, compensation="off", duration_s=120, step_s=2)
        drift = (await client.get(f"/api/v1/runs/{off['id']}/drift-removed")).json()
        assert drift["basis"] == "drift" and drift["steps"] == off["steps_recorded"]
        assert drift["residual_max_um"] == pytest.approx(off["summary"]["measured_drift_max_um"])
        on = await _run(
            client, compensation="absolute", duration_s=120, step_s=2, reference_run=off["id"]
        )
        figures = (await client.get(f"/api/v1/runs/{on['id']}/drift-removed")).json()
        summary = on["summary"]
        assert figures["basis"] == "reference" and figures["reference_run"] == off["id"]
        assert math.isclose(figures["removed_percent"], summary["reduction_percent"])
        assert math.isclose(figures["reference_max_um"], summary["reference_max_um"])
        assert summary["reduction_percent"] > 50  # the bench's compensation works
        assert figures["headline"].startswith(
            f"{summary['reduction_percent']:.0f} % of the measured drift removed:"
        )
        missing = await client.get("/api/v1/runs/99/drift-removed")
        assert missing.status_code == 404
