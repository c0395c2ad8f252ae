"""``GET /arm-models`` and ``GET /arm-models/{name}`` (issue 20) through a real uvicorn server
and the real daemon on the simulated bench: the saved arm models with their identification
tables as the files hold them, an unreadable file reported (never a 500), malformed names a
422 and unknown ones a 404 in one line, reads needing the read scope."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from api.app import create_app
from config import Settings
from daemon.arm.arm_model import ArmModel, arm_model_toml, saved_arm_models_dir
from daemon.arm.duty import available_duty_cycles
from daemon.arm.loading import available_arms
from daemon.model.calibration import CalibratedParameter
from daemon.service import Daemon
from tests.test_api_server import CONTROL, READ, serve

READ_AUTH = {"Authorization": f"Bearer {READ}"}

MODEL = ArmModel(
    name="cal",
    arm="CRS A465",
    heat_scales=(1.0, 1.21, 0.83, 1.0, 1.0, 1.0),
    convection_scale=0.76,
    alpha_scale=1.06,
    ir_offsets_c={"upper-arm-mid": 0.27},
    ir_offset_sigma_c={"upper-arm-mid": 0.05},
    parameters=(
        CalibratedParameter("heat:2", 1.21, 0.04, 0.033, True, ""),
        CalibratedParameter("heat:4", 1.0, None, None, False, "relative standard error > 50 %"),
    ),
    duty_cycle="a465-pick-and-place",
    source_runs=("run 1",),
    identified_at="2026-11-24T01:00:00+00:00",
    marker_rms_um=3.9,
    temperature_rms_c=0.02,
    validation_runs=("run 2",),
    validation_marker_rms_um=4.1,
    validation_preset_marker_rms_um=12.5,
)


def settings_for(data_dir: Path, arm: bool = False) -> Settings:
    return Settings.model_validate(
        {
            "storage": {"data_dir": str(data_dir), "report_at_end": False},
            "api": {"control_token": CONTROL, "read_token": READ, "anonymous_read": False},
            "arm": {"enabled": arm, "duty_cycle": "a465-pick-and-place"},
        }
    )


def save(data_dir: Path, name: str, text: str) -> None:
    folder = saved_arm_models_dir(data_dir)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{name}.toml").write_text(text, "utf-8")


async def test_saved_arm_models_are_listed_with_their_identification(tmp_path: Path) -> None:
    data_dir = tmp_path / "data"
    save(data_dir, "cal", arm_model_toml(MODEL))
    save(data_dir, "broken", "format = 1\nname = ")
    wrong = arm_model_toml(MODEL).replace("standard_error = 0.04", 'standard_error = "small"')
    save(data_dir, "wrong", wrong)  # TOML, but a text where a number belongs
    app = create_app(settings_for(data_dir), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
    ):
        refused = await client.get("/api/v1/arm-models")
        assert refused.status_code == 401  # reads need a token here
        listed = (await client.get("/api/v1/arm-models", headers=READ_AUTH)).json()
        assert listed["arm_runs"] is False  # the two-link bench: arm runs are not enabled
        assert listed["arm_presets"] == available_arms() and "crs-a465" in listed["arm_presets"]
        assert listed["duty_cycles"] == available_duty_cycles()
        assert [m["name"] for m in listed["arm_models"]] == ["cal"]
        unreadable = {p["name"]: p["error"] for p in listed["unreadable"]}
        assert set(unreadable) == {"broken", "wrong"}
        assert "broken.toml" in unreadable["broken"]
        assert "standard_error must be a number" in unreadable["wrong"]

        one = await client.get("/api/v1/arm-models/cal", headers=READ_AUTH)
        assert one.status_code == 200, one.text
        model = one.json()
        assert model == listed["arm_models"][0]
        assert (model["arm"], model["duty_cycle"]) == ("CRS A465", "a465-pick-and-place")
        assert model["source_runs"] == ["run 1"] and model["identified_at"].startswith("2026")
        assert model["heat_scales"] == list(MODEL.heat_scales)
        assert (model["convection_scale"], model["alpha_scale"]) == (0.76, 1.06)
        assert model["marker_rms_um"] == 3.9 and model["temperature_rms_c"] == 0.02
        assert model["ir_offsets_c"] == {"upper-arm-mid": 0.27}
        parameters = {p["name"]: p for p in model["parameters"]}
        assert parameters["heat:2"]["standard_error"] == 0.04
        assert parameters["heat:2"]["identifiable"] is True
        assert parameters["heat:4"]["standard_error"] is None
        assert parameters["heat:4"]["reason"].startswith("relative standard error")
        assert model["validation_runs"] == ["run 2"]
        assert model["validation_marker_rms_um"] == 4.1
        assert model["validation_preset_marker_rms_um"] == 12.5

        broken = await client.get("/api/v1/arm-models/broken", headers=READ_AUTH)
        assert broken.status_code == 422 and "does not load" in broken.json()["message"]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "status", "says"),
    [
        ("nothing", 404, "no saved arm model 'nothing' (saved: cal;"),
        ("x.toml", 404, "no saved arm model 'x.toml'"),
        (".hidden", 422, "is not a name"),
        ("-rf", 422, "is not a name"),
        ("a b", 422, "is not a name"),
        ("x" * 65, 422, "is not a name"),
        ("..%2F..%2Fetc%2Fpasswd", 404, "Not Found"),  # a path: no such route
    ],
)
async def test_bad_arm_model_names(tmp_path: Path, name: str, status: int, says: str) -> None:
    data_dir = tmp_path / "data"
    save(data_dir, "cal", arm_model_toml(MODEL))
    app = create_app(settings_for(data_dir), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
    ):
        response = await client.get(f"/api/v1/arm-models/{name}", headers=READ_AUTH)
    body = response.json()
    assert response.status_code == status, response.text
    assert says in body["message"] and "\n" not in body["message"]
    assert "root:" not in response.text
