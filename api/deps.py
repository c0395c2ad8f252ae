"""Request dependencies: what a route may ask for, resolved from the application's state.

Nothing here is module-level state: :func:`api.app.create_app` puts one :class:`ApiContext` on
``app.state.context`` and every dependency reads it from the request's application, so two
applications in one process (as in the tests) never share anything.
"""

from __future__ import annotations

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
    #: the exit status a failed start asks for (api/app.py's lifespan): 2 for a bad file or
    #: name, never uvicorn's 3 ("device absent", which systemd retries forever)
    start_failure_status: int | None = None
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

#: The one request that must always get through: holding the robot (issue 16).
HOLD_PATH = "/api/v1/robot/stop"


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
    one token shares its allowance, whatever address it comes from). Holding the robot is
    never limited: it must get through whatever else the token's clients are doing."""
    context = context_of(request)
    _authenticate(context, request, "control")
    if request.url.path == HOLD_PATH:
        return
    wait_s = context.control_limiter.acquire("control")
    if wait_s is not None:
        raise _rate_limited(wait_s, "control requests")


ReadAccess = Depends(require_read)
ControlAccess = Depends(require_control)
