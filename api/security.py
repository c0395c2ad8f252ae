"""Who may do what: bearer tokens with the scopes ``read`` and ``control``, and rate limits.

A control token also grants ``read``. Tokens come from the settings (``api.control_token``,
``api.read_token``, usually given in the environment) and are compared in constant time with
every configured token, so neither a token's prefix nor which scope it has shows in the timing.
Anonymous reads are allowed when ``api.anonymous_read`` says so; left unset, only when the
server is bound to a loopback address (nobody else can reach it).

A server on loopback without a configured control token makes one (:func:`local_control_token`):
a random secret kept in the data directory (mode 0600) and printed at start-up as the
dashboard's address with ``?token=`` (Jupyter's convention), so the dashboard can start, stop
and hold from the first ``make run``. Control without any token on loopback was refused as the
default: every local user and every web page the browser opens can reach 127.0.0.1 (a plain
POST needs no CORS pre-flight), and a daemon that moves a robot must not be one of them's
(docs/tutorials/dashboard.md).
"""

from __future__ import annotations

import errno
import hmac
import ipaddress
import math
import os
import secrets
import socket
import stat
import time
from collections.abc import Callable
from pathlib import Path
from typing import Literal
from urllib.parse import urlsplit

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


def parse_authorization(header: str | None) -> str | None:
    """The token of ``Authorization: Bearer <token>``; None without the header.

    Any other scheme (``Basic ...``), or a Bearer without a token, is an :class:`AuthError`
    like a wrong token: a credential the server cannot check must not pass as "no
    credentials" (which anonymous reads would accept)."""
    if header is None:
        return None
    scheme, _, value = header.strip().partition(" ")
    if scheme.lower() != "bearer" or not value.strip():
        raise AuthError(401, "unauthorized", "the Authorization header must be `Bearer <token>`")
    return value.strip()


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

    def require(self, token: str | None, scope: Scope) -> frozenset[Scope]:
        """The scopes of ``token`` (None: no credentials; anonymous reads get none) when it
        grants ``scope``; else raise."""
        if token is None:
            if scope == "read" and self.anonymous_read:
                return frozenset()
            raise AuthError(401, "unauthorized", f"a bearer token with the {scope} scope is needed")
        scopes = self.scopes_of(token)
        if scopes is None:
            raise AuthError(401, "unauthorized", "unknown token")
        if scope not in scopes:
            raise AuthError(403, "forbidden", f"this token does not have the {scope} scope")
        return scopes


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


#: Addresses a server bound to them listens on every interface of.
_WILDCARD_ADDRESSES = frozenset({"0.0.0.0", "::", ""})


def split_host(value: str) -> str:
    """The host part of a Host header or URL netloc, lower-case, without port or brackets:
    ``"[::1]:8000"`` -> ``"::1"``, ``"Lab-PC:8000"`` -> ``"lab-pc"``."""
    value = value.strip().lower()
    if value.startswith("["):
        return value[1 : value.find("]")] if "]" in value else value[1:]
    if value.count(":") == 1:
        value = value.split(":", 1)[0]
    return value.rstrip(".")


def _is_ip_literal(host: str) -> bool:
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


class HostAllowList:
    """Which ``Host`` headers (and WebSocket ``Origin`` hosts) the API answers.

    DNS rebinding makes a browser send a page's own name (``evil.example``) to an address the
    attacker chose (127.0.0.1): checking the name is what stops it. Allowed: the loopback
    names and addresses, the bound address, ``api.allowed_hosts``; when bound to every
    interface (0.0.0.0, ::) also this machine's host names and any IP literal (a client that
    typed an address resolved no name, so no rebinding happened).
    """

    def __init__(self, api: ApiSettings) -> None:
        bound = split_host(api.host)
        names = set(_LOOPBACK_NAMES) | {"127.0.0.1", "::1"}
        names |= {split_host(host) for host in api.allowed_hosts}
        self.any_host = "*" in names
        self.any_ip = bound in _WILDCARD_ADDRESSES
        if self.any_ip:
            names |= {socket.gethostname().lower(), socket.getfqdn().lower()}
        else:
            names.add(bound)
        self.names = frozenset(names)

    def allows(self, host_header: str | None) -> bool:
        if self.any_host:
            return True
        if not host_header:
            return False
        host = split_host(host_header)
        if host in self.names:
            return True
        if _is_ip_literal(host):
            return self.any_ip or is_loopback(host)
        return False

    def allows_origin(self, origin: str, allowed_origins: tuple[str, ...]) -> bool:
        """A browser's ``Origin``: listed in ``api.allowed_origins``, or an http(s) origin of
        an allowed host -- never compared with the client's own ``Host`` header, which the
        same page controls."""
        if origin.rstrip("/") in {a.rstrip("/") for a in allowed_origins}:
            return True
        parts = urlsplit(origin)
        return parts.scheme in ("http", "https") and self.allows(parts.netloc)


#: The generated control token's file in the data directory (mode 0600).
CONTROL_TOKEN_FILE = "control-token"
#: Random bytes of a generated token (256 bits; URL-safe base64, 43 characters).
CONTROL_TOKEN_BYTES = 32


class TokenFileError(Exception):
    """The token file cannot be read, written, or is readable by other users (one line)."""


def local_control_token(data_dir: Path) -> str:
    """The control token kept in ``data_dir``/control-token, made on first use.

    The file is created with mode 0600 (O_EXCL: two servers starting at once cannot both
    write it). One that other users could read is refused, as ssh refuses such a key: the
    token may have leaked, and only its owner can say so. An empty file gets a new token."""
    path = Path(data_dir) / CONTROL_TOKEN_FILE
    try:
        info = path.stat()
    except FileNotFoundError:
        return _new_token(path)
    except OSError as err:
        raise TokenFileError(f"cannot read {path}: {err.strerror}") from err
    if info.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise TokenFileError(
            f"{path} is readable by other users (mode {stat.S_IMODE(info.st_mode):04o}): "
            f"run `chmod 600 {path}`, or delete it for a new token"
        )
    try:
        token = path.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError) as err:
        raise TokenFileError(f"cannot read {path}: {err}: delete it for a new token") from err
    if not token:
        path.unlink()
        return _new_token(path)
    return token


def _new_token(path: Path) -> str:
    token = secrets.token_urlsafe(CONTROL_TOKEN_BYTES)
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:  # another server made it meanwhile: use that one
        return local_control_token(path.parent)
    except OSError as err:
        reason = "permission denied" if err.errno == errno.EACCES else err.strerror
        raise TokenFileError(f"cannot write {path}: {reason}") from err
    with os.fdopen(fd, "w", encoding="ascii") as file:
        file.write(token + "\n")
    return token


def dashboard_url(host: str, port: int, token: str | None = None) -> str:
    """The dashboard's address; with ``?token=`` the page takes the token and drops it from
    the address bar (api/static/js/api.js)."""
    shown = f"[{host}]" if ":" in host else host
    if host in _WILDCARD_ADDRESSES:
        shown = "127.0.0.1"
    url = f"http://{shown}:{port}/"
    return f"{url}?token={token}" if token else url
