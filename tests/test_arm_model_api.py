"""``"arm_model"`` in POST /runs (issue 20) through a real uvicorn server and the real daemon on
the arm bench (virtual clock, the C500C emulator in joint space on a pty): a name, never a
path (422), an unknown name is a 404, a saved arm model runs with prediction ``model+ir``
(the IR observer on the arm model's nodes) to the end."""

from __future__ import annotations

import asyncio
from pathlib import Path

import httpx
import pytest

from api.app import create_app
from config import Settings
from daemon.arm.arm_model import ArmModel, arm_model_toml, saved_arm_models_dir
from daemon.service import Daemon
from tests.test_api_server import CONTROL, READ, serve

HEADERS = {"Authorization": f"Bearer {CONTROL}"}
STEPS = 6
#: The states a run ends in (daemon/run/states.py: the terminal ones, and a fault).
ENDED = frozenset({"finished", "stopped", "aborted", "interrupted", "fault"})


def arm_settings(data_dir: Path) -> Settings:
    return Settings.model_validate(
        {
            "bench": {"seed": 7, "clock": "virtual"},
            "storage": {"data_dir": str(data_dir), "report_at_end": False},
            "scheduler": {"duration_s": 10.0 * STEPS, "step_s": 10.0},
            "compensation": {"time_scale": 240.0},
            "camera": {"bit_depth": 12, "grab_timeout_s": 30.0},
            "arm": {"enabled": True, "duty_cycle": "a465-pick-and-place"},
            "api": {"control_token": CONTROL, "read_token": READ},
        }
    )


@pytest.mark.slow
async def test_arm_model_by_name_over_the_api(tmp_path: Path) -> None:
    data_dir = tmp_path / "data"
    folder = saved_arm_models_dir(data_dir)
    folder.mkdir(parents=True)
    model = ArmModel(
        name="cal",
        arm="CRS A465",
        heat_scales=(1.0, 0.85, 0.8, 1.0, 1.0, 1.0),
        convection_scale=0.75,
        alpha_scale=1.05,
        ir_offsets_c={"upper-arm-mid": 0.27, "forearm-mid": -0.29},
        ir_offset_sigma_c={"upper-arm-mid": 0.05, "forearm-mid": 0.05},
        source_runs=("run 1",),
    )
    (folder / "cal.toml").write_text(arm_model_toml(model), "utf-8")
    app = create_app(arm_settings(data_dir), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=60) as client,
    ):
        for body, status in (
            ({"arm_model": "../../etc/passwd"}, 422),
            ({"arm_model": "a/b"}, 422),
            ({"arm_model": "nothing"}, 404),
        ):
            response = await client.post("/api/v1/runs", json=body, headers=HEADERS)
            assert response.status_code == status, response.text
            assert "passwd" not in response.text
        missing = await client.post("/api/v1/runs", json={"arm_model": "nothing"}, headers=HEADERS)
        assert "cal" in missing.json()["message"]  # the 404 lists the saved arm models
        listed = (await client.get("/api/v1/arm-models", headers=HEADERS)).json()
        assert listed["arm_runs"] is True  # arm.enabled: the dashboard offers the models
        assert [m["name"] for m in listed["arm_models"]] == ["cal"]
        assert listed["arm_models"][0]["heat_scales"] == list(model.heat_scales)
        started = await client.post(
            "/api/v1/runs",
            json={"arm_model": "cal", "prediction": "model+ir"},
            headers=HEADERS,
        )
        assert started.status_code == 201, started.text
        run_id = started.json()["id"]
        assert started.json()["parameters"]["arm_model"] == "cal"
        async with asyncio.timeout(90):
            while True:
                run = (await client.get(f"/api/v1/runs/{run_id}", headers=HEADERS)).json()
                # the end, not the first state past running ("stopping" comes between)
                if run["state"] in ENDED:
                    break
                await asyncio.sleep(0.05)
        assert run["state"] == "finished", run
        steps = (
            await client.get(f"/api/v1/runs/{run_id}/steps?format=json", headers=HEADERS)
        ).json()
        rows = steps["steps"] if isinstance(steps, dict) else steps
        assert len(rows) == STEPS
        assert all(row["flags"] == "" for row in rows), [row["error"] for row in rows]
        assert all(row["drift_3d_um"] is not None for row in rows)
