"""The API's own machinery, in process (httpx ASGITransport): error shape, tokens and scopes,
rate limits, body limits, redaction, presets, metrics, the WebSocket fan-out, thumbnails."""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import AsyncIterator
from typing import Any

import httpx
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from api.app import create_app
from api.broadcast import Hub, json_safe
from api.relay import CROP_FRAME_PX, spot_crop, thumbnail
from api.security import Authenticator, AuthError, RateLimiter, is_loopback
from config import CONFIG_DIR, Settings
from daemon.vision import render_spot

CONTROL = "control-token-0123456789"
READ = "read-token-0123456789"


def settings(**api: Any) -> Settings:
    return Settings.model_validate({"api": {"control_token": CONTROL, "read_token": READ, **api}})


def bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


@pytest.fixture
async def client() -> AsyncIterator[httpx.AsyncClient]:
    app = create_app(settings())
    transport = httpx.ASGITransport(app=app, raise_app_exceptions=False)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
        yield c


def assert_error_shape(response: httpx.Response, status: int, kind: str) -> dict[str, Any]:
    assert response.status_code == status, response.text
    body: dict[str, Any] = response.json()
    assert set(body) == {"status", "kind", "message", "details"}
    assert body["status"] == status and body["kind"] == kind
    assert "Traceback" not in response.text
    return body


# --- error shape ------------------------------------------------------------------------


async def test_unknown_route_and_method_use_the_error_shape(client: httpx.AsyncClient) -> None:
    assert_error_shape(await client.get("/api/v1/nothing-here"), 404, "not-found")
    assert_error_shape(await client.delete("/api/v1/health"), 405, "method-not-allowed")


async def test_unexpected_exception_is_a_bare_500_without_trace() -> None:
    app = create_app(settings())

    @app.get("/boom")
    async def boom() -> None:
        raise RuntimeError("secret internal detail /etc/passwd")

    transport = httpx.ASGITransport(app=app, raise_app_exceptions=False)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
        response = await c.get("/boom")
    body = assert_error_shape(response, 500, "internal")
    assert "secret internal detail" not in response.text
    assert body["details"] is None


async def test_validation_errors_are_422_with_field_messages() -> None:
    app = create_app(settings())

    @app.get("/echo")
    async def echo(count: int) -> int:
        return count

    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
        response = await c.get("/echo", params={"count": "many"})
    body = assert_error_shape(response, 422, "validation")
    assert body["details"][0]["field"] == "query.count"
    assert "integer" in body["details"][0]["message"]


# --- tokens and scopes ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("host", "loopback"),
    [
        ("127.0.0.1", True),
        ("::1", True),
        ("localhost", True),
        ("0.0.0.0", False),
        ("192.168.1.5", False),
        ("lab-pc", False),
    ],
)
def test_loopback_detection(host: str, loopback: bool) -> None:
    assert is_loopback(host) is loopback


def test_scopes_of_tokens() -> None:
    auth = Authenticator(settings(host="0.0.0.0").api)
    assert auth.anonymous_read is False
    assert auth.scopes_of(CONTROL) == {"read", "control"}
    assert auth.scopes_of(READ) == {"read"}
    assert auth.scopes_of(CONTROL[:-1]) is None
    assert auth.scopes_of(CONTROL + "x") is None
    auth.require(READ, "read")
    auth.require(CONTROL, "control")
    for token, scope, status in [
        (None, "read", 401),
        (None, "control", 401),
        ("guess", "read", 401),
        (READ, "control", 403),
    ]:
        with pytest.raises(AuthError) as caught:
            auth.require(token, scope)  # type: ignore[arg-type]
        assert caught.value.status == status


def test_anonymous_read_defaults_to_loopback_only_and_can_be_set() -> None:
    assert Authenticator(settings(host="127.0.0.1").api).anonymous_read is True
    assert Authenticator(settings(host="0.0.0.0").api).anonymous_read is False
    assert Authenticator(settings(host="0.0.0.0", anonymous_read=True).api).anonymous_read
    assert not Authenticator(settings(host="127.0.0.1", anonymous_read=False).api).anonymous_read


def test_no_control_token_configured_means_no_control() -> None:
    auth = Authenticator(Settings().api)
    with pytest.raises(AuthError) as caught:
        auth.require("", "control")
    assert caught.value.status == 401


