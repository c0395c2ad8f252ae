"""The OpenAPI description against the daemon running on the simulated bench (issue 10: "no
5xx"): schemathesis generates requests for every operation from the server's own
``/openapi.json`` and sends them to a real uvicorn server whose daemon drives the bench (C500C
emulator on a pseudo-terminal, simulated camera and IR, accelerated clock). Each answer must
be no server error and must match what the description promises: its status, content type,
headers and body schema; schema-valid requests are accepted and schema-violating ones refused.
Then every operation that needs a token is tried without one, and the control ones with a
read-only token: 401 and 403, never anything else.

Hypothesis is derandomized (a fixed seed per operation and mode), so CI repeats the same
requests; a failure prints schemathesis's report with a curl command that reproduces it.
"""

from __future__ import annotations

import asyncio
import importlib.util
import io
import re
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest
import requests
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis import Case, GenerationMode
from schemathesis.core import storage as schemathesis_storage

from api.app import create_app
from api.routers import run_data as run_data_router
from config import Settings
from daemon.arm.arm_model import ArmModel, arm_model_toml, saved_arm_models_dir
from daemon.model import available_presets
from daemon.service import Daemon
from daemon.storage.recorder import Recorder
from daemon.storage.reports import write_run_report
from tests.test_api_runs import wait_state
from tests.test_api_server import CONTROL, READ, serve

CONTROL_AUTH = {"Authorization": f"Bearer {CONTROL}"}
READ_AUTH = {"Authorization": f"Bearer {READ}"}
#: The one operation the description declares without security: liveness for health checks.
PUBLIC = frozenset({"GET /api/v1/health"})
#: Examples per operation with the control token: schema-valid, schema-violating; and without
#: a token (the token is checked first, so a few show it).
POSITIVE_EXAMPLES = 30
NEGATIVE_EXAMPLES = 12
NO_TOKEN_EXAMPLES = 3
#: The harness's own run, kept active while the run-control and read operations are fuzzed:
#: a 1 s step on the bench clock at 10x is one step per 100 ms of wall time.
HARNESS_RUN = {"duration_s": 3600, "step_s": 1}
#: Operations that do their work only while idle (409 during a run): fuzzed with no run active.
IDLE_OPERATIONS = frozenset({"POST /api/v1/runs", "GET /api/v1/devices/preview"})
#: The control rate limit the fuzzing runs under (api.control_rate_per_s, control_burst). The
#: fuzzer must outpace it for the test to meet it: at 20/s it did not beside another xdist
#: worker at load 10 (2 of 2 runs without a 429); 5/s leaves a margin of four.
RATE_PER_S = 5.0
BURST = 20


def waited_out(send: Callable[[], Any], answers: set[int]) -> Any:
    """``send()`` again while it is refused with 429 (each a documented error with
    Retry-After), after the wait the answer says; the first other answer."""
    response = send()
    while response.status_code == 429:
        answers.add(429)
        body = response.json()
        headers = {name.lower(): value for name, value in response.headers.items()}
        retry_after = headers["retry-after"]  # a list in schemathesis' responses
        retry_after = retry_after[0] if isinstance(retry_after, list) else retry_after
        assert body["kind"] == "rate-limited" and int(retry_after) >= 1
        time.sleep(float(body["details"]["retry_after_s"]))
        response = send()
    return response


#: Schemathesis' configuration (its TOML). Every built-in check is on; what differs from the
#: defaults, and why:
SCHEMATHESIS_CONFIG = """
[generation]
# Unknown query parameters are ignored, as HTTP APIs do; the description cannot say so, and a
# negative case made only of them would be counted as "schema-violating data accepted".
allow-extra-parameters = false
# The tokens are the harness's to give (or withhold), not random strings to generate.
with-security-parameters = false

[[operations]]
include-name = "POST /api/v1/runs"
# Schema-valid run parameters may still be refused, as the description documents: 422 when
# they are not admissible (an unknown heater node, step_s over duration_s, a deformation scale
# that would carry the spot off the camera chip: thesis 6.3), and 404 when the network they
# name (a well-formed name) is neither a preset nor a network saved in the data directory.
checks.positive_data_acceptance.expected-statuses = [
    "2xx", "401", "403", "404", "409", "422", "429"
]
"""


