"""Runs through the API on the simulated bench: a real uvicorn server on a free port, the real
daemon (C500C emulator on a pseudo-terminal, simulated camera and IR), a real WebSocket client."""

from __future__ import annotations

import asyncio
import base64
import csv
import gc
import io
import json
import socket
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families
from websockets.asyncio.client import ClientConnection, connect

from api.app import create_app
from api.routers import run_data as run_data_router
from config import Settings
from daemon.service import Daemon
from tests.test_api_server import CONTROL, READ, receive_json, serve

CONTROL_HEADERS = {"Authorization": f"Bearer {CONTROL}"}


def bench_settings(data_dir: Path, clock: str = "accelerated", **api: Any) -> Settings:
    return Settings.model_validate(
        {
            # 50 bench seconds per wall second: a 1 s step every 20 ms
            "bench": {"clock": clock, "time_factor": 50.0},
            "storage": {"data_dir": str(data_dir), "archive_every": 5},
            "api": {"control_token": CONTROL, "read_token": READ, "control_burst": 50, **api},
        }
    )


async def next_of_type(ws: ClientConnection, kind: str, timeout_s: float = 30.0) -> dict[str, Any]:
    async with asyncio.timeout(timeout_s):
        while True:
            message = await receive_json(ws, timeout_s)
            if message["type"] == kind:
                return message


async def wait_state(client: httpx.AsyncClient, *states: str, timeout_s: float = 30) -> None:
    async with asyncio.timeout(timeout_s):
        while True:
            if (await client.get("/api/v1/state")).json()["state"] in states:
                return
            await asyncio.sleep(0.02)


@pytest.fixture
async def bench(tmp_path: Path) -> AsyncIterator[tuple[httpx.AsyncClient, str]]:
    app = create_app(bench_settings(tmp_path / "data"), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
    ):
        yield client, address


