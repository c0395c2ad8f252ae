"""Who may do what: bearer tokens with the scopes ``read`` and ``control``, and rate limits.

A control token also grants ``read``. Tokens come from the settings (``api.control_token``,
``api.read_token``, usually given in the environment) and are compared in constant time with
every configured token, so neither a token's prefix nor which scope it has shows in the timing.
Anonymous reads are allowed when ``api.anonymous_read`` says so; left unset, only when the
server is bound to a loopback address (nobody else can reach it).
"""

from __future__ import annotations

import hmac
import ipaddress
import math
import time
from collections.abc import Callable
from typing import Literal

from config.settings import ApiSettings

Scope = Literal["read", "control"]

#: Host names that only this machine can reach.
_LOOPBACK_NAMES = frozenset({"localhost", "localhost.localdomain", "ip6-localhost"})


def is_loopback(host: str) -> bool:
    if host.lower() in _LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


class AuthError(Exception):
    """A request without the needed scope; ``status`` is 401 (who are you) or 403 (not you)."""

    def __init__(self, status: Literal[401, 403], kind: str, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.kind = kind
        self.message = message


class Authenticator:
    """Decides whether a presented token (or none) grants a scope."""

    def __init__(self, api: ApiSettings) -> None:
        self._tokens: list[tuple[bytes, frozenset[Scope]]] = []
        if api.control_token:
            self._tokens.append((api.control_token.encode(), frozenset({"read", "control"})))
        if api.read_token:
            self._tokens.append((api.read_token.encode(), frozenset({"read"})))
        self.anonymous_read = (
            api.anonymous_read if api.anonymous_read is not None else is_loopback(api.host)
        )

    def scopes_of(self, token: str) -> frozenset[Scope] | None:
        """The scopes of ``token``, or None when it is no configured token."""
        presented = token.encode()
        granted: frozenset[Scope] | None = None
        for known, scopes in self._tokens:  # no early exit: same work whichever matches
            if hmac.compare_digest(presented, known):
                granted = scopes
        return granted

    def require(self, token: str | None, scope: Scope) -> None:
        """Return when ``token`` (None: no credentials) grants ``scope``; else raise."""
        if token is None:
            if scope == "read" and self.anonymous_read:
                return
            raise AuthError(401, "unauthorized", f"a bearer token with the {scope} scope is needed")
        scopes = self.scopes_of(token)
        if scopes is None:
            raise AuthError(401, "unauthorized", "unknown token")
        if scope not in scopes:
            raise AuthError(403, "forbidden", f"this token does not have the {scope} scope")


class RateLimiter:
    """A token bucket per client: ``burst`` requests at once, then ``rate_per_s`` on average.

    Memory stays bounded: buckets that have refilled completely carry no information and are
    dropped once there are many clients.
    """

    MAX_CLIENTS = 1024

    def __init__(
        self, rate_per_s: float, burst: int, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.rate_per_s = rate_per_s
        self.burst = burst
        self._clock = clock
        self._buckets: dict[str, tuple[float, float]] = {}  # client -> (tokens, at time)

    def acquire(self, client: str) -> float | None:
        """Take one request for ``client``: None when allowed, else seconds to wait."""
        now = self._clock()
        tokens, since = self._buckets.get(client, (float(self.burst), now))
        tokens = min(float(self.burst), tokens + (now - since) * self.rate_per_s)
        if tokens < 1.0:
            self._buckets[client] = (tokens, now)
            return (1.0 - tokens) / self.rate_per_s
        self._buckets[client] = (tokens - 1.0, now)
        if len(self._buckets) > self.MAX_CLIENTS:
            self._forget_full(now)
        return None

    def _forget_full(self, now: float) -> None:
        full_after = self.burst / self.rate_per_s
        for client, (_, since) in list(self._buckets.items()):
            if now - since >= full_after:
                del self._buckets[client]


def retry_after_header(wait_s: float) -> dict[str, str]:
    return {"Retry-After": str(max(1, math.ceil(wait_s)))}
