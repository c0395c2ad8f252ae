"""The API through a real uvicorn server on a free loopback port and a real WebSocket client:
the refusals and bounds of the WebSocket (issue 7 security, issue 10 "refused or bounded")."""

from __future__ import annotations

import asyncio
import base64
import json
import socket
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import pytest
import uvicorn
from fastapi import FastAPI
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidStatus

from api.app import create_app
from config import Settings

CONTROL = "control-token-0123456789"
READ = "read-token-0123456789"


@asynccontextmanager
async def serve(
    app: FastAPI, ws_max_size: int | None = None, send_buffer_bytes: int | None = None
) -> AsyncIterator[str]:
    """Run ``app`` under a real uvicorn server on a free loopback port; yield ``host:port``.

    The server runs in this event loop (its lifespan too) and is shut down cleanly after.
    ``send_buffer_bytes`` fixes the kernel send buffer of the accepted connections (Linux
    inherits it from the listening socket); otherwise loopback autotuning lets the kernel
    absorb megabytes for a client that reads nothing."""
    server = uvicorn.Server(
        uvicorn.Config(
            app,
            host="127.0.0.1",
            port=0,
            log_config=None,
            access_log=False,
            lifespan="on",
            ws_max_size=ws_max_size or 16 * 1024 * 1024,
        )
    )
    task = asyncio.create_task(server.serve(), name="uvicorn")
    try:
        while not server.started:
            if task.done():
                task.result()
                raise AssertionError("the server did not start")
            await asyncio.sleep(0.01)
        listening = server.servers[0].sockets[0]
        if send_buffer_bytes is not None:
            listening.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, send_buffer_bytes)
        port = listening.getsockname()[1]
        yield f"127.0.0.1:{port}"
    finally:
        server.should_exit = True
        await task


def api_settings(**api: Any) -> Settings:
    return Settings.model_validate({"api": {"control_token": CONTROL, "read_token": READ, **api}})


async def refused_status(uri: str, **kwargs: Any) -> tuple[int, dict[str, Any]]:
    with pytest.raises(InvalidStatus) as caught:
        async with connect(uri, **kwargs):
            pass
    response = caught.value.response
    return response.status_code, json.loads(response.body or b"{}")


async def receive_json(ws: ClientConnection, timeout_s: float = 10.0) -> dict[str, Any]:
    message: dict[str, Any] = json.loads(await asyncio.wait_for(ws.recv(), timeout_s))
    return message


def bearer_protocol(token: str) -> str:
    """The subprotocol a browser sends its token in (api/static/js/app.js)."""
    return "bearer." + base64.urlsafe_b64encode(token.encode()).decode().rstrip("=")


async def test_websocket_refusals_happen_before_accept() -> None:
    settings = api_settings(host="0.0.0.0", allowed_origins=["https://lab.example"])
    read_header = {"Authorization": f"Bearer {READ}"}
    async with serve(create_app(settings)) as address:
        uri = f"ws://{address}/api/v1/ws"
        status, body = await refused_status(uri)
        assert (status, body["kind"]) == (401, "unauthorized")
        status, body = await refused_status(uri, additional_headers={"Authorization": "Bearer x"})
        assert (status, body["kind"]) == (401, "unauthorized")
        status, body = await refused_status(
            uri,
            subprotocols=["thermocomp.v1", bearer_protocol("wrong")],  # type: ignore[list-item]
        )
        assert (status, body["kind"]) == (401, "unauthorized")
        status, body = await refused_status(
            uri, additional_headers=read_header, origin="https://evil.example"
        )
        assert (status, body["kind"]) == (403, "forbidden-origin")
        status, body = await refused_status(
            f"{uri}?topics=steps,secrets", additional_headers=read_header
        )
        assert (status, body["kind"]) == (400, "bad-request")
        # the server's own origin, an allow-listed one, and no origin (not a browser) pass
        for origin in (f"http://{address}", "https://lab.example", None):
            async with connect(uri, additional_headers=read_header, origin=origin) as ws:  # type: ignore[arg-type]
                hello = await receive_json(ws)
                assert hello["type"] == "hello"
                assert hello["data"]["topics"] == ["errors", "state", "steps"]
        # a browser's way: the token as a subprotocol, ours chosen by the server
        protocols = ["thermocomp.v1", bearer_protocol(READ)]
        async with connect(uri, subprotocols=protocols, origin=f"http://{address}") as ws:  # type: ignore[arg-type]
            assert ws.subprotocol == "thermocomp.v1"
            assert (await receive_json(ws))["type"] == "hello"


async def test_websocket_message_limits_and_subscriptions() -> None:
    settings = api_settings(ws_max_message_bytes=256)
    app = create_app(settings)
    async with serve(app, ws_max_size=settings.api.ws_max_message_bytes) as address:
        uri = f"ws://{address}/api/v1/ws?topics=state"
        async with connect(uri) as ws:  # anonymous read: bound to loopback
            assert (await receive_json(ws))["data"]["topics"] == ["state"]
            await ws.send(json.dumps({"subscribe": ["steps", "errors"]}))
            assert (await receive_json(ws)) == {
                "type": "subscribed",
                "data": {"topics": ["errors", "steps"]},
            }
            hub = app.state.context.hub
            hub.publish("steps", {"step": 1})
            hub.publish("state", {"state": "running"})  # no longer subscribed
            hub.publish("errors", {"message": "x"})
            assert (await receive_json(ws))["type"] == "step"
            assert (await receive_json(ws))["type"] == "error"
            await ws.send(json.dumps({"ping": 7}))
            assert await receive_json(ws) == {"type": "pong", "data": 7}
            await ws.send(json.dumps({"subscribe": ["nonsense"]}))
            invalid = await receive_json(ws)
            assert invalid["type"] == "invalid" and invalid["data"]["status"] == 400
            await ws.send("x" * 1000)  # over the limit: the connection is closed
            with pytest.raises(ConnectionClosed) as closed:
                await asyncio.wait_for(ws.recv(), 10)
            assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009


async def test_websocket_floods_are_bounded() -> None:
    settings = api_settings(ws_max_clients=3)
    app = create_app(settings)
    async with serve(app) as address:
        uri = f"ws://{address}/api/v1/ws"
        async with connect(uri) as a, connect(uri) as b, connect(uri) as c:
            for ws in (a, b, c):
                await receive_json(ws)
            status, body = await refused_status(uri)
            assert (status, body["kind"]) == (503, "too-many-clients")
            for _ in range(50):  # a flood of invalid messages ends the connection
                try:
                    await a.send("not json")
                except ConnectionClosed:
                    break
            with pytest.raises(ConnectionClosed) as closed:
                while True:
                    await asyncio.wait_for(a.recv(), 10)
            assert closed.value.rcvd is not None and closed.value.rcvd.code == 1008
        # disconnects free the slots and the gauge follows
        for _ in range(100):
            if len(app.state.context.hub) == 0:
                break
            await asyncio.sleep(0.02)
        assert len(app.state.context.hub) == 0
        async with connect(uri) as again:
            assert (await receive_json(again))["type"] == "hello"
