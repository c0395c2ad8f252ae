"""``/api/v1/ws``: the daemon's events as JSON messages, to a subset a client subscribes to.

Before the handshake is accepted: the Host must be allowed (api/middleware.py Gate), the Origin
(when a browser sends one) must be of an allowed host or in ``api.allowed_origins``; the token
must grant ``read``; the client count must be below ``api.ws_max_clients``. A refusal is an
HTTP 400/401/403 with the usual error body.

The token comes in ``Authorization: Bearer <token>`` or, from a browser (which cannot set that
header on a WebSocket), as the subprotocols ``thermocomp.v1, bearer.<base64url(token)>``;
never in the URL, which servers and proxies log.

Messages to the client: ``{"type": "step"|"state"|"error"|"frame"|"lost"|"hello"|"invalid",
"data": ...}``; ``lost`` says how many messages a slow client's queue dropped. Messages from
the client (at most ``api.ws_max_message_bytes``): ``{"subscribe": ["steps", "state"]}`` or
``{"ping": any}``. A larger message closes the connection with 1009, repeated invalid ones
with 1008.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import logging
from typing import Any

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from starlette.websockets import WebSocketState

from api.broadcast import TOPICS, ClientQueue, Topic, encode
from api.deps import ApiContext, context_of
from api.errors import ErrorBody, error_response
from api.security import AuthError, parse_authorization

logger = logging.getLogger(__name__)

router = APIRouter(tags=["websocket"])

DEFAULT_TOPICS: tuple[Topic, ...] = ("steps", "state", "errors")
MAX_INVALID_MESSAGES = 10
CLOSE_POLICY_VIOLATION = 1008
CLOSE_TOO_BIG = 1009
#: Subprotocols a browser offers: ours, and the token (base64url, so any token is a valid
#: subprotocol name).
PROTOCOL = "thermocomp.v1"
BEARER_PROTOCOL_PREFIX = "bearer."


def parse_topics(raw: object) -> tuple[Topic, ...] | None:
    """Topics from ``"steps,state"`` or ``["steps", "state"]``; None when any is unknown."""
    items = raw.split(",") if isinstance(raw, str) else raw
    if not isinstance(items, list | tuple):
        return None
    topics: list[Topic] = []
    for item in items:
        name = str(item).strip()
        if not name:
            continue
        match = next((t for t in TOPICS if t == name), None)
        if match is None:
            return None
        topics.append(match)
    return tuple(topics)


def origin_allowed(websocket: WebSocket, context: ApiContext) -> bool:
    """No Origin (not a browser) passes; a browser's must be of an allowed host or listed in
    ``api.allowed_origins``. Never compared with the request's own Host: a rebinding page
    sets both (Host = Origin = evil.example)."""
    origin = websocket.headers.get("origin")
    if origin is None:
        return True
    return context.hosts.allows_origin(origin, context.settings.api.allowed_origins)


async def _refuse(websocket: WebSocket, status: int, kind: str, message: str) -> None:
    """Refuse the handshake with an HTTP status and the error body when the server can
    (the ASGI denial-response extension), else with a plain close (HTTP 403)."""
    context = context_of(websocket)
    context.metrics.websocket_refused.labels(reason=kind).inc()
    if "websocket.http.response" in websocket.scope.get("extensions", {}):
        await websocket.send_denial_response(error_response(status, kind, message))
    else:
        await websocket.close(code=CLOSE_POLICY_VIOLATION, reason=message[:120])


def _token(websocket: WebSocket) -> str | None:
    """The presented token; None without any; AuthError for a non-Bearer Authorization."""
    header = websocket.headers.get("authorization")
    if header is not None:
        return parse_authorization(header)
    for protocol in websocket.scope.get("subprotocols", []):
        if protocol.startswith(BEARER_PROTOCOL_PREFIX):
            encoded = protocol.removeprefix(BEARER_PROTOCOL_PREFIX)
            try:
                return base64.urlsafe_b64decode(encoded + "=" * (-len(encoded) % 4)).decode()
            except (ValueError, UnicodeDecodeError):
                return ""  # presented but unreadable: an unknown token, not anonymous
    return None


@router.websocket("/ws")
async def stream(websocket: WebSocket) -> None:
    context = context_of(websocket)
    api = context.settings.api
    if not origin_allowed(websocket, context):
        await _refuse(websocket, 403, "forbidden-origin", "this Origin may not open the stream")
        return
    try:
        context.auth.require(_token(websocket), "read")
    except AuthError as err:
        await _refuse(websocket, err.status, err.kind, err.message)
        return
    topics = parse_topics(websocket.query_params.get("topics", ",".join(DEFAULT_TOPICS)))
    if topics is None:
        await _refuse(websocket, 400, "bad-request", f"topics must be among {', '.join(TOPICS)}")
        return
    if len(context.hub) >= api.ws_max_clients:
        await _refuse(websocket, 503, "too-many-clients", "too many WebSocket clients")
        return
    # the slot is taken before the handshake's await, so concurrent clients cannot overbook
    client = context.hub.connect(topics)
    context.metrics.websocket_clients.inc()
    sender: asyncio.Task[None] | None = None
    try:
        subprotocols = websocket.scope.get("subprotocols", [])
        await websocket.accept(subprotocol=PROTOCOL if PROTOCOL in subprotocols else None)
        # everything goes through the queue, so only the sender ever writes (in order)
        client.offer(encode("hello", _hello(context, client)))
        sender = asyncio.create_task(_send_loop(websocket, client), name="ws-sender")
        await _receive_loop(websocket, context, client)
    except WebSocketDisconnect:
        pass
    finally:
        context.hub.disconnect(client)
        context.metrics.websocket_clients.dec()
        if sender is not None:
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await sender


def _hello(context: ApiContext, client: ClientQueue) -> dict[str, Any]:
    """The first message: what the client subscribed to, and the state now (so a dashboard
    needs no separate request to start)."""
    daemon = context.service
    return {
        "topics": sorted(client.topics),
        "queue_messages": context.settings.api.ws_queue_messages,
        "state": None if daemon is None else daemon.snapshot(),
    }


async def _send_loop(websocket: WebSocket, client: ClientQueue) -> None:
    """Send what the client's queue holds; tell it first how many messages it lost."""
    while True:
        lost, messages = await client.take()
        if lost:
            await websocket.send_text(encode("lost", {"count": lost}))
        for text in messages:
            await websocket.send_text(text)