def bench_settings(data_dir: Path) -> Settings:
    return Settings.model_validate(
        {
            "bench": {"clock": "accelerated", "time_factor": 10.0},
            "storage": {"data_dir": str(data_dir), "archive_every": 2, "report_at_end": False},
            "api": {
                "control_token": CONTROL,
                "read_token": READ,
                # reads need a token too, so the no-token pass covers every secured operation
                "anonymous_read": False,
                # a real limit, not disabled: the fuzzer sends more control requests than it
                # lets through, so 429s are met, checked against the description and waited
                # out (Retry-After) like a client would
                "control_rate_per_s": RATE_PER_S,
                "control_burst": BURST,
            },
        }
    )


@dataclass
class Bench:
    """The running server, and a finished run with steps and archived frames to aim at."""

    base_url: str
    finished_run: int
    finished_steps: int  # how many steps it recorded
    archived_step: int
    arm_model: str  # a saved arm model (GET /arm-models/{name})
    answers: dict[str, set[int]] = field(default_factory=dict)


@pytest.fixture(autouse=True)
def schemathesis_writes_in_tmp_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Schemathesis keeps its cache and crash reports under ./.schemathesis: the test's own
    folder instead (tests/conftest.py refuses files in the repository)."""
    monkeypatch.setattr(schemathesis_storage, "DEFAULT_ROOT", tmp_path / ".schemathesis")


@pytest.fixture
async def bench(tmp_path: Path) -> AsyncIterator[Bench]:
    # an identified arm model saved in the data directory, as `identify RUN --save` writes it
    arm_model = ArmModel(name="cal", arm="CRS A465", heat_scales=(1.0, 1.2, 0.9, 1.0, 1.0, 1.0))
    saved_arm_models_dir(tmp_path / "data").mkdir(parents=True)
    (saved_arm_models_dir(tmp_path / "data") / "cal.toml").write_text(
        arm_model_toml(arm_model), "utf-8"
    )
    app = create_app(bench_settings(tmp_path / "data"), service_factory=Daemon)
    async with (
        serve(app) as address,
        httpx.AsyncClient(base_url=f"http://{address}", headers=CONTROL_AUTH, timeout=30) as client,
    ):
        started = await client.post("/api/v1/runs", json={"duration_s": 6, "step_s": 1})
        assert started.status_code == 201, started.text
        run_id = started.json()["id"]
        await wait_state(client, "idle")
        steps = (await client.get(f"/api/v1/runs/{run_id}/steps")).json()["steps"]
        archived = [s["step"] for s in steps if s["frame_path"]]
        # 6 deadlines of 100 ms wall time: a loaded machine overruns some, which are skipped
        # (daemon/run/scheduler.py), so 1 to 6 steps, numbered 0, 1, 2 ... all the same
        assert 1 <= len(steps) <= 6 and archived
        assert [s["step"] for s in steps] == list(range(len(steps)))
        # its report, as `thermocomp report RUN` writes it (the API only serves reports)
        await asyncio.to_thread(write_run_report, tmp_path / "data", run_id)
        yield Bench(f"http://{address}", run_id, len(steps), archived[0], arm_model.name)


# --- the fuzzing, in a worker thread: schemathesis' requests block, the server runs in this
# --- test's event loop --------------------------------------------------------------------


class RunKeeper:
    """Keeps the daemon where the next request can do something: idle before a start (else it
    is 409 every time), a run active for everything else (pause, resume and stop have
    something to act on, reads see live progress). A run the fuzzer starts is stopped before
    the next request, so its parameters (a 10 ms step, a duration of 1e308 s) cannot load the
    bench for longer than one request."""

    def __init__(self, client: httpx.Client) -> None:
        self.client = client
        self.refused: set[int] = set()

    def active_run(self) -> int | None:
        state = self.client.get("/api/v1/state").json()
        run = state["run"]
        return int(run["id"]) if run is not None and state["state"] != "idle" else None

    def prepare(self, label: str) -> int | None:
        """Set the daemon up for a request of ``label``; the active run's id, if any."""
        active = self.active_run()
        if label in IDLE_OPERATIONS:
            self.stop(active)
            return None
        if active is None:
            started = waited_out(
                lambda: self.client.post("/api/v1/runs", json=HARNESS_RUN), self.refused
            )
            assert started.status_code == 201, started.text
            active = int(started.json()["id"])
        return active

    def stop(self, run_id: int | None) -> None:
        if run_id is not None:
            # 409 when it ended on its own in the meantime: as good
            stop = waited_out(lambda: self.client.post(f"/api/v1/runs/{run_id}/stop"), self.refused)
            assert stop.status_code in (200, 409)


