"""Issue 16's findings, each reproduced the way the drill made it, through a real server:
the token-less flood that starved the hold, slowloris sockets, DNS rebinding (Host and
WebSocket Origin), missing security headers, HEAD/OPTIONS, the OpenAPI security."""

from __future__ import annotations

import asyncio
import socket
import threading
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import httpx
import pytest
import uvicorn
from websockets.asyncio.client import connect
from websockets.exceptions import InvalidStatus

from api.app import create_app
from api.serve import connection_guard, server_config
from config import Settings
from tests.helpers import running_server

CONTROL = "control-token-0123456789"
READ = "read-token-0123456789"


def hardened_settings(**api: Any) -> Settings:
    return Settings.model_validate(
        {"api": {"control_token": CONTROL, "read_token": READ, "port": 0, **api}}
    )


@asynccontextmanager
async def guarded_server(settings: Settings) -> AsyncIterator[tuple[str, int]]:
    """The application (no daemon) under the daemon's own uvicorn configuration
    (api.serve.server_config: connection cap, request deadline) on a free loopback port."""
    app = create_app(settings)
    guard = connection_guard(settings, app.state.context)
    server = uvicorn.Server(server_config(settings, app, guard))
    task = asyncio.create_task(server.serve(), name="uvicorn")
    try:
        while not server.started:
            if task.done():
                task.result()
                raise AssertionError("the server did not start")
            await asyncio.sleep(0.01)
        port: int = server.servers[0].sockets[0].getsockname()[1]
        yield "127.0.0.1", port
    finally:
        server.should_exit = True
        await task
        guard.close()


def _read_until_closed(sock: socket.socket, limit_s: float) -> float:
    """Seconds until the server closes ``sock`` (recv gives EOF or a reset), at most limit_s."""
    start = time.monotonic()
    sock.settimeout(limit_s)
    try:
        while sock.recv(4096):
            pass
    except TimeoutError:
        return float("inf")
    except ConnectionResetError:
        pass
    return time.monotonic() - start


# --- the hold is never starved ------------------------------------------------------------


@pytest.mark.slow
def test_a_token_less_flood_never_throttles_the_operators_hold() -> None:
    """The drill: 5 token-less POST /robot/stop per second from one address made the
    operator's hold answer 429 six times out of ten. Now the token is checked before any
    rate accounting, and the hold with the control token is never limited."""
    env = {
        "THERMOCOMP_API__CONTROL_TOKEN": CONTROL,
        "THERMOCOMP_API__CONTROL_RATE_PER_S": "1",
        "THERMOCOMP_API__CONTROL_BURST": "2",
    }
    with running_server(["--config", "config/sim.toml"], env=env) as base:
        hold = f"{base}/api/v1/robot/stop"
        stop = threading.Event()
        anonymous: list[int] = []

        def flood() -> None:
            with httpx.Client(timeout=10) as client:
                while not stop.is_set():
                    anonymous.append(client.post(hold).status_code)

        flooder = threading.Thread(target=flood)
        flooder.start()
        try:
            with httpx.Client(timeout=30) as client:
                while len(anonymous) < 10:  # the flood has spent the failure bucket
                    time.sleep(0.01)
                statuses = [
                    client.post(hold, headers={"Authorization": f"Bearer {CONTROL}"}).status_code
                    for _ in range(10)
                ]
        finally:
            stop.set()
            flooder.join()
    assert statuses == [200] * 10
    assert set(anonymous) == {401}


# --- bounded connections ------------------------------------------------------------------


async def test_slowloris_and_silent_sockets_are_dropped_within_the_request_timeout() -> None:
    settings = hardened_settings(request_timeout_s=1.0)
    async with guarded_server(settings) as (host, port):
        silent = socket.create_connection((host, port))
        trickling = socket.create_connection((host, port))
        trickling.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-a: ")
        waited = await asyncio.gather(
            asyncio.to_thread(_read_until_closed, silent, 10.0),
            asyncio.to_thread(_read_until_closed, trickling, 10.0),
        )
        silent.close()
        trickling.close()
        assert all(0.5 < seconds < 4.0 for seconds in waited), waited
        # a complete request on a fresh connection is served as usual
        async with httpx.AsyncClient(base_url=f"http://{host}:{port}") as client:
            assert (await client.get("/api/v1/health")).status_code == 200


# --- DNS rebinding --------------------------------------------------------------------------