async def test_reads_need_a_token_off_loopback() -> None:
    app = create_app(settings(host="0.0.0.0"))
    async with httpx.AsyncClient(
        transport=httpx.ASGITransport(app=app), base_url="http://127.0.0.1"
    ) as c:
        assert_error_shape(await c.get("/api/v1/config"), 401, "unauthorized")
        assert_error_shape(
            await c.get("/api/v1/config", headers=bearer("nope")), 401, "unauthorized"
        )
        assert (await c.get("/api/v1/config", headers=bearer(READ))).status_code == 200
        assert (await c.get("/api/v1/config", headers=bearer(CONTROL))).status_code == 200
        # liveness needs no token (health checks, Docker HEALTHCHECK)
        assert (await c.get("/api/v1/health")).status_code == 200


async def test_control_needs_the_control_scope(client: httpx.AsyncClient) -> None:
    robot_stop = "/api/v1/robot/stop"
    response = await client.post(robot_stop)
    assert_error_shape(response, 401, "unauthorized")
    assert response.headers["WWW-Authenticate"] == "Bearer"
    assert_error_shape(await client.post(robot_stop, headers=bearer(READ)), 403, "forbidden")
    # the control token passes authorisation; with no daemon the route then answers 503
    assert_error_shape(await client.post(robot_stop, headers=bearer(CONTROL)), 503, "unavailable")


# --- rate limits ------------------------------------------------------------------------


def test_rate_limiter_is_a_token_bucket() -> None:
    now = [0.0]
    limiter = RateLimiter(rate_per_s=2.0, burst=5, clock=lambda: now[0])
    assert [limiter.acquire("a") for _ in range(5)] == [None] * 5
    wait = limiter.acquire("a")
    assert wait == pytest.approx(0.5)  # one token takes 1 / rate
    assert limiter.acquire("b") is None  # per client
    now[0] = 1.0  # 2 tokens back
    assert limiter.acquire("a") is None
    assert limiter.acquire("a") is None
    assert limiter.acquire("a") is not None
    now[0] = 100.0  # never more than the burst
    assert sum(limiter.acquire("a") is None for _ in range(10)) == 5


async def test_control_requests_beyond_the_limit_get_429() -> None:
    """Authenticated control is limited per token; the hold never is."""
    app = create_app(settings(control_rate_per_s=0.001, control_burst=3))
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
        resume = "/api/v1/runs/1/resume"
        statuses = [(await c.post(resume, headers=bearer(CONTROL))).status_code for _ in range(3)]
        assert statuses == [503] * 3  # past the limiter: no daemon in this app
        response = await c.post(resume, headers=bearer(CONTROL))
        body = assert_error_shape(response, 429, "rate-limited")
        assert int(response.headers["Retry-After"]) >= 1
        assert body["details"]["retry_after_s"] > 0
        # the hold is never throttled, however many control requests came before
        for _ in range(5):
            hold = await c.post("/api/v1/robot/stop", headers=bearer(CONTROL))
            assert hold.status_code == 503, hold.text  # reached the route: no daemon here
        # reads are not limited
        assert all([(await c.get("/api/v1/health")).status_code == 200 for _ in range(20)])


async def test_stopping_and_pausing_are_never_rate_limited_for_the_control_token() -> None:
    """Issue 26: 50 of 53 dashboard stops got 429 and held nothing. A run's stop and pause
    hold the robot like /robot/stop: with the control token they always pass the limiter
    and spend nothing of it; other control requests are still limited; without the control
    scope they are refused as before."""
    app = create_app(settings(control_rate_per_s=0.001, control_burst=3))
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
        resume = "/api/v1/runs/1/resume"
        spent = [(await c.post(resume, headers=bearer(CONTROL))).status_code for _ in range(4)]
        assert spent == [503, 503, 503, 429]  # the bucket is empty
        holding = ["/api/v1/runs/1/stop", "/api/v1/runs/1/pause", "/api/v1/robot/stop"]
        statuses = [
            (await c.post(path, headers=bearer(CONTROL))).status_code
            for _ in range(53)
            for path in holding
        ]
        assert statuses == [503] * len(statuses)  # past the limiter: no daemon in this app
        assert (await c.post(resume, headers=bearer(CONTROL))).status_code == 429
        for path in holding:
            assert (await c.post(path, headers=bearer(READ))).status_code == 403
            assert (await c.post(path)).status_code == 401
            assert (await c.get(path, headers=bearer(CONTROL))).status_code == 405


