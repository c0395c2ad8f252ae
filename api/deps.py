"""Request dependencies: what a route may ask for, resolved from the application's state.

Nothing here is module-level state: :func:`api.app.create_app` puts one :class:`ApiContext` on
``app.state.context`` and every dependency reads it from the request's application, so two
applications in one process (as in the tests) never share anything.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Annotated, Any

from fastapi import Depends, Request, WebSocket

from api.broadcast import Hub
from api.errors import ApiError
from api.metrics import ApiMetrics
from api.security import (
    Authenticator,
    AuthError,
    HostAllowList,
    RateLimiter,
    Scope,
    parse_authorization,
    retry_after_header,
)
from config import Settings
from daemon.service import Daemon


@dataclass
class ApiContext:
    """Everything the routes of one application share."""

    settings: Settings
    auth: Authenticator
    control_limiter: RateLimiter  # per token: authenticated control requests
    hosts: HostAllowList
    hub: Hub
    metrics: ApiMetrics
    service: Daemon | None = None  # the daemon while the application runs
    event_count: int = 0  # daemon events seen: a cached answer older than the last is stale
    extras: dict[str, Any] = field(default_factory=dict)


def context_of(request: Request | WebSocket) -> ApiContext:
    context: ApiContext = request.app.state.context
    return context


# Every dependency is ``async def``: FastAPI runs a plain ``def`` dependency in the thread
# pool, and a request that crosses it twice cost /state three quarters of its throughput
# (issue 16). None of these blocks.


async def get_context(request: Request) -> ApiContext:
    return context_of(request)


async def get_settings(request: Request) -> Settings:
    """The settings the application was built with (never a module-level global)."""
    return context_of(request).settings


async def get_daemon(request: Request) -> Daemon:
    """The running daemon; 503 while there is none (starting up, shutting down)."""
    daemon = context_of(request).service
    if daemon is None:
        raise ApiError(503, "unavailable", "the daemon is not running")
    return daemon


ContextDep = Annotated[ApiContext, Depends(get_context)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
DaemonDep = Annotated[Daemon, Depends(get_daemon)]

#: Every request that holds the robot: the hold itself (``POST /robot/stop``, the one request
#: that must always get through, issue 16), and a run's stop and pause (both hold the robot).
#: From a control token they are never rate-limited (issue 26: 50 of 53 dashboard stops got
#: 429 and held nothing) and get in beyond the connection cap (api/connections.py).
_HOLDING_PATH = re.compile(r"/api/v1/(?:robot/stop|runs/[^/]+/(?:stop|pause))")


def holds_robot(method: str, path: str) -> bool:
    """Whether ``method path`` is a request that holds the robot."""
    return method == "POST" and _HOLDING_PATH.fullmatch(path) is not None


def grants_control(context: ApiContext, authorization: str | None) -> bool:
    """Whether an ``Authorization`` header value carries the control scope."""
    try:
        token = parse_authorization(authorization)
        context.auth.require(token, "control")
    except AuthError:
        return False
    return True


def _auth_failed(err: AuthError) -> ApiError:
    return ApiError(err.status, err.kind, err.message, headers={"WWW-Authenticate": "Bearer"})


def _rate_limited(wait_s: float, what: str) -> ApiError:
    return ApiError(
        429,
        "rate-limited",
        f"too many {what}; retry later",
        {"retry_after_s": round(wait_s, 3)},
        headers=retry_after_header(wait_s),
    )


def _authenticate(context: ApiContext, request: Request, scope: Scope) -> frozenset[Scope]:
    """The caller's scopes when they grant ``scope``, checked BEFORE any rate accounting, so
    nobody without the token can spend its allowance (issue 16: token-less requests charged
    the per-address bucket the operator's hold shared). Failures are not rate-limited: a
    limit a valid token skips cannot slow guessing, and one it obeys lets anyone on the
    operator's address block the hold; guessing a long random token (docs/reference/api.md: openssl
    rand) compared in constant time is hopeless anyway."""
    try:
        token = parse_authorization(request.headers.get("authorization"))
        return context.auth.require(token, scope)
    except AuthError as err:
        raise _auth_failed(err) from err


def require_read_now(context: ApiContext, request: Request) -> None:
    """Reads need the ``read`` scope unless anonymous reads are allowed (raises ApiError)."""
    _authenticate(context, request, "read")


async def require_read(request: Request) -> None:
    """Reads need the ``read`` scope unless anonymous reads are allowed."""
    require_read_now(context_of(request), request)


async def require_control(request: Request) -> None:
    """Control needs the ``control`` scope; then it is rate-limited per token (every client of
    one token shares its allowance, whatever address it comes from). A request that holds the
    robot (:func:`holds_robot`) is never limited and spends nothing: it must get through
    whatever else the token's clients are doing."""
    context = context_of(request)
    _authenticate(context, request, "control")
    if holds_robot(request.method, request.url.path):
        return
    wait_s = context.control_limiter.acquire("control")
    if wait_s is not None:
        raise _rate_limited(wait_s, "control requests")


ReadAccess = Depends(require_read)
ControlAccess = Depends(require_control)