async def test_a_rebound_host_is_refused_and_the_real_ones_served() -> None:
    settings = hardened_settings(allowed_hosts=("lab-pc.example.org",))
    async with (
        guarded_server(settings) as (host, port),
        httpx.AsyncClient(base_url=f"http://{host}:{port}") as client,
    ):
        rebound = await client.get("/api/v1/config", headers={"Host": "evil.example"})
        assert rebound.status_code == 400 and rebound.json()["kind"] == "forbidden-host"
        assert "api.allowed_hosts" in rebound.json()["message"]
        for name in (f"127.0.0.1:{port}", f"localhost:{port}", "lab-pc.example.org:8000"):
            response = await client.get("/api/v1/config", headers={"Host": name})
            assert response.status_code == 200, (name, response.text)


async def test_websocket_origin_is_checked_against_the_allow_list_not_the_host() -> None:
    settings = hardened_settings()
    async with guarded_server(settings) as (host, port):
        uri = f"ws://{host}:{port}/api/v1/ws"
        auth = {"Authorization": f"Bearer {READ}"}
        # the drill: Host = Origin = evil.example was let in
        status_line = await asyncio.to_thread(_raw_handshake, host, port, "evil.example")
        assert status_line.startswith(b"HTTP/1.1 400"), status_line
        # a page of another site talking to the real name: its Origin is refused
        with pytest.raises(InvalidStatus) as caught:
            async with connect(uri, additional_headers=auth, origin="http://evil.example"):
                pass
        assert caught.value.response.status_code == 403
        async with connect(uri, additional_headers=auth, origin=f"http://localhost:{port}") as ws:
            assert "hello" in await asyncio.wait_for(ws.recv(), 10)


def _raw_handshake(host: str, port: int, name: str) -> bytes:
    """A WebSocket handshake whose Host and Origin are both ``name``; the status line."""
    with socket.create_connection((host, port), timeout=10) as sock:
        sock.sendall(
            (
                f"GET /api/v1/ws HTTP/1.1\r\nHost: {name}\r\nOrigin: http://{name}\r\n"
                "Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\n"
                f"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                f"Authorization: Bearer {READ}\r\n\r\n"
            ).encode()
        )
        return sock.recv(4096).split(b"\r\n", 1)[0]


# --- headers, methods, description ----------------------------------------------------------


async def test_security_headers_on_every_response() -> None:
    settings = hardened_settings()
    async with (
        guarded_server(settings) as (host, port),
        httpx.AsyncClient(base_url=f"http://{host}:{port}") as client,
    ):
        for path in ("/", "/docs", "/static/js/app.js", "/api/v1/health", "/api/v1/nothing"):
            response = await client.get(path)
            csp = response.headers["content-security-policy"]
            assert "frame-ancestors 'none'" in csp and "script-src 'self'" in csp, path
            assert "unsafe-inline" not in csp.split("style-src")[0], path  # no inline script
            assert response.headers["x-content-type-options"] == "nosniff", path
            assert response.headers["x-frame-options"] == "DENY", path
        for path in ("/api/v1/health", "/api/v1/config", "/api/v1/nothing"):
            response = await client.get(path)
            assert response.headers["cache-control"] == "no-store", path
        page = (await client.get("/docs")).text
        assert "<script>" not in page  # the Swagger UI starts from a file
        assert (await client.get("/static/swagger-init.js")).status_code == 200


async def test_head_wherever_get_and_options_with_the_real_methods() -> None:
    settings = hardened_settings()
    async with (
        guarded_server(settings) as (host, port),
        httpx.AsyncClient(base_url=f"http://{host}:{port}") as client,
    ):
        for path in ("/docs", "/", "/api/v1/health", "/openapi.json", "/static/js/app.js"):
            get, head = await client.get(path), await client.head(path)
            assert head.status_code == 200, path
            assert head.content == b""
            assert head.headers["content-type"] == get.headers["content-type"], path
        options = await client.options("/api/v1/runs")
        assert options.status_code == 204
        assert set(options.headers["allow"].split(", ")) == {"GET", "HEAD", "POST", "OPTIONS"}
        wrong = await client.delete("/api/v1/runs")
        assert wrong.status_code == 405
        assert "POST" in wrong.headers["allow"] and "GET" in wrong.headers["allow"]
        assert (await client.options("/api/v1/nothing")).status_code == 404