async def test_failed_authentications_never_spend_the_tokens_allowance() -> None:
    """Issue 16: token-less requests used to charge the per-address bucket the operator's hold
    shared. The token is checked first; failures charge nothing."""
    app = create_app(settings(control_rate_per_s=0.001, control_burst=3))
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
        anonymous = [(await c.post("/api/v1/robot/stop")).status_code for _ in range(6)]
        assert anonymous == [401] * 6
        wrong = await c.post("/api/v1/runs/1/pause", headers=bearer("guess"))
        assert_error_shape(wrong, 401, "unauthorized")
        hold = await c.post("/api/v1/robot/stop", headers=bearer(CONTROL))
        assert hold.status_code == 503, hold.text  # authenticated, not limited
        resume = await c.post("/api/v1/runs/1/resume", headers=bearer(CONTROL))
        assert resume.status_code == 503, resume.text  # the token's own bucket is untouched


@pytest.mark.parametrize("header", ["Basic dXNlcjpwYXNz", "Bearer", "Token abc", "bearer"])
async def test_a_non_bearer_authorization_is_refused_like_a_wrong_token(header: str) -> None:
    """Anonymous reads are on (loopback), yet a credential that cannot be checked is a 401."""
    app = create_app(settings())
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as c:
        assert (await c.get("/api/v1/config")).status_code == 200  # anonymous
        response = await c.get("/api/v1/config", headers={"Authorization": header})
        assert_error_shape(response, 401, "unauthorized")
        assert response.headers["WWW-Authenticate"] == "Bearer"


# --- body size --------------------------------------------------------------------------


async def test_oversized_bodies_are_refused_with_413(client: httpx.AsyncClient) -> None:
    big = b"{" + b" " * 70_000 + b"}"
    declared = await client.post(
        "/api/v1/runs", content=big, headers={**bearer(CONTROL), "Content-Type": "application/json"}
    )
    assert_error_shape(declared, 413, "too-large")

    async def chunks() -> AsyncIterator[bytes]:  # no Content-Length: counted as it arrives
        for _ in range(20):
            yield b" " * 8192

    streamed = await client.post(
        "/api/v1/runs",
        content=chunks(),
        headers={**bearer(CONTROL), "Content-Type": "application/json"},
    )
    assert_error_shape(streamed, 413, "too-large")


# --- config and networks ----------------------------------------------------------------


async def test_config_redacts_secrets(client: httpx.AsyncClient) -> None:
    response = await client.get("/api/v1/config")
    assert response.status_code == 200
    assert CONTROL not in response.text and READ not in response.text
    api = response.json()["api"]
    assert api["control_token"] == "<redacted>" and api["read_token"] == "<redacted>"
    assert response.json()["robot"]["baudrate"] == 57600
    app = create_app(Settings())
    async with httpx.AsyncClient(
        transport=httpx.ASGITransport(app=app), base_url="http://127.0.0.1"
    ) as c:
        assert (await c.get("/api/v1/config")).json()["api"]["control_token"] is None


async def test_networks_lists_the_presets(client: httpx.AsyncClient) -> None:
    response = await client.get("/api/v1/networks")
    assert response.status_code == 200
    listed = {n["name"]: n for n in response.json()["networks"]}
    on_disk = {p.stem for p in (CONFIG_DIR / "networks").glob("*.toml")}
    assert set(listed) | {p["name"] for p in response.json()["unreadable"]} == on_disk
    two_link = listed["thesis-two-link"]
    assert two_link["node_count"] == 17  # Table 5.1
    assert two_link["reference_nodes"] == ["2", "16"]
    assert two_link["heater_nodes"] == ["2", "9"]


# --- metrics ----------------------------------------------------------------------------


def _samples(text: str) -> dict[str, float]:
    return {
        sample.name + json.dumps(sample.labels, sort_keys=True): sample.value
        for family in text_string_to_metric_families(text)
        for sample in family.samples
    }


