"""Bounds on connections that uvicorn does not give, built so that the hold always gets in
(issue 16: 300 slowloris sockets stayed open 45 s, 1,100 idle ones exhausted the descriptors;
issue 26: the cap that fixed it closed every connection beyond it before its request was read,
so 300 held-open sockets let 0 of 75 holds in).

How it works (docs/explanation/api-connections.md has the numbers):

- **Nothing reaches uvicorn before its request head.** A new connection is *pending*: this
  module reads its first request head itself (httptools, the parser uvicorn[standard] ships),
  and only then hands the connection, with the bytes read so far, to uvicorn's own HTTP
  protocol. Silent and trickling sockets never take one of uvicorn's ``api.max_connections``
  slots.
- **Pending connections are bounded, oldest out first.** Beyond ``PENDING_MAX`` the oldest
  pending connections are closed (silent ones before those that sent part of a head), and
  only after the event loop has read what the newest ones sent: a flood of held-open sockets
  pushes out its own oldest members, while a client that sends its request with its
  connection (a hold) is served.
- **The cap answers 503, except to a hold.** A connection whose head arrives while
  ``api.max_connections`` connections are served gets a 503 and is closed -- unless the head
  is a request that holds the robot (``POST /robot/stop``, ``/runs/{id}/stop``,
  ``/runs/{id}/pause``) with a control token: that one is served from ``CONTROL_RESERVE``
  slots beyond the cap.
- **A request deadline** (slowloris): every request must be complete (head and body) within
  ``api.request_timeout_s`` of the connection opening or of the request's first byte, else
  the connection is closed. This parser sees every byte, so the deadline holds for a second
  request on a kept-alive connection too. Idle kept-alive connections are uvicorn's
  (``timeout_keep_alive``).

Why this shape (issue 27): the old guard subclassed uvicorn's private ``HttpToolsProtocol``
and overrode its callbacks, so a uvicorn release could change them silently, and
``http="h11"`` dropped the guard altogether. Here uvicorn is used only through what it
documents or types as public: ``Config(http=<an asyncio.Protocol class>)`` (a class called
with keyword arguments we pass on untouched to uvicorn's own implementation, chosen by its
public name "auto", "httptools" or "h11"), and the asyncio ``Protocol``/``Transport``
interfaces between them. The guard is a protocol *around* uvicorn's, never a subclass of it,
and works the same over either implementation (tests/test_api_connections.py runs both).
Not a listener of our own in front of uvicorn: handing it an accepted connection needs its
private protocol factory, and relaying the bytes instead would double the work of every
request and WebSocket message on the control loop's event loop.

What it cannot do: a flood of new connections faster than this process accepts them fills
the kernel's listen queue, and the kernel then drops connections -- a hold's too -- which TCP
retries 1 s and 3 s later (benchmarks/bench_flood.py measures it). A second listener (a local
Unix socket) would have a queue of its own, but only for clients on this machine; the
dashboard's hold comes over the network, through the one port.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any

import httptools
from uvicorn.config import HTTP_PROTOCOLS
from uvicorn.importer import import_from_string

from api.http_wire import HEAD_TOO_LARGE, MAX_HEAD_BYTES, Handover, busy_answer, head_facts

logger = logging.getLogger(__name__)

#: Connections whose first request head has not arrived yet, kept at most: beyond it the
#: oldest are closed, silent ones first, after the event loop's round of reads (see
#: ConnectionGuard.arrived). The bound on their descriptors; until it is reached every
#: connection has its whole request deadline to send its request, which a client whose
#: packets the kernel dropped in a flood (and TCP resent 1-3 s later) needs. A hold survives
#: a storm of new connections for at least min(api.request_timeout_s, PENDING_MAX / rate).
PENDING_MAX = 2048
#: The listen backlog (uvicorn's default): the kernel queues this many connections not yet
#: accepted, and asyncio accepts up to this many in one go.
LISTEN_BACKLOG = 2048
#: Connections served beyond ``api.max_connections`` for requests that hold the robot.
CONTROL_RESERVE = 16
#: Descriptors the server may hold beyond ``api.max_connections`` (api/startup.py's
#: descriptor check and deploy/thermocomp.service's LimitNOFILE count them): the pending
#: bound, two accept bursts on their way to it (accepted, not yet judged), the reserve.
ACCEPT_MARGIN = PENDING_MAX + 2 * LISTEN_BACKLOG + CONTROL_RESERVE
#: asyncio may run a timer this early (its clock resolution, rounded up) (s).
CLOCK_SLACK_S = 0.001
#: At most one warning about closed connections per this many seconds (no journal floods).
WARN_INTERVAL_S = 10.0

#: Decides whether a request may use the reserve beyond the cap: (method, path without the
#: query, Authorization header or None) -> True for an authenticated hold.
HoldCheck = Callable[[str, str, "str | None"], bool]


class ConnectionGuard:
    """The bounds of one server: who is pending, how many are served, the counts.

    ``protocol`` is the class to give uvicorn as ``Config(http=...)``. Call :meth:`close`
    once the server has stopped: pending connections are not uvicorn's to close.
    """

    def __init__(
        self,
        max_connections: int,
        request_timeout_s: float,
        admits_hold: HoldCheck,
        *,
        http: str = "auto",
        pending_max: int = PENDING_MAX,
        control_reserve: int = CONTROL_RESERVE,
    ) -> None:
        self.max_connections = max_connections
        self.request_timeout_s = request_timeout_s
        self.admits_hold = admits_hold
        self.pending_max = pending_max
        self.control_reserve = control_reserve
        # uvicorn's own HTTP protocol, by the public name its Config takes ("auto" is
        # httptools when installed, else h11)
        self.inner_protocol: type[asyncio.Protocol] = import_from_string(
            HTTP_PROTOCOLS.get(http, http)
        )
        self.served = 0  # connections handed to uvicorn, within max_connections
        self.reserve_used = 0  # ... and beyond it, for holds
        # pending connections -> when they arrived (loop time), in arrival order (dicts keep
        # it): silent ones, and the ones that sent part of a head
        self._silent: dict[GuardedConnection, float] = {}
        self._started: dict[GuardedConnection, float] = {}
        self._sweep: asyncio.TimerHandle | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        # served connections with a request under way -> when it began, oldest first (a
        # request is added when it begins, so insertion order is time order)
        self._in_request: dict[GuardedConnection, float] = {}
        self._request_sweep: asyncio.TimerHandle | None = None
        self.counts = {"evicted": 0, "refused": 0, "timed_out": 0, "held_beyond_cap": 0}
        self._last_warning = -WARN_INTERVAL_S
        self._unreported = 0
        self.protocol: type[GuardedConnection] = type(
            "GuardedConnection", (GuardedConnection,), {"guard": self}
        )

    @property
    def pending(self) -> int:
        return len(self._silent) + len(self._started)

    @property
    def pending_silent(self) -> int:
        """Pending connections that have sent nothing yet."""
        return len(self._silent)

    # --- pending connections ---------------------------------------------------------------
    #
    # One timer for all of them (not one per connection: a flood's sockets would each cost a
    # timer), set for the next moment anything can change: the oldest silent connection's
    # request deadline, or now when the pool is over PENDING_MAX. A timer due now runs after
    # the event loop's next round of reads (asyncio runs due timers after the I/O callbacks
    # of a round), so the connections of an accept burst are judged by what they sent with
    # their connection, not closed unread.

    def arrived(self, connection: GuardedConnection, loop: asyncio.AbstractEventLoop) -> None:
        now = loop.time()
        self._silent[connection] = now
        self._loop = loop
        if len(self._silent) + len(self._started) > self.pending_max:
            self._wake_at(now)
        else:
            self._wake_at(now + self.request_timeout_s)

    def began(self, connection: GuardedConnection, now: float) -> float:
        """``connection`` sent its first bytes (it is still pending): when it arrived."""
        arrived = self._silent.pop(connection, now)
        self._started[connection] = arrived
        return arrived

    def left_pending(self, connection: GuardedConnection) -> None:
        self._silent.pop(connection, None)
        self._started.pop(connection, None)

    def _wake_at(self, when: float) -> None:
        sweep = self._sweep
        if sweep is not None:
            if sweep.when() <= when:
                return
            sweep.cancel()
        assert self._loop is not None
        self._sweep = self._loop.call_at(when, self._sweep_pending)

    def _sweep_pending(self) -> None:
        self._sweep = None
        assert self._loop is not None
        now = self._loop.time()
        # silent beyond the request deadline (the ones that began have their own timer)
        deadline = now - self.request_timeout_s + CLOCK_SLACK_S
        timed_out = self._close(self._silent, len(self._silent), deadline)
        if timed_out:
            self.counts["timed_out"] += timed_out
            self.note_dropped(f"no request within {self.request_timeout_s:g} s", timed_out)
        excess = self.pending - self.pending_max
        evicted = self._close(self._silent, excess, float("inf"))
        evicted += self._close(self._started, excess - evicted, float("inf"))
        if evicted:
            self.counts["evicted"] += evicted
            self.note_dropped("the oldest connections without a request: too many", evicted)
        if self._silent:
            self._wake_at(max(next(iter(self._silent.values())) + self.request_timeout_s, now))

    @staticmethod
    def _close(queue: dict[GuardedConnection, float], count: int, arrived_before: float) -> int:
        """Close up to ``count`` connections of ``queue`` (oldest first) that arrived at or
        before ``arrived_before``; how many."""
        closed = 0
        while closed < count and queue:
            oldest, arrived = next(iter(queue.items()))
            if arrived > arrived_before:
                break
            del queue[oldest]
            closed += 1
            oldest.evict()
        return closed

    # --- requests on served connections -----------------------------------------------------
    #
    # One timer for all of them, at the oldest request's deadline: a timer per request (armed
    # and cancelled around every request) cost /state a measurable share of its throughput.

    def request_began(self, connection: GuardedConnection, now: float) -> None:
        self._in_request.pop(connection, None)
        self._in_request[connection] = now
        if self._request_sweep is None:
            assert self._loop is not None
            self._request_sweep = self._loop.call_at(
                now + self.request_timeout_s, self._sweep_requests
            )

    def request_ended(self, connection: GuardedConnection) -> None:
        self._in_request.pop(connection, None)

    def _sweep_requests(self) -> None:
        self._request_sweep = None
        assert self._loop is not None
        now = self._loop.time()
        limit = now - self.request_timeout_s + CLOCK_SLACK_S
        expired = []
        for connection, began in self._in_request.items():
            if began > limit:
                break
            expired.append(connection)
        for connection in expired:
            del self._in_request[connection]
            connection.timed_out()
        if self._in_request:
            oldest = next(iter(self._in_request.values()))
            self._request_sweep = self._loop.call_at(
                max(oldest + self.request_timeout_s, now), self._sweep_requests
            )

    # --- served connections ----------------------------------------------------------------

    def admit(self, method: str, path: str, authorization: str | None) -> bool | None:
        """Whether a connection whose first request head is this may be served: True within
        the cap, False beyond it for a hold (the reserve), None when refused."""
        if self.served < self.max_connections:
            self.served += 1
            return True
        if self.reserve_used < self.control_reserve and self.admits_hold(
            method, path, authorization
        ):
            self.reserve_used += 1
            self.counts["held_beyond_cap"] += 1
            return False
        self.counts["refused"] += 1
        self.note_dropped(f"answered 503: {self.max_connections} connections served")
        return None

    def released(self, in_reserve: bool) -> None:
        if in_reserve:
            self.reserve_used -= 1
        else:
            self.served -= 1

    # --- the whole server ------------------------------------------------------------------

    def close(self) -> None:
        """Close every pending connection (the server has stopped serving)."""
        for sweep in (self._sweep, self._request_sweep):
            if sweep is not None:
                sweep.cancel()
        self._sweep = self._request_sweep = None
        self._in_request.clear()
        for connection in [*self._silent, *self._started]:
            self.left_pending(connection)
            connection.evict()

    def note_dropped(self, why: str, count: int = 1) -> None:
        self._unreported += count
        now = asyncio.get_running_loop().time()
        if now - self._last_warning >= WARN_INTERVAL_S:
            logger.warning("closed %d connection(s) in the last period: %s", self._unreported, why)
            self._unreported = 0
            self._last_warning = now


class GuardedConnection(asyncio.Protocol):
    """One connection: pending until its first request head is read, then forwarding to
    uvicorn's protocol; every request on it under the request deadline."""

    guard: ConnectionGuard  # set on the class ConnectionGuard.protocol makes

    def __init__(self, **uvicorn_arguments: Any) -> None:
        # uvicorn calls its protocol class with keyword arguments (config, server state ...);
        # they go, unread, to uvicorn's own protocol once the connection is served
        self._arguments = uvicorn_arguments
        self.inner: asyncio.BaseProtocol | None = None
        self._transport: asyncio.Transport | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._parser: httptools.HttpRequestParser | None = None
        self._deadline: asyncio.TimerHandle | None = None
        self._head = bytearray()  # the first request's bytes, while pending
        self._head_complete = False
        self.pending = True
        self._served = False
        self._in_reserve = False

    # --- asyncio.Protocol --------------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self._transport = transport
        self._loop = loop = asyncio.get_running_loop()
        self.guard.arrived(self, loop)  # the guard keeps its deadline while it sends nothing

    def data_received(self, data: bytes) -> None:
        if self.pending and not self._head:
            # its first bytes: the request deadline still counts from the connection's start
            arrived = self.guard.began(self, self._now())
            self._parser = httptools.HttpRequestParser(self)
            self._arm(arrived + self.guard.request_timeout_s)
        parser = self._parser
        if parser is not None:
            try:
                parser.feed_data(data)
            except httptools.HttpParserUpgrade:
                # Nothing after an upgrade request is HTTP: it must become a WebSocket (its
                # protocol then owns the connection and its timeouts, see forward_to) within
                # the request deadline, or be closed.
                self._parser = None
                self._disarm()
                self.guard.request_ended(self)
                self._arm(self._now() + self.guard.request_timeout_s)
            except httptools.HttpParserError:
                # malformed: uvicorn's own parser answers 400 and closes
                self._parser = None
                self._disarm()
                self.guard.request_ended(self)
                self._head_complete = True
        inner = self.inner
        if inner is not None:
            inner.data_received(data)  # type: ignore[attr-defined]
            return
        if not self.pending:
            return  # refused or evicted: the transport is closing
        self._head += data
        if self._head_complete:
            self._decide()
        elif len(self._head) > MAX_HEAD_BYTES:
            self._answer_and_close(HEAD_TOO_LARGE)

    def eof_received(self) -> bool | None:
        inner = self.inner
        if inner is not None:
            return inner.eof_received()  # type: ignore[attr-defined,no-any-return]
        if self.pending:  # a client that gave up (the transport closes): not one to evict
            self.pending = False
            self.guard.left_pending(self)
        return None

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        self.guard.request_ended(self)
        self._parser = None
        if self.pending:
            self.pending = False
            self.guard.left_pending(self)
        if self._served:
            self._served = False
            self.guard.released(self._in_reserve)
        inner = self.inner
        if inner is not None:
            inner.connection_lost(exc)

    def pause_writing(self) -> None:
        if self.inner is not None:
            self.inner.pause_writing()

    def resume_writing(self) -> None:
        if self.inner is not None:
            self.inner.resume_writing()

    # --- httptools parser callbacks ----------------------------------------------------------

    # Only these three: a callback per header or URL piece would cost every request; the first
    # request's head is read from its bytes once (_decide).

    def on_message_begin(self) -> None:
        if self._deadline is None:  # (the first request's runs from the connection's start)
            assert self._loop is not None
            self.guard.request_began(self, self._loop.time())

    def on_headers_complete(self) -> None:
        self._head_complete = True

    def on_message_complete(self) -> None:
        if self._deadline is not None:
            self._disarm()
        else:
            self.guard.request_ended(self)

    # --- the guard's decisions ---------------------------------------------------------------

    def forward_to(self, protocol: asyncio.BaseProtocol) -> None:
        """uvicorn switched the connection to ``protocol`` (a WebSocket)."""
        self.inner = protocol
        self._disarm()
        self.guard.request_ended(self)

    def evict(self) -> None:
        self.pending = False
        self._disarm()
        if self._transport is not None:
            self._transport.close()

    def _decide(self) -> None:
        self.pending = False
        self.guard.left_pending(self)
        method, path, authorization = head_facts(self._head)
        admitted = self.guard.admit(method, path, authorization)
        if admitted is None:
            self._answer_and_close(busy_answer(self.guard.max_connections))
            return
        self._served = True
        self._in_reserve = not admitted
        head, self._head = bytes(self._head), bytearray()
        assert self._transport is not None
        inner = self.guard.inner_protocol(**self._arguments)
        self.inner = inner
        inner.connection_made(Handover(self._transport, self))
        if not self._transport.is_closing():
            inner.data_received(head)

    def _answer_and_close(self, answer: bytes) -> None:
        if self.pending:
            self.pending = False
            self.guard.left_pending(self)
        self._disarm()
        self._parser = None
        if self._transport is not None and not self._transport.is_closing():
            self._transport.write(answer)
            self._transport.close()

    def _now(self) -> float:
        assert self._loop is not None
        return self._loop.time()

    def _arm(self, when: float) -> None:
        assert self._loop is not None
        self._deadline = self._loop.call_at(when, self._timed_out)

    def _disarm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _timed_out(self) -> None:
        self._deadline = None
        self.timed_out()

    def current_protocol(self) -> asyncio.BaseProtocol:
        """The protocol the connection's bytes go to now (the Handover's get_protocol)."""
        return self.inner or self

    def timed_out(self) -> None:
        """The request deadline has passed: close the connection."""
        transport = self._transport
        if transport is not None and not transport.is_closing():
            self.guard.counts["timed_out"] += 1
            self.guard.note_dropped(
                f"no complete request within {self.guard.request_timeout_s:g} s"
            )
            transport.close()