def test_openapi_security_matches_anonymous_reads() -> None:
    def security(settings: Settings) -> dict[str, Any]:
        paths = create_app(settings).openapi()["paths"]
        return {
            "read": paths["/api/v1/runs"]["get"]["security"],
            "control": paths["/api/v1/runs"]["post"]["security"],
            "health": paths["/api/v1/health"]["get"].get("security"),
        }

    loopback = security(hardened_settings())
    assert loopback == {"read": [{"bearer": []}, {}], "control": [{"bearer": []}], "health": None}
    remote = security(hardened_settings(host="0.0.0.0"))
    assert remote["read"] == [{"bearer": []}]


@pytest.mark.slow
def test_422_messages_a_curl_user_understands() -> None:
    env = {"THERMOCOMP_API__CONTROL_TOKEN": CONTROL}
    with (
        running_server(["--config", "config/sim.toml"], env=env) as base,
        httpx.Client(base_url=base, headers={"Authorization": f"Bearer {CONTROL}"}) as client,
    ):
        broken = client.post(
            "/api/v1/runs",
            content=b'{\n  "duration_s": 60,\n  "step_s": ,\n}',
            headers={"Content-Type": "application/json"},
        )
        assert broken.status_code == 422
        message = broken.json()["message"]
        assert message.startswith("the body is not valid JSON: Expecting value"), message
        assert "line 3, column 13" in message
        # curl -d without -H: the body goes as a form
        form = client.post(
            "/api/v1/runs",
            content=b"duration_s=60",
            headers={"Content-Type": "application/x-www-form-urlencoded"},
        )
        assert form.status_code == 422, form.text
        message = form.json()["message"]
        assert "expected a JSON body with Content-Type: application/json" in message
        assert "application/x-www-form-urlencoded" in message
        assert "-H 'Content-Type: application/json'" in message


async def test_polled_state_route_keeps_the_read_checks() -> None:
    """/state is served by a plain route ahead of FastAPI's (api/app.py): the same checks."""
    remote = create_app(hardened_settings(host="0.0.0.0"))
    transport = httpx.ASGITransport(app=remote)
    async with httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1") as client:
        anonymous = await client.get("/api/v1/state")
        assert anonymous.status_code == 401 and anonymous.headers["WWW-Authenticate"] == "Bearer"
        assert anonymous.json()["kind"] == "unauthorized"
        basic = await client.get("/api/v1/state", headers={"Authorization": "Basic eDp5"})
        assert basic.status_code == 401
        read = await client.get("/api/v1/state", headers={"Authorization": f"Bearer {READ}"})
        assert read.status_code == 503 and read.json()["kind"] == "unavailable"  # no daemon
        assert read.headers["cache-control"] == "no-store"
        head = await client.head("/api/v1/state", headers={"Authorization": f"Bearer {READ}"})
        assert head.status_code == 503 and head.content == b""


@pytest.mark.parametrize(
    ("bound", "extra", "host", "allowed"),
    [
        ("127.0.0.1", (), "127.0.0.1:8000", True),
        ("127.0.0.1", (), "localhost", True),
        ("127.0.0.1", (), "[::1]:8000", True),
        ("127.0.0.1", (), "127.0.0.2:8000", True),  # loopback, not a rebindable name
        ("127.0.0.1", (), "evil.example", False),
        ("127.0.0.1", (), "evil.example:8000", False),
        ("127.0.0.1", (), "192.168.1.20:8000", False),  # not where we listen
        ("127.0.0.1", (), None, False),
        ("192.168.1.20", (), "192.168.1.20:8000", True),  # the bound address
        ("0.0.0.0", (), "192.168.1.20:8000", True),  # any address of this machine
        ("0.0.0.0", (), "lab-pc.example.org", False),
        ("0.0.0.0", ("Lab-PC.example.org",), "lab-pc.example.org:8000", True),
        ("0.0.0.0", ("*",), "anything.example", True),  # explicitly anything
    ],
)
def test_host_allow_list(
    bound: str, extra: tuple[str, ...], host: str | None, allowed: bool
) -> None:
    from api.security import HostAllowList

    hosts = HostAllowList(hardened_settings(host=bound, allowed_hosts=extra).api)
    assert hosts.allows(host) is allowed


def test_origins_are_judged_by_the_allow_list() -> None:
    from api.security import HostAllowList

    api = hardened_settings(allowed_origins=("https://dash.example.org",)).api
    hosts = HostAllowList(api)
    assert hosts.allows_origin("http://localhost:8000", api.allowed_origins)
    assert hosts.allows_origin("https://dash.example.org/", api.allowed_origins)
    assert not hosts.allows_origin("http://evil.example", api.allowed_origins)
    assert not hosts.allows_origin("file://localhost", api.allowed_origins)
    assert not hosts.allows_origin("null", api.allowed_origins)