async def _receive_loop(websocket: WebSocket, context: ApiContext, client: ClientQueue) -> None:
    limit = context.settings.api.ws_max_message_bytes
    invalid = 0
    while True:
        message = await websocket.receive()
        if message["type"] == "websocket.disconnect":
            raise WebSocketDisconnect(message.get("code", 1000))
        raw = message.get("text")
        size = len(raw.encode()) if raw is not None else len(message.get("bytes") or b"")
        if size > limit:
            await _close(websocket, CLOSE_TOO_BIG, f"message over {limit} bytes")
            return
        reply = _handle(raw, client)
        if reply is not None:
            invalid += 1
            if invalid > MAX_INVALID_MESSAGES:
                await _close(websocket, CLOSE_POLICY_VIOLATION, "too many invalid messages")
                return
            client.offer(
                encode(
                    "invalid", ErrorBody(status=400, kind="bad-request", message=reply).model_dump()
                )
            )


def _handle(raw: str | None, client: ClientQueue) -> str | None:
    """Apply one client message; return why it is invalid, or None."""
    try:
        request = json.loads(raw) if raw is not None else None
    except ValueError:
        return "not JSON"
    if not isinstance(request, dict):
        return 'expected an object such as {"subscribe": ["steps"]}'
    if "subscribe" in request:
        topics = parse_topics(request["subscribe"])
        if topics is None:
            return f"topics must be among {', '.join(TOPICS)}"
        client.topics = frozenset(topics)
        client.offer(encode("subscribed", {"topics": sorted(client.topics)}))
        return None
    if "ping" in request:
        client.offer(encode("pong", request["ping"]))
        return None
    return "unknown request"


async def _close(websocket: WebSocket, code: int, reason: str) -> None:
    if websocket.application_state is WebSocketState.CONNECTED:
        await websocket.close(code=code, reason=reason)