def fuzz_operation(
    operation: Any,
    mode: GenerationMode,
    examples: int,
    send: Callable[[Case, str], None],
) -> None:
    """Run ``send(case, target)`` on ``examples`` generated cases; ``target`` says which run a
    positive case aims at: the one drawn, the finished run or the active one (a drawn run id
    rarely exists, so without this only 404s would be seen); likewise a saved arm model's
    name instead of the drawn one."""
    targets = ("drawn", "finished", "active") if mode is GenerationMode.POSITIVE else ("drawn",)

    @settings(
        max_examples=examples,
        derandomize=True,  # the same requests on every run: reproducible in CI
        database=None,
        # every example is a real HTTP exchange with the daemon, often a run started or
        # stopped: neither a per-example deadline nor the "too slow" health check applies
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow],
    )
    @given(case=operation.as_strategy(generation_mode=mode), target=st.sampled_from(targets))
    def run(case: Case, target: str) -> None:
        send(case, target)

    run()


def fuzz(bench: Bench) -> set[str]:
    """Fuzz every operation of the server's description; return the labels fuzzed."""
    config = schemathesis.Config.from_str(SCHEMATHESIS_CONFIG)
    schema = schemathesis.openapi.from_url(f"{bench.base_url}/openapi.json", config=config)
    fuzzed: set[str] = set()
    with (
        httpx.Client(base_url=bench.base_url, headers=CONTROL_AUTH, timeout=30) as client,
        requests.Session() as session,
    ):
        keeper = RunKeeper(client)

        def send_with_token(case: Case, target: str) -> None:
            label = case.operation.label
            active = keeper.prepare(label)
            if "run_id" in case.path_parameters and target != "drawn":
                run_id = bench.finished_run if target == "finished" or active is None else active
                case.path_parameters["run_id"] = run_id
                if "step" in case.path_parameters and run_id == bench.finished_run:
                    case.path_parameters["step"] = bench.archived_step
            if "name" in case.path_parameters and target != "drawn":
                case.path_parameters["name"] = bench.arm_model  # a drawn name is rarely saved
            answers = bench.answers.setdefault(label, set())
            response = waited_out(
                lambda: case.call(base_url=bench.base_url, session=session, headers=CONTROL_AUTH),
                answers,
            )
            case.validate_response(response)
            answers.add(response.status_code)

        def send_without_scope(case: Case, _: str) -> None:
            label = case.operation.label
            control = case.method == "POST"  # every POST needs the control scope
            headers = READ_AUTH if control else {}
            response = case.call(base_url=bench.base_url, session=session, headers=headers)
            sent = response.request.headers.get("Authorization")
            assert sent == (READ_AUTH["Authorization"] if control else None)
            expected = 403 if control else 401
            assert response.status_code == expected, (label, response.status_code, response.text)
            assert response.json()["kind"] == ("forbidden" if control else "unauthorized")
            case.validate_response(response)

        for result in schema.get_all_operations():
            operation = result.ok()  # raises on an operation schemathesis cannot read
            label = operation.label
            fuzz_operation(operation, GenerationMode.POSITIVE, POSITIVE_EXAMPLES, send_with_token)
            # an operation without parameters or body has no schema to violate
            if list(operation.iter_parameters()) or len(operation.body):
                fuzz_operation(
                    operation, GenerationMode.NEGATIVE, NEGATIVE_EXAMPLES, send_with_token
                )
            if label not in PUBLIC:
                fuzz_operation(
                    operation, GenerationMode.POSITIVE, NO_TOKEN_EXAMPLES, send_without_scope
                )
            fuzzed.add(label)
        keeper.stop(keeper.active_run())
    return fuzzed


