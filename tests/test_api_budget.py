"""``GET /api/v1/budget`` (issue 32) through a real uvicorn server and the daemon on the
simulated bench: made live from the settings when nothing is saved, the latest `thermocomp
budget --save` (with its recordings) when one is, reads needing the read scope."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from api.app import create_app
from daemon.analysis.budget import Budget, Source
from daemon.service import Daemon
from daemon.storage.budgets import BUDGET_FILE, save_budget
from tests.test_api_arm_models import READ_AUTH, settings_for
from tests.test_api_server import serve


async def test_budget_live_then_saved(tmp_path: Path) -> None:
    data_dir = tmp_path / "data"
    app = create_app(settings_for(data_dir), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=60) as client,
    ):
        assert (await client.get("/api/v1/budget")).status_code == 401
        live = await client.get("/api/v1/budget", headers=READ_AUTH)
        assert live.status_code == 200, live.text
        body = live.json()
        assert (body["source"], body["recorded"], body["made_at"]) == ("live", False, None)
        rows = {row["key"]: row for row in body["sources"]}
        assert rows["bending"]["delta_l_um"] == pytest.approx(0.00123, rel=0.02)
        assert rows["camera-drift"]["evidence"] == "not quantified"
        assert "--save" in rows["camera-drift"]["basis"]
        assert body["target_um"] == 5.0 and body["resolves"] is True

        tight = (await client.get("/api/v1/budget?target_um=0.1", headers=READ_AUTH)).json()
        assert tight["target_um"] == 0.1 and tight["resolves"] is False
        assert tight["verdict"].startswith("CANNOT RESOLVE")
        refused = await client.get("/api/v1/budget?target_um=-1", headers=READ_AUTH)
        assert refused.status_code == 422

        measured = Source("camera-drift", "Thermal drift of the camera", "4.8", "measured",
                          1.5, "moves the chip", "warm it up", "recorded")  # fmt: skip
        save_budget(data_dir, Budget("saved set-up", 140.0, "model", 5.0, (measured,)), True)
        saved = (await client.get("/api/v1/budget", headers=READ_AUTH)).json()
        assert (saved["source"], saved["recorded"], saved["setup"]) == (
            "saved",
            True,
            "saved set-up",
        )
        assert saved["made_at"] and saved["sources"][0]["delta_l_um"] == 1.5
        fresh = (await client.get("/api/v1/budget?fresh=true", headers=READ_AUTH)).json()
        assert fresh["source"] == "live"
        (data_dir / BUDGET_FILE).write_text("{not json")
        broken = await client.get("/api/v1/budget", headers=READ_AUTH)
        assert broken.status_code == 200 and broken.json()["source"] == "live"


async def test_an_arms_live_budget_has_its_poses(tmp_path: Path) -> None:
    app = create_app(settings_for(tmp_path / "data", arm=True), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=60) as client,
    ):
        answer = await client.get("/api/v1/budget", headers=READ_AUTH)
        assert answer.status_code == 200, answer.text
        body = answer.json()
        assert body["source"] == "live" and body["setup"].startswith("arm CRS A465")
        poses = body["poses"]
        assert poses and all(p["measurement_um"] > 0 and p["cameras_seeing"] for p in poses)
        rows = {row["key"]: row for row in body["sources"]}
        assert rows["measurement-3d"]["evidence"] == "model"
        assert rows["camera-drift"]["evidence"] == "not quantified"