async def test_metrics_use_a_registry_per_app() -> None:
    first, second = create_app(settings()), create_app(settings())  # no duplicate-name error
    context = first.state.context
    context.metrics.observe_step(
        {"lateness_s": 0.0015, "stage_ms_json": json.dumps({"move": 12.0, "centroid": 3.5})},
        new_overruns=2,
    )
    context.metrics.observe_error({"device": "robot", "kind": "timeout"})
    texts = []
    for app in (first, second):
        async with httpx.AsyncClient(
            transport=httpx.ASGITransport(app=app), base_url="http://127.0.0.1"
        ) as c:
            response = await c.get("/metrics")
            assert response.headers["content-type"].startswith("text/plain")
            texts.append(_samples(response.text))
    observed, fresh = texts
    assert observed["thermocomp_steps_total{}"] == 1
    assert observed["thermocomp_overruns_total{}"] == 2
    assert observed['thermocomp_step_lateness_seconds_bucket{"le": "0.001"}'] == 0
    assert observed['thermocomp_step_lateness_seconds_bucket{"le": "0.002"}'] == 1
    assert observed['thermocomp_stage_duration_seconds_sum{"stage": "move"}'] == pytest.approx(
        0.012
    )
    assert observed['thermocomp_device_errors_total{"device": "robot", "kind": "timeout"}'] == 1
    assert fresh["thermocomp_steps_total{}"] == 0


def test_every_metric_is_in_the_metrics_reference() -> None:
    """docs/reference/metrics.md names every metric family /metrics exposes, with its type."""
    page = (CONFIG_DIR.parent / "docs" / "reference" / "metrics.md").read_text()
    metrics = create_app(settings()).state.context.metrics
    for family in metrics.registry.collect():
        name = family.name + ("_total" if family.type == "counter" else "")
        assert f"| `{name}` | {family.type} |" in page, name


async def test_the_stage_budget_comes_from_the_step_event() -> None:
    """A step event's stage times (the record stage's too) and stage ends; a record alone
    keeps its stage_ms_json; nonsense in either is no sample."""
    context = create_app(settings()).state.context
    context.metrics.observe_step(
        {
            "lateness_s": 0.001,
            "stage_ms_json": json.dumps({"move": 12.0}),
            "stage_s": {"model": 0.002, "move": 0.010, "record": 0.003, "ir": math.nan},
            "stage_lateness_s": {"model": 0.003, "move": 0.013, "record": 0.016, "ir": "x"},
            "step_period_s": 0.02,
        }
    )
    samples = {
        (s.name, s.labels.get("stage")): s.value
        for family in context.metrics.registry.collect()
        for s in family.samples
        if "le" not in s.labels
    }
    assert samples[("thermocomp_stage_duration_seconds_sum", "move")] == pytest.approx(0.010)
    assert samples[("thermocomp_stage_duration_seconds_sum", "record")] == pytest.approx(0.003)
    assert samples[("thermocomp_stage_lateness_seconds_sum", "record")] == pytest.approx(0.016)
    assert ("thermocomp_stage_lateness_seconds_count", "ir") not in samples
    assert ("thermocomp_stage_duration_seconds_count", "ir") not in samples
    assert samples[("thermocomp_step_period_seconds", None)] == 0.02


# --- WebSocket fan-out ------------------------------------------------------------------


async def test_a_slow_client_loses_the_oldest_and_is_told_how_many() -> None:
    dropped: list[int] = []
    hub = Hub(queue_size=4, on_drop=dropped.append)
    slow = hub.connect(["steps"])
    other = hub.connect(["state"])
    for step in range(10):
        hub.publish("steps", {"step": step})
    lost, messages = await slow.take()
    assert lost == 6 and sum(dropped) == 6
    assert [json.loads(m)["data"]["step"] for m in messages] == [6, 7, 8, 9]  # newest kept
    assert other.lost == 0 and not hub.subscribed("frames")
    hub.publish("state", {"state": "running"})
    lost, messages = await other.take()
    assert lost == 0 and json.loads(messages[0]) == {"type": "state", "data": {"state": "running"}}
    hub.disconnect(slow)
    hub.publish("steps", {"step": 11})
    assert len(hub) == 1


def test_messages_are_strict_json() -> None:
    safe = json_safe({"a": math.nan, "b": [math.inf, 1.5], "c": {"d": -math.inf}})
    assert json.dumps(safe, allow_nan=False) == '{"a": null, "b": [null, 1.5], "c": {"d": null}}'


