"""Request dependencies: what a route may ask for, resolved from the application's state.

Nothing here is module-level state: :func:`api.app.create_app` puts one :class:`ApiContext` on
``app.state.context`` and every dependency reads it from the request's application, so two
applications in one process (as in the tests) never share anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any

from fastapi import Depends, Request, WebSocket
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from api.broadcast import Hub
from api.errors import ApiError
from api.metrics import ApiMetrics
from api.security import Authenticator, AuthError, RateLimiter, Scope, retry_after_header
from config import Settings
from daemon.service import Daemon


@dataclass
class ApiContext:
    """Everything the routes of one application share."""

    settings: Settings
    auth: Authenticator
    control_limiter: RateLimiter
    hub: Hub
    metrics: ApiMetrics
    service: Daemon | None = None  # the daemon while the application runs
    event_count: int = 0  # daemon events seen: a cached answer older than the last is stale
    extras: dict[str, Any] = field(default_factory=dict)


def context_of(request: Request | WebSocket) -> ApiContext:
    context: ApiContext = request.app.state.context
    return context


def get_context(request: Request) -> ApiContext:
    return context_of(request)


def get_settings(request: Request) -> Settings:
    """The settings the application was built with (never a module-level global)."""
    return context_of(request).settings


def get_daemon(request: Request) -> Daemon:
    """The running daemon; 503 while there is none (starting up, shutting down)."""
    daemon = context_of(request).service
    if daemon is None:
        raise ApiError(503, "unavailable", "the daemon is not running")
    return daemon


ContextDep = Annotated[ApiContext, Depends(get_context)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
DaemonDep = Annotated[Daemon, Depends(get_daemon)]

_bearer = HTTPBearer(
    auto_error=False,
    description="`Authorization: Bearer <token>`; the control token also grants read.",
)
Credentials = Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]


def _check(
    context: ApiContext, credentials: HTTPAuthorizationCredentials | None, scope: Scope
) -> None:
    try:
        context.auth.require(None if credentials is None else credentials.credentials, scope)
    except AuthError as err:
        raise ApiError(
            err.status, err.kind, err.message, headers={"WWW-Authenticate": "Bearer"}
        ) from err


async def require_read(request: Request, credentials: Credentials) -> None:
    """Reads need the ``read`` scope unless anonymous reads are allowed."""
    _check(context_of(request), credentials, "read")


async def require_control(request: Request, credentials: Credentials) -> None:
    """Control needs the ``control`` scope, and is rate-limited per client address before the
    token is even looked at (so guessing tokens is rate-limited too)."""
    context = context_of(request)
    client = request.client.host if request.client else "unknown"
    wait_s = context.control_limiter.acquire(client)
    if wait_s is not None:
        raise ApiError(
            429,
            "rate-limited",
            "too many control requests; retry later",
            {"retry_after_s": round(wait_s, 3)},
            headers=retry_after_header(wait_s),
        )
    _check(context, credentials, "control")


ReadAccess = Depends(require_read)
ControlAccess = Depends(require_control)