@pytest.mark.slow
async def test_full_run_cycle(
    bench: tuple[httpx.AsyncClient, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    client, address = bench
    monkeypatch.setattr(run_data_router, "CSV_CHUNK_STEPS", 4)  # the CSV streams in many chunks
    health = (await client.get("/api/v1/health")).json()
    assert health["daemon"] == "running"
    assert health["devices"] == {"robot": "connected", "camera": "open", "ir": "open"}

    read = {"Authorization": f"Bearer {READ}"}
    async with (
        connect(f"ws://{address}/api/v1/ws?topics=steps,state", additional_headers=read) as ws,
        connect(f"ws://{address}/api/v1/ws?topics=frames", additional_headers=read) as frames,
    ):
        assert (await receive_json(ws))["type"] == "hello"
        assert (await receive_json(frames))["type"] == "hello"
        body = {"duration_s": 3600, "step_s": 1.0, "compensation": "absolute"}
        assert (await client.post("/api/v1/runs", json=body)).status_code == 401
        forbidden = await client.post(
            "/api/v1/runs", json=body, headers={"Authorization": f"Bearer {READ}"}
        )
        assert forbidden.status_code == 403

        bad = await client.post(
            "/api/v1/runs",
            json={"step_s": 0.001, "compensation": "sideways", "colour": "red"},
            headers=CONTROL_HEADERS,
        )
        assert bad.status_code == 422
        fields = {d["field"] for d in bad.json()["details"]}
        assert {"body.step_s", "body.compensation", "body.colour"} <= fields
        inconsistent = await client.post(
            "/api/v1/runs", json={"step_s": 10, "duration_s": 5}, headers=CONTROL_HEADERS
        )
        assert inconsistent.status_code == 422 and inconsistent.json()["kind"] == "validation"
        for refused in (
            '{"duration_s": Infinity}',  # JSON extension Python accepts: refused
            '{"network": "../../etc/passwd"}',  # only presets over the API, never a path
            '{"heat_w": {"999": 1.0}, "duration_s": 5}',  # no such node
        ):
            response = await client.post(
                "/api/v1/runs",
                content=refused,
                headers={**CONTROL_HEADERS, "Content-Type": "application/json"},
            )
            assert response.status_code == 422, (refused, response.text)
            assert "passwd" not in response.json()["details"][0]["message"]

        started = await client.post("/api/v1/runs", json=body, headers=CONTROL_HEADERS)
        assert started.status_code == 201, started.text
        run = started.json()
        run_id = run["id"]
        assert run["parameters"]["compensation"] == "absolute"
        assert run["links"]["steps_csv"] == f"/api/v1/runs/{run_id}/steps?format=csv"
        again = await client.post("/api/v1/runs", json={}, headers=CONTROL_HEADERS)
        assert again.status_code == 409 and again.json()["kind"] == "conflict"

        streamed = [(await next_of_type(ws, "step"))["data"] for _ in range(8)]
        assert [s["run_id"] for s in streamed] == [run_id] * 8
        assert [s["step"] for s in streamed] == sorted(s["step"] for s in streamed)
        # each absolute move's console commands, timed (the Prometheus histogram's input)
        per_move = len(streamed[0]["serial_round_trips_s"])
        assert per_move > 0
        assert all(len(s["serial_round_trips_s"]) == per_move for s in streamed)
        assert all(t > 0 for s in streamed for t in s["serial_round_trips_s"])
        devices = (await client.get("/api/v1/health")).json()["devices"]
        assert devices == {"robot": "connected", "camera": "ok", "ir": "ok"}
        # a thumbnail of the camera frame: the spot is in the block the centroid says
        frame = (await next_of_type(frames, "frame"))["data"]
        assert frame["run_id"] == run_id and frame["centroid_x_px"] is not None
        small = cv2.imdecode(
            np.frombuffer(base64.b64decode(frame["png_base64"]), np.uint8), cv2.IMREAD_UNCHANGED
        )
        assert small.shape == (frame["height"], frame["width"])
        row, col = np.unravel_index(np.argmax(small), small.shape)
        scale = frame["scale"]
        assert abs(col - (frame["centroid_x_px"] + 0.5) // scale) <= 1
        assert abs(row - (frame["centroid_y_px"] + 0.5) // scale) <= 1

        state = (await client.get("/api/v1/state")).json()
        assert state["state"] == "running" and state["run"]["id"] == run_id
        assert state["last_step"]["step"] >= 7 and state["websocket_clients"] == 2
        progress = (await client.get(f"/api/v1/runs/{run_id}")).json()
        assert 0 < progress["progress_percent"] < 100
        assert progress["remaining_s"] > 0 and progress["eta_s"] > 0

        paused = await client.post(f"/api/v1/runs/{run_id}/pause", headers=CONTROL_HEADERS)
        assert paused.status_code == 200 and paused.json()["state"] == "paused"
        # /state answers from a cache, but never an answer older than the pause
        assert (await client.get("/api/v1/state")).json()["state"] == "paused"
        assert (await next_of_type(ws, "state"))["data"]["state"] == "paused"
        twice = await client.post(f"/api/v1/runs/{run_id}/pause", headers=CONTROL_HEADERS)
        assert twice.status_code == 409
        resumed = await client.post(f"/api/v1/runs/{run_id}/resume", headers=CONTROL_HEADERS)
        assert resumed.status_code == 200 and resumed.json()["state"] == "running"
        await next_of_type(ws, "step")  # steps go on after the resume
        held = await client.post("/api/v1/robot/stop", headers=CONTROL_HEADERS)
        assert held.status_code == 200 and held.json() == {"held": True, "state": "paused"}
        stopped = await client.post(f"/api/v1/runs/{run_id}/stop", headers=CONTROL_HEADERS)
        assert stopped.status_code == 200 and stopped.json()["state"] == "stopped"
        assert 0 < stopped.json()["summary"]["n"] <= stopped.json()["steps_recorded"]
        late = await client.post(f"/api/v1/runs/{run_id}/stop", headers=CONTROL_HEADERS)
        assert late.status_code == 409
    assert (await client.get("/api/v1/state")).json()["state"] == "idle"

    # the steps, as JSON pages and as CSV, are the records the stream carried
    steps_recorded = stopped.json()["steps_recorded"]
    page = (await client.get(f"/api/v1/runs/{run_id}/steps", params={"from": 2, "limit": 3})).json()
    assert [s["step"] for s in page["steps"]] == [2, 3, 4] and page["next_from"] == 5
    csv_response = await client.get(f"/api/v1/runs/{run_id}/steps", params={"format": "csv"})
    assert csv_response.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(csv_response.text)))
    assert len(rows) == steps_recorded
    assert [int(r["step"]) for r in rows] == list(range(steps_recorded))
    part = await client.get(f"/api/v1/runs/{run_id}/steps?format=csv&from=2&limit=7")
    part_rows = list(csv.DictReader(io.StringIO(part.text)))
    assert part_rows == rows[2:9]
    for message in streamed:
        row = rows[message["step"]]
        assert float(row["predicted_x_um"]) == message["predicted_x_um"]
        assert float(row["offset_x_mm"]) == message["offset_x_mm"]

    # frames archived every 5th step are served as 16-bit PNGs; others are 404
    frame = await client.get(f"/api/v1/runs/{run_id}/frames/5")
    assert frame.status_code == 200 and frame.headers["content-type"] == "image/png"
    image = cv2.imdecode(np.frombuffer(frame.content, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image.dtype == np.uint16 and image.ndim == 2
    assert (await client.get(f"/api/v1/runs/{run_id}/frames/6")).status_code == 404

    # the daemon writes the report after the run's end: 202 (ask again) until it is there.
    # Its writer runs at niceness 10 (daemon/storage/report_worker.py REPORT_NICENESS), so on
    # a 2-core machine busy at niceness 0 (`make test` beside two busy loops) it gets a few %
    # of a core: 60 s ran out once there (202 still), minutes are its honest bound
    report = await client.get(f"/api/v1/runs/{run_id}/report")
    deadline = time.monotonic() + 240
    while report.status_code == 202 and time.monotonic() < deadline:
        assert report.json()["kind"] == "pending" and report.headers["retry-after"] == "2"
        await asyncio.sleep(0.2)
        report = await client.get(f"/api/v1/runs/{run_id}/report")
    assert report.status_code == 200 and report.headers["content-type"].startswith("text/html")
    assert (await client.get("/api/v1/runs/999/report")).status_code == 404

    metrics = {
        sample.name: sample.value
        for family in text_string_to_metric_families((await client.get("/metrics")).text)
        for sample in family.samples
    }
    assert metrics["thermocomp_steps_total"] == steps_recorded
    assert metrics["thermocomp_step_lateness_seconds_count"] == steps_recorded
    moved = sum(1 for r in rows if r["pose_x_mm"] != "")  # a move read its pose back
    assert metrics["thermocomp_serial_round_trip_seconds_count"] == moved * per_move > 0
    assert (await client.get("/api/v1/errors")).status_code == 200


@pytest.mark.slow
async def test_runs_are_listed_newest_first_in_pages(tmp_path: Path) -> None:
    app = create_app(bench_settings(tmp_path / "data", clock="virtual"), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
    ):
        ids = []
        for _ in range(3):
            response = await client.post(
                "/api/v1/runs", json={"duration_s": 5, "step_s": 1}, headers=CONTROL_HEADERS
            )
            assert response.status_code == 201
            ids.append(response.json()["id"])
            await wait_state(client, "idle")
        first = (await client.get("/api/v1/runs", params={"limit": 2})).json()
        assert [r["id"] for r in first["runs"]] == ids[::-1][:2] and first["next_offset"] == 2
        rest = (await client.get("/api/v1/runs", params={"limit": 2, "offset": 2})).json()
        assert [r["id"] for r in rest["runs"]] == ids[:1] and rest["next_offset"] is None
        done = (await client.get(f"/api/v1/runs/{ids[0]}")).json()
        assert done["state"] == "finished" and done["progress_percent"] == 100
        assert done["steps_recorded"] == 5 and done["eta_s"] == 0
        assert (await client.get("/api/v1/runs/12345")).status_code == 404


@pytest.mark.slow
async def test_a_slow_websocket_client_does_not_hold_up_the_steps(tmp_path: Path) -> None:
    """A client that reads nothing while a whole run goes by: the run still records every
    step on the virtual clock (had a send waited for the client, it would stall), and every
    step message is afterwards either delivered or counted as lost."""
    steps = 150  # ~1.3 kB each: far more than the buffers between server and client hold
    settings = bench_settings(tmp_path / "data", clock="virtual", ws_queue_messages=8)
    app = create_app(settings, service_factory=Daemon)
    async with (
        serve(app, send_buffer_bytes=4096) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
    ):
        # a small receive buffer, so the kernel cannot hide the client's slowness
        host, port = address.split(":")
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        sock.connect((host, int(port)))
        sock.setblocking(False)
        uri = f"ws://{address}/api/v1/ws?topics=steps"
        # no compression: the messages keep their size on the wire
        async with connect(uri, sock=sock, max_queue=1, compression=None) as slow:
            assert (await receive_json(slow))["type"] == "hello"
            started = await client.post(
                "/api/v1/runs", json={"duration_s": steps, "step_s": 1}, headers=CONTROL_HEADERS
            )
            assert started.status_code == 201
            await wait_state(client, "idle", timeout_s=60)
            run = (await client.get(f"/api/v1/runs/{started.json()['id']}")).json()
            assert run["state"] == "finished" and run["steps_recorded"] == steps

            delivered, lost = 0, 0
            async with asyncio.timeout(30):
                while delivered + lost < run["steps_recorded"]:
                    message = json.loads(await slow.recv())
                    if message["type"] == "lost":
                        lost += message["data"]["count"]
                    else:
                        assert message["type"] == "step"
                        delivered += 1
            assert lost > 0 and delivered + lost == steps


STAGE_ORDER = ("model", "check", "move", "frame", "centroid", "ir", "record")


@pytest.mark.slow
async def test_metrics_give_each_stages_share_of_the_step_budget(tmp_path: Path) -> None:
    """/metrics of a real server after a run: per stage, how long it took and how late past
    the step's deadline it ended, for every step; the ends follow the stages' order, each at
    least the stages' durations until then (the budget is spent in order, gaps included),
    and the period they share."""
    steps = 5
    thresholds = gc.get_threshold()
    app = create_app(bench_settings(tmp_path / "data", clock="virtual"), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", timeout=30) as client,
    ):
        started = await client.post(
            "/api/v1/runs", json={"duration_s": steps, "step_s": 1}, headers=CONTROL_HEADERS
        )
        assert started.status_code == 201
        await wait_state(client, "idle")
        text = (await client.get("/metrics")).text
        # full collections were deferred while it stepped (daemon/run/gc_policy.py): not now
        assert gc.get_threshold() == thresholds
    families = {family.name: family for family in text_string_to_metric_families(text)}
    assert families["thermocomp_stage_lateness_seconds"].type == "histogram"
    samples = {
        (sample.name, sample.labels.get("stage")): sample.value
        for family in families.values()
        for sample in family.samples
    }
    assert samples[("thermocomp_step_period_seconds", None)] == 1.0
    late = "thermocomp_stage_lateness_seconds"
    took = "thermocomp_stage_duration_seconds"
    for stage in STAGE_ORDER:
        assert samples[(f"{late}_count", stage)] == steps, stage
        assert samples[(f"{took}_count", stage)] == steps, stage
    ends = [samples[(f"{late}_sum", stage)] for stage in STAGE_ORDER]
    assert ends == sorted(ends) and ends[0] > 0
    spent = 0.0
    for stage, end in zip(STAGE_ORDER, ends, strict=True):
        spent += samples[(f"{took}_sum", stage)]
        assert end >= spent * (1 - 1e-9), (stage, end, spent)
    # every collection of the process is counted, by generation
    assert families["thermocomp_gc_collections"].type == "counter"
    collected = {
        sample.labels["generation"]: sample.value
        for sample in families["thermocomp_gc_collections"].samples
        if sample.name == "thermocomp_gc_collections_total"
    }
    assert set(collected) == {"0", "1", "2"} and collected["0"] > 0  # a served run allocates