async def test_publish_never_waits() -> None:
    hub = Hub(queue_size=2)
    client = hub.connect(["steps"])
    for step in range(1000):  # nobody reads; publish returns each time without awaiting
        hub.publish("steps", {"step": step})
    assert client.lost == 998
    take = asyncio.create_task(client.take())
    lost, messages = await take
    assert (lost, len(messages)) == (998, 2)


# --- thumbnails -------------------------------------------------------------------------


def test_thumbnail_keeps_the_spot_where_the_centroid_says() -> None:
    import base64

    import cv2

    centre = (401.3, 233.6)
    image = render_spot(centre_xy=centre, sigma_px=2.0, rng=np.random.default_rng(3))
    picture = thumbnail(image, max_width_px=240)
    scale = picture["scale"]
    assert scale == math.ceil(752 / 240)
    png = np.frombuffer(base64.b64decode(picture["png_base64"]), dtype=np.uint8)
    small = cv2.imdecode(png, cv2.IMREAD_UNCHANGED)
    assert small.shape == (picture["height"], picture["width"]) == (582 // scale, 752 // scale)
    assert small.max() == 255 and small.min() == 0  # stretched
    # the brightest block is the one holding the spot's centre: (x + 0.5) / scale
    row, col = np.unravel_index(np.argmax(small), small.shape)
    assert (col, row) == (int((centre[0] + 0.5) // scale), int((centre[1] + 0.5) // scale))


@pytest.mark.parametrize("centre", [(401.3, 233.6), (3.2, 578.9)])  # mid-frame, in a corner
def test_the_spot_crop_is_full_resolution_around_the_centroid(
    centre: tuple[float, float],
) -> None:
    import base64

    import cv2

    image = render_spot(centre_xy=centre, sigma_px=2.0, rng=np.random.default_rng(4))
    picture = spot_crop(image, centre)
    size, x0, y0 = picture["crop_size_px"], picture["crop_x0_px"], picture["crop_y0_px"]
    assert size == CROP_FRAME_PX and 0 <= x0 <= 752 - size and 0 <= y0 <= 582 - size
    crop = cv2.imdecode(
        np.frombuffer(base64.b64decode(picture["crop_png_base64"]), np.uint8),
        cv2.IMREAD_UNCHANGED,
    )
    assert crop.shape == (size, size) and crop.min() == 0 and crop.max() == 255  # stretched
    window = image[y0 : y0 + size, x0 : x0 + size]
    assert (picture["crop_low"], picture["crop_high"]) == (window.min(), window.max())
    # the brightest crop pixel is the frame's brightest pixel of the window, one to one
    row, col = np.unravel_index(np.argmax(crop), crop.shape)
    assert image[y0 + row, x0 + col] == window.max()
    assert abs(x0 + col - centre[0]) <= 1 and abs(y0 + row - centre[1]) <= 1


def test_every_issue_route_is_in_the_openapi_description() -> None:
    paths = set(create_app(settings()).openapi()["paths"])
    for path in [
        "/api/v1/health",
        "/api/v1/state",
        "/api/v1/runs",
        "/api/v1/runs/{run_id}",
        "/api/v1/runs/{run_id}/pause",
        "/api/v1/runs/{run_id}/resume",
        "/api/v1/runs/{run_id}/stop",
        "/api/v1/robot/stop",
        "/api/v1/runs/{run_id}/steps",
        "/api/v1/runs/{run_id}/report",
        "/api/v1/runs/{run_id}/frames/{step}",
        "/api/v1/config",
        "/api/v1/networks",
        "/api/v1/errors",
        "/metrics",
    ]:
        assert path in paths


# --- API description --------------------------------------------------------------------


async def test_docs_page_works_offline(client: httpx.AsyncClient) -> None:
    """/docs must not depend on a CDN: every script and stylesheet is served by the daemon."""
    page = await client.get("/docs")
    assert page.status_code == 200
    assert "http://" not in page.text and "https://" not in page.text
    assets = [
        "/static/vendor/swagger-ui/swagger-ui-bundle.js",
        "/static/vendor/swagger-ui/swagger-ui.css",
    ]
    for asset in assets:
        assert asset in page.text
        assert (await client.get(asset)).status_code == 200
    assert (await client.get("/openapi.json")).json()["info"]["title"] == "thermocomp"