def described_operations(description: dict[str, Any]) -> dict[str, bool]:
    """``"METHOD path"`` of every operation of an OpenAPI description -> whether it is
    secured."""
    return {
        f"{method.upper()} {path}": bool(operation.get("security"))
        for path, item in description["paths"].items()
        for method, operation in item.items()
    }


@pytest.mark.slow
async def test_every_operation_holds_to_its_description(bench: Bench) -> None:
    async with httpx.AsyncClient(base_url=bench.base_url, headers=READ_AUTH, timeout=30) as client:
        described = described_operations((await client.get("/openapi.json")).json())
        assert {label for label, secured in described.items() if not secured} == PUBLIC

        fuzzed = await asyncio.to_thread(fuzz, bench)

        # every operation was fuzzed: a new endpoint cannot escape, and with the control
        # token each one did its real work at least once
        assert fuzzed == set(described)
        missing_success = sorted(
            label for label in described if not any(200 <= s < 300 for s in bench.answers[label])
        )
        assert not missing_success, bench.answers
        # the rate limit was met and waited out, the hold never: it is not limited
        assert any(429 in statuses for statuses in bench.answers.values()), bench.answers
        assert 429 not in bench.answers["POST /api/v1/robot/stop"]
        # the fuzzing left the bench working: a short run on the emulated robot completes
        health = (await client.get("/api/v1/health")).json()
        assert health["devices"]["robot"] == "connected"
        started = await client.post(
            "/api/v1/runs", json={"duration_s": 4, "step_s": 1}, headers=CONTROL_AUTH
        )
        assert started.status_code == 201, started.text
        await wait_state(client, "idle")
        run = (await client.get(f"/api/v1/runs/{started.json()['id']}")).json()
        # 4 deadlines of 100 ms wall time: some may be skipped on a loaded machine
        assert run["state"] == "finished" and 1 <= run["steps_recorded"] <= 4, run
        health = (await client.get("/api/v1/health")).json()
        assert health["devices"] == {"robot": "connected", "camera": "ok", "ir": "ok"}


# --- what schemathesis found, kept as regressions --------------------------------------


def step_format_enum(description: dict[str, Any]) -> list[str]:
    parameters = description["paths"]["/api/v1/runs/{run_id}/steps"]["get"]["parameters"]
    enum: list[str] = next(p for p in parameters if p["name"] == "format")["schema"]["enum"]
    return enum


@pytest.mark.parametrize("installed", [False, True])
def test_parquet_is_described_only_when_pyarrow_is_installed(
    monkeypatch: pytest.MonkeyPatch, installed: bool
) -> None:
    """Without the ``parquet`` extra the server answered format=parquet with a 501: a request
    its own description offered ended in a server error. Now the format is offered only when
    the export can be written."""
    monkeypatch.setattr(run_data_router, "parquet_available", lambda: installed)
    description = create_app(Settings()).openapi()
    expected = ["json", "csv", "parquet"] if installed else ["json", "csv"]
    assert step_format_enum(description) == expected
    assert "501" not in description["paths"]["/api/v1/runs/{run_id}/steps"]["get"]["responses"]


