"""Bounds on connections that uvicorn does not give (issue 16: 300 slowloris sockets stayed
open 45 s; 1,100 idle ones exhausted the file descriptors).

uvicorn bounds what it can: ``limit_concurrency`` answers 503 to requests beyond
``api.max_connections``, ``timeout_keep_alive`` closes idle keep-alive connections. It has no
bound on a connection that never completes a request (its keep-alive timer starts only after
a response), and ``limit_concurrency`` acts only once a request has arrived, so silent sockets
hold a descriptor each for ever. The smallest guard is this subclass of uvicorn's own
httptools protocol, three hooks:

- a request deadline: a request must be complete (headers and body) within
  ``api.request_timeout_s`` of the connection opening or of its first byte, else the
  connection is closed;
- a hard cap: a connection accepted while ``api.max_connections`` + ``ACCEPT_MARGIN`` are
  open is closed at once, so descriptors stay bounded whatever clients do (the unit's
  ``LimitNOFILE`` has headroom above it, so accept() never fails with EMFILE);
- the hold (``POST /api/v1/robot/stop``) is never answered by uvicorn's 503: the application
  checks its token and serves it whatever the load.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

logger = logging.getLogger(__name__)

#: Connections beyond ``api.max_connections`` still accepted (and answered 503 by uvicorn)
#: before new ones are closed on accept: a polite answer for a few, a bound for all.
ACCEPT_MARGIN = 16
#: At most one warning about closed connections per this many seconds (no journal floods).
WARN_INTERVAL_S = 10.0

HOLD_URL = b"/api/v1/robot/stop"


class GuardedHttpProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with a request deadline and a hard connection cap."""

    max_open = 256 + ACCEPT_MARGIN
    request_timeout_s = 5.0
    _last_warning = -WARN_INTERVAL_S
    _dropped = 0

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        if len(self.connections) > self.max_open:
            self._note_dropped("over the connection cap")
            transport.close()
            return
        self._arm()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def on_message_begin(self) -> None:
        super().on_message_begin()
        self._arm()

    def on_headers_complete(self) -> None:
        if self.url.split(b"?", 1)[0] != HOLD_URL:
            super().on_headers_complete()
            return
        limit, self.limit_concurrency = self.limit_concurrency, None
        try:
            super().on_headers_complete()
        finally:
            self.limit_concurrency = limit

    def on_message_complete(self) -> None:
        self._disarm()
        super().on_message_complete()

    def handle_websocket_upgrade(self) -> None:
        self._disarm()  # the WebSocket protocol owns the connection from here
        super().handle_websocket_upgrade()

    def _arm(self) -> None:
        if self._deadline is None:
            self._deadline = self.loop.call_later(self.request_timeout_s, self._timed_out)

    def _disarm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _timed_out(self) -> None:
        self._deadline = None
        if not self.transport.is_closing():
            self._note_dropped(f"no complete request within {self.request_timeout_s:g} s")
            self.transport.close()

    def _note_dropped(self, why: str) -> None:
        cls = type(self)
        cls._dropped += 1
        now = self.loop.time()
        if now - cls._last_warning >= WARN_INTERVAL_S:
            logger.warning("closed %d connection(s) in the last period: %s", cls._dropped, why)
            cls._dropped = 0
            cls._last_warning = now


def guarded_protocol(max_connections: int, request_timeout_s: float) -> type[HttpToolsProtocol]:
    """The protocol class for uvicorn's ``http=`` with this server's bounds."""
    return type(
        "GuardedHttpProtocol",
        (GuardedHttpProtocol,),
        {
            "max_open": max_connections + ACCEPT_MARGIN,
            "request_timeout_s": request_timeout_s,
            "_last_warning": -WARN_INTERVAL_S,
            "_dropped": 0,
        },
    )
