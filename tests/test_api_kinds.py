"""``GET /kinds`` (issue 27: each run kind owns its dashboard view) through a real uvicorn server
and the real daemon on the simulated benches: every kind of the factory is served, the answer
holds to the API's own description, the kind a start makes follows the settings, what each
view names exists on the page, and each run record carries its kind as recorded."""

from __future__ import annotations

import asyncio
import re
import sqlite3
from pathlib import Path
from typing import Any

import httpx
import pytest
import requests
import schemathesis

from api.app import create_app
from api.routers.runs import RunRequest
from config import Settings
from daemon.run.kinds import KINDS
from daemon.service import Daemon
from daemon.storage.recorder import DATABASE_NAME, Recorder
from tests.test_api_server import CONTROL, READ, serve

READ_AUTH = {"Authorization": f"Bearer {READ}"}
PAGE = (Path(__file__).resolve().parent.parent / "api" / "static" / "index.html").read_text("utf-8")

#: The runs table before runs recorded their kind (main before issue 27's kind views).
OLDER_RUNS = """CREATE TABLE runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT, state TEXT NOT NULL, started_at REAL NOT NULL,
    ended_at REAL, parameters_json TEXT NOT NULL, config_json TEXT NOT NULL, network_json TEXT,
    software_version TEXT NOT NULL, summary_json TEXT, reason TEXT)"""


def settings_for(data_dir: Path, *, arm: bool) -> Settings:
    return Settings.model_validate(
        {
            "storage": {"data_dir": str(data_dir), "report_at_end": False},
            "api": {"control_token": CONTROL, "read_token": READ, "anonymous_read": False},
            "arm": {"enabled": arm, "duty_cycle": "a465-pick-and-place"},
        }
    )


def described_kinds(base_url: str) -> requests.Response:
    """``GET /kinds`` as schemathesis calls it, its answer checked against /openapi.json
    (status, content type, body schema): blocking, on a thread beside the server's loop."""
    schema = schemathesis.openapi.from_url(f"{base_url}/openapi.json")
    operation = schema["/api/v1/kinds"]["GET"]
    case = operation.Case(headers=dict(READ_AUTH))
    response = case.call(base_url=base_url)
    case.validate_response(response)
    return response


async def kinds_served(settings: Settings) -> dict[str, Any]:
    app = create_app(settings, service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
    ):
        refused = await client.get("/api/v1/kinds")
        assert refused.status_code == 401  # reads need a token here
        response = await asyncio.to_thread(described_kinds, f"http://{address}")
    assert response.status_code == 200
    body: dict[str, Any] = response.json()
    return body


@pytest.mark.slow  # a daemon on the simulated bench: ~7 s under load
@pytest.mark.parametrize(("arm", "started"), [(False, "two-link"), (True, "arm")])
async def test_every_kind_serves_its_view(tmp_path: Path, arm: bool, started: str) -> None:
    body = await kinds_served(settings_for(tmp_path / "data", arm=arm))
    views = {view["name"]: view for view in body["kinds"]}
    assert list(views) == [kind.name for kind in KINDS]  # the factory's kinds, in its order
    assert body["default"] == started  # what a start from these settings makes

    slots = set(re.findall(r'id="slot-([\w-]+)"', PAGE))
    fields = set(re.findall(r'data-field="(\w+)"', PAGE))
    requestable = set(RunRequest.model_fields)
    for name, view in views.items():
        drawn = [plot["slot"] for plot in view["plots"]]
        assert drawn and set(drawn) <= slots, (name, drawn)
        assert all(plot["title"] for plot in view["plots"])
        assert set(view["form_fields"]) <= fields & requestable, name
        assert view["form_title"] and view["x_label"] and view["temperature_x_label"]
        assert set(view["reference_kinds"]) <= set(views)
        assert view["reference_runs"] == bool(view["reference_kinds"])
        # a template names run parameters only
        for key in ("what_text", "model_text", "doing_text", "reference_text"):
            assert set(re.findall(r"\{(\w+)\}", view[key])) <= requestable, (name, key)
    # the page's every kind-specific field is some kind's
    assert fields == {f for view in views.values() for f in view["form_fields"]}


def test_a_run_records_its_kind_and_an_older_database_gains_the_column(tmp_path: Path) -> None:
    data = tmp_path / "data"
    data.mkdir()
    with Recorder(data) as recorder:
        recorded = recorder.create_run({"compensation": "off"}, {}, None, "0", kind="arm")
        assert (recorder.run(recorded) or pytest.fail("no row")).kind == "arm"
    # a database of the version before: no kind column, one run
    with sqlite3.connect(data / DATABASE_NAME) as db:
        columns = [row[1] for row in db.execute("PRAGMA table_info(runs)") if row[1] != "kind"]
        db.execute(OLDER_RUNS.replace("runs (", "older ("))
        db.execute(f"INSERT INTO older SELECT {', '.join(columns)} FROM runs")
        db.execute("DROP TABLE runs")
        db.execute("ALTER TABLE older RENAME TO runs")
        db.commit()
    with Recorder(data) as recorder:
        (old,) = recorder.runs()
        assert old.kind is None  # not guessed from its parameters
        new = recorder.create_run({}, {}, None, "0", kind="two-link")
        assert (recorder.run(new) or pytest.fail("no row")).kind == "two-link"