@pytest.mark.slow
async def test_parquet_export_without_and_with_pyarrow(
    bench: Bench, monkeypatch: pytest.MonkeyPatch
) -> None:
    steps_url = f"/api/v1/runs/{bench.finished_run}/steps"
    async with httpx.AsyncClient(base_url=bench.base_url, headers=READ_AUTH, timeout=30) as client:
        monkeypatch.setattr(run_data_router, "parquet_available", lambda: False)
        refused = await client.get(steps_url, params={"format": "parquet"})
        assert refused.status_code == 422, refused.text
        body = refused.json()
        assert body["kind"] == "validation" and body["details"][0]["field"] == "query.format"
        assert "pip install 'thermocomp[parquet]'" in body["message"]
        run = (await client.get(f"/api/v1/runs/{bench.finished_run}")).json()
        assert "steps_parquet" not in run["links"]  # no link to what the server cannot do

        monkeypatch.setattr(run_data_router, "parquet_available", lambda: True)
        run = (await client.get(f"/api/v1/runs/{bench.finished_run}")).json()
        assert run["links"]["steps_parquet"] == f"{steps_url}?format=parquet"
        if importlib.util.find_spec("pyarrow") is None:
            # this environment lacks the extra: the recorder's exporter (tested with pyarrow in
            # test_recorder.py) is stood in for by one writing the step numbers, so what is
            # checked here is that the route serves the file the exporter wrote
            def export_parquet(recorder: Recorder, run_id: int, path: Path) -> None:
                steps = [str(s.step) for s in recorder.steps(run_id)]
                path.write_text("step\n" + "\n".join(steps))

            monkeypatch.setattr(Recorder, "export_parquet", export_parquet)
        exported = await client.get(run["links"]["steps_parquet"])
        assert exported.status_code == 200, exported.text
        assert exported.headers["content-type"] == "application/vnd.apache.parquet"
        assert f"run-{bench.finished_run}-steps.parquet" in exported.headers["content-disposition"]
        if importlib.util.find_spec("pyarrow") is None:
            steps = [int(line) for line in exported.text.splitlines()[1:]]
        else:
            import pyarrow.parquet as pq  # type: ignore[import-not-found, unused-ignore]

            steps = pq.read_table(io.BytesIO(exported.content)).column("step").to_pylist()
        assert steps == list(range(bench.finished_steps))


def test_run_networks_are_described_as_names() -> None:
    """The description said ``network`` was any string, the server refused all but the presets
    with a 422: schema-valid requests rejected. Since identified networks saved in the data
    directory are run networks too (issue 19), the schema gives the name's pattern (no path
    matches it) with the presets as examples."""
    description = create_app(Settings()).openapi()
    network = description["components"]["schemas"]["RunRequest"]["properties"]["network"]
    named = network["anyOf"][0]
    assert named["examples"] == available_presets()
    pattern = re.compile(named["pattern"])
    assert all(pattern.match(name) for name in available_presets())
    assert not any(pattern.match(bad) for bad in ("../../etc/passwd", "/tmp/x.toml", "a/b", ""))


async def test_an_unreadable_body_is_a_documented_400() -> None:
    """A body that is not UTF-8 is refused by FastAPI with a 400 the description did not list."""
    app = create_app(Settings.model_validate({"api": {"control_token": CONTROL}}))
    start = app.openapi()["paths"]["/api/v1/runs"]["post"]["responses"]
    assert "400" in start
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
        response = await client.post(
            "/api/v1/runs",
            content=b'{"duration_s": 1\xff}',
            headers={**CONTROL_AUTH, "Content-Type": "application/json"},
        )
    assert response.status_code == 400
    assert response.json()["kind"] == "bad-request"
