"""Plain ASGI middleware around every request: the Host allow-list, the security headers, and
honest ``OPTIONS`` answers. Plain ASGI (not BaseHTTPMiddleware): each costs one function call
per request, nothing is buffered, and streamed exports stay streamed.
"""

from __future__ import annotations

from collections.abc import Iterable

from starlette.datastructures import MutableHeaders
from starlette.responses import Response
from starlette.routing import BaseRoute, Match, Mount
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from api.errors import error_response
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
_COMMON_HEADERS = (
    ("x-content-type-options", "nosniff"),
    ("x-frame-options", "DENY"),
    ("referrer-policy", "no-referrer"),
    ("cross-origin-opener-policy", "same-origin"),
)


class HostCheck:
    """Refuse (400) a request or WebSocket whose ``Host`` is not allowed (DNS rebinding)."""

    def __init__(self, app: ASGIApp, hosts: HostAllowList) -> None:
        self.app = app
        self.hosts = hosts

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            host = next((v for k, v in scope["headers"] if k == b"host"), None)
            text = host.decode("latin-1") if host is not None else None
            if not self.hosts.allows(text):
                response = error_response(
                    400,
                    "forbidden-host",
                    f"Host {text!r} is not served here: reach the API by an allowed name "
                    "(loopback, the bound address, api.allowed_hosts)",
                )
                if scope["type"] == "websocket":
                    if "websocket.http.response" in scope.get("extensions", {}):
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
                    return
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)


class SecurityHeaders:
    """Security headers on every HTTP response (error answers and static files included);
    ``Cache-Control: no-store`` on what the API answers (live state, run data), which no
    browser or proxy should keep."""

    def __init__(self, app: ASGIApp, api_prefixes: tuple[str, ...]) -> None:
        self.app = app
        self.api_prefixes = api_prefixes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path: str = scope["path"]
        policy = DOCS_CONTENT_SECURITY_POLICY if path == "/docs" else CONTENT_SECURITY_POLICY
        no_store = path.startswith(self.api_prefixes)

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                headers.setdefault("content-security-policy", policy)
                for name, value in _COMMON_HEADERS:
                    headers.setdefault(name, value)
                content_type = headers.get("content-type", "")
                if no_store or content_type.startswith("application/json"):
                    headers["cache-control"] = "no-store"
            await send(message)

        await self.app(scope, receive, send_with_headers)


#: The methods probed for ``Allow`` (the API uses no others).
_METHODS = ("GET", "POST", "PUT", "PATCH", "DELETE")


def allowed_methods(routes: Iterable[BaseRoute], path: str) -> list[str]:
    """Every method some route serves at ``path`` (FastAPI answers a 405 or an OPTIONS with
    the first matching route's methods only: /runs has a GET route and a POST route). Each
    method is probed through the routes' own matching, included routers too."""
    methods: set[str] = set()
    for route in routes:
        if isinstance(route, Mount):  # static files: they match any method, serve two
            if path.startswith(route.path + "/"):
                methods |= {"GET", "HEAD"}
            continue
        for method in _METHODS:
            probe = {"type": "http", "path": path, "method": method, "root_path": ""}
            if route.matches({**probe, "headers": [], "query_string": b""})[0] is Match.FULL:
                methods.add(method)
    if methods:
        methods.add("OPTIONS")
        if "GET" in methods:
            methods.add("HEAD")
    return sorted(methods)


class MethodOptions:
    """``OPTIONS <path>``: 204 with ``Allow`` listing the path's real methods (404 when none);
    no token needed, nothing else is revealed."""

    def __init__(self, app: ASGIApp, routes: Iterable[BaseRoute]) -> None:
        self.app = app
        self.routes = routes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "OPTIONS":
            await self.app(scope, receive, send)
            return
        methods = allowed_methods(self.routes, scope["path"])
        response: Response = (
            Response(status_code=204, headers={"Allow": ", ".join(methods)})
            if methods
            else error_response(404, "not-found", "Not Found")
        )
        await response(scope, receive, send)


class HeadAsGet:
    """``HEAD`` wherever ``GET`` is: FastAPI routes (unlike Starlette's) answer HEAD with 405,
    so a HEAD is served as the GET and only its headers (Content-Length included) are sent."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return
        ended = False

        async def headers_only(message: Message) -> None:
            nonlocal ended
            if message["type"] == "http.response.start":
                await send(message)
            elif message["type"] == "http.response.body" and not ended:
                ended = True
                await send({"type": "http.response.body", "body": b"", "more_body": False})

        await self.app({**scope, "method": "GET"}, receive, headers_only)
