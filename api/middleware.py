"""One plain ASGI layer in front of every request (:class:`Gate`): the Host allow-list, honest
``OPTIONS`` answers, ``HEAD`` wherever ``GET`` is, the request body limit and the security
headers.

One layer, not five: each ASGI layer costs a coroutine and a closure per request, and /state
must serve within 0.7x of the bare stack (issue 16). Plain ASGI (not BaseHTTPMiddleware):
nothing is buffered, streamed exports stay streamed.
"""

from __future__ import annotations

from collections.abc import Iterable

from starlette.responses import Response
from starlette.routing import BaseRoute
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from api.errors import ApiError, error_response
from api.methods import allowed_methods
from api.security import HostAllowList

#: The dashboard's policy: its own scripts, styles and connections only (no inline script or
#: style: static/ has none), frame thumbnails as data: URLs, never framed by another page.
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
    "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; "
    "frame-ancestors 'none'"
)
#: Swagger UI (/docs, vendored) sets inline styles from its bundle; its script stays 'self'.
DOCS_CONTENT_SECURITY_POLICY = CONTENT_SECURITY_POLICY.replace(
    "style-src 'self'", "style-src 'self' 'unsafe-inline'"
)
_COMMON_HEADERS = [
    (b"x-content-type-options", b"nosniff"),
    (b"x-frame-options", b"DENY"),
    (b"referrer-policy", b"no-referrer"),
    (b"cross-origin-opener-policy", b"same-origin"),
]
_PAGE_HEADERS = [(b"content-security-policy", CONTENT_SECURITY_POLICY.encode()), *_COMMON_HEADERS]
_DOCS_HEADERS = [
    (b"content-security-policy", DOCS_CONTENT_SECURITY_POLICY.encode()),
    *_COMMON_HEADERS,
]
_NO_STORE = (b"cache-control", b"no-store")
#: Methods that may carry a body (the only ones whose body is counted).
_BODY_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})


class Gate:
    """Before the application:

    - a request or WebSocket whose ``Host`` is not allowed is refused with 400 (DNS
      rebinding: api/security.py HostAllowList);
    - ``OPTIONS <path>``: 204 with ``Allow`` listing the path's real methods (404 when none),
      no token needed, nothing else revealed;
    - a declared ``Content-Length`` over ``api.max_body_bytes`` is refused at once (413); a
      body without one (chunked) is counted as it arrives and refused past the limit;
    - ``HEAD`` is served as the ``GET`` (FastAPI routes, unlike Starlette's, answer it 405)
      and only the headers are sent;

    and on every HTTP answer (refusals and static files included) the security headers, plus
    ``Cache-Control: no-store`` on what the API answers (live state, run data) and any JSON.
    """

    def __init__(
        self,
        app: ASGIApp,
        hosts: HostAllowList,
        routes: Iterable[BaseRoute],
        max_body_bytes: int,
        api_prefixes: tuple[str, ...],
    ) -> None:
        self.app = app
        self.hosts = hosts
        self.routes = routes
        self.max_body_bytes = max_body_bytes
        self.api_prefixes = api_prefixes
        self._allowed: set[bytes] = set()  # Host values already found allowed

    def _host_allowed(self, scope: Scope) -> tuple[bool, str | None]:
        host = next((value for name, value in scope["headers"] if name == b"host"), None)
        if host is not None and host in self._allowed:
            return True, None
        text = host.decode("latin-1") if host is not None else None
        if not self.hosts.allows(text):
            return False, text
        if host is not None and len(self._allowed) < 256:
            self._allowed.add(host)
        return True, None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        kind = scope["type"]
        if kind not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        allowed, host = self._host_allowed(scope)
        if not allowed:
            await self._refuse_host(scope, receive, send, host)
            return
        if kind == "websocket":
            await self.app(scope, receive, send)
            return
        path: str = scope["path"]
        extra = _DOCS_HEADERS if path == "/docs" else _PAGE_HEADERS
        no_store = path.startswith(self.api_prefixes)

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", ()))
                present = {name.lower() for name, _ in headers}
                headers.extend(item for item in extra if item[0] not in present)
                if b"cache-control" not in present:
                    json = any(
                        name.lower() == b"content-type" and value.startswith(b"application/json")
                        for name, value in headers
                    )
                    if no_store or json:
                        headers.append(_NO_STORE)
                message = {**message, "headers": headers}
            await send(message)

        method: str = scope["method"]
        if method == "OPTIONS":
            methods = allowed_methods(self.routes, path)
            response: Response = (
                Response(status_code=204, headers={"Allow": ", ".join(methods)})
                if methods
                else error_response(404, "not-found", "Not Found")
            )
            await response(scope, receive, send_with_headers)
            return
        if method in _BODY_METHODS:
            await self._with_body_limit(scope, receive, send_with_headers)
            return
        if method == "HEAD":
            await self.app({**scope, "method": "GET"}, receive, _headers_only(send_with_headers))
            return
        await self.app(scope, receive, send_with_headers)

    async def _refuse_host(
        self, scope: Scope, receive: Receive, send: Send, host: str | None
    ) -> None:
        response = error_response(
            400,
            "forbidden-host",
            f"Host {host!r} is not served here: reach the API by an allowed name "
            "(loopback, the bound address, api.allowed_hosts)",
        )
        if scope["type"] == "http":
            headers = [*response.raw_headers, *_PAGE_HEADERS, _NO_STORE]
            await send({"type": "http.response.start", "status": 400, "headers": headers})
            await send({"type": "http.response.body", "body": response.body})
        elif "websocket.http.response" in scope.get("extensions", {}):
            await send(
                {
                    "type": "websocket.http.response.start",
                    "status": 400,
                    "headers": response.raw_headers,
                }
            )
            await send({"type": "websocket.http.response.body", "body": response.body})
        else:
            await send({"type": "websocket.close", "code": 1008})

    async def _with_body_limit(self, scope: Scope, receive: Receive, send: Send) -> None:
        limit = self.max_body_bytes
        declared = next((v for k, v in scope["headers"] if k == b"content-length"), None)
        if declared is not None and (not declared.isdigit() or int(declared) > limit):
            response = error_response(413, "too-large", f"request body over {limit} bytes")
            await response(scope, receive, send)
            return
        received = 0

        async def counting_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise ApiError(413, "too-large", f"request body over {limit} bytes")
            return message

        await self.app(scope, counting_receive, send)


def _headers_only(send: Send) -> Send:
    """A ``send`` that passes the response's start and ends its body at once (HEAD)."""
    ended = False

    async def headers_only(message: Message) -> None:
        nonlocal ended
        if message["type"] == "http.response.start":
            await send(message)
        elif message["type"] == "http.response.body" and not ended:
            ended = True
            await send({"type": "http.response.body", "body": b"", "more_body": False})

    return headers_only
