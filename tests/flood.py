"""Connection floods on loopback and a hold that times itself (issue 26), for the tests and
benchmarks/bench_flood.py. Every flood is bounded (sockets, time) and stops by itself; the
target is always 127.0.0.1.

- :class:`HeldSockets`: ``count`` sockets kept open without a byte sent; each one the server
  closes is opened again (``churn=False``), or new ones are opened back to back and the
  oldest beyond ``count`` closed (``churn=True``: the server sees a stream of new silent
  connections with ``count`` of them open at any time);
- :class:`ConnectStorm`: connect and close, back to back;
- either at most ``rate_per_s`` new connections a second, or as fast as the machine can;
- :class:`FloodProcess`: one of them in a process of its own, so that the client and the
  server under test do not share an interpreter lock;
- :func:`send_hold`: ``POST /api/v1/robot/stop`` on a new connection; its status, error kind
  and time from connect() to the whole answer.
"""

from __future__ import annotations

import json
import multiprocessing
import selectors
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any, Self

HOST = "127.0.0.1"
HOLD_PATH = "/api/v1/robot/stop"


@dataclass(frozen=True)
class Answer:
    status: int  # 0: the connection was closed without an answer
    kind: str | None  # the error body's ``kind``; None for a success or no answer
    seconds: float
    error: str | None = None  # what ended a connection without an answer


def request(method: str, path: str, token: str | None = None, body: bytes = b"") -> bytes:
    head = f"{method} {path} HTTP/1.1\r\nHost: {HOST}\r\nConnection: close\r\n"
    if token is not None:
        head += f"Authorization: Bearer {token}\r\n"
    head += f"Content-Length: {len(body)}\r\n\r\n"
    return head.encode() + body


def read_answer(sock: socket.socket) -> tuple[int, bytes]:
    """The status and body of one HTTP/1.1 answer (Content-Length framed); (0, b"") when the
    server closed the connection first."""
    data = b""
    try:
        while b"\r\n\r\n" not in data:
            chunk = sock.recv(65536)
            if not chunk:
                return 0, b""
            data += chunk
        head, _, body = data.partition(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        status = int(lines[0].split()[1])
        length = next(
            (
                int(line.split(":", 1)[1])
                for line in lines
                if line.lower().startswith("content-length:")
            ),
            0,
        )
        while len(body) < length:
            chunk = sock.recv(65536)
            if not chunk:
                break
            body += chunk
    except (ConnectionResetError, BrokenPipeError):
        return 0, b""
    return status, body


def exchange(port: int, payload: bytes, timeout_s: float = 20.0) -> Answer:
    """Send ``payload`` on a new connection and read the answer, timed from connect()."""
    started = time.perf_counter()
    error = None
    try:
        with socket.create_connection((HOST, port), timeout=timeout_s) as sock:
            connected = time.perf_counter() - started
            sock.sendall(payload)
            status, body = read_answer(sock)
            if status == 0:
                error = f"closed without an answer ({connected:.3f} s to connect)"
    except OSError as err:  # refused, reset, timed out
        status, body, error = 0, b"", f"{type(err).__name__}: {err}"
    seconds = time.perf_counter() - started
    kind = None
    if status >= 400 and body:
        try:
            kind = json.loads(body).get("kind")
        except ValueError:
            kind = None
    return Answer(status, kind, seconds, error)


def send_hold(port: int, token: str | None, timeout_s: float = 20.0) -> Answer:
    return exchange(port, request("POST", HOLD_PATH, token), timeout_s)


class _Flood(threading.Thread):
    """A flood thread that runs until stopped or ``limit_s`` has passed."""

    def __init__(self, port: int, limit_s: float, rate_per_s: float | None = None) -> None:
        super().__init__(daemon=True)
        self.port = port
        self.limit_s = limit_s
        self.rate_per_s = rate_per_s
        self._next = 0.0
        self._halt = threading.Event()
        self.opened = 0
        self.failed = 0  # connect() refused or timed out

    def stop(self) -> None:
        self._halt.set()
        self.join()

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(self, *_: object) -> None:
        self.stop()

    def _connect(self) -> socket.socket | None:
        if self.rate_per_s is not None:
            now = time.monotonic()
            if now < self._next:
                time.sleep(self._next - now)
            self._next = max(now, self._next) + 1.0 / self.rate_per_s
        try:
            sock = socket.create_connection((HOST, self.port), timeout=5.0)
        except OSError:
            self.failed += 1
            return None
        self.opened += 1
        return sock

    def _running(self, until: float) -> bool:
        return not self._halt.is_set() and time.monotonic() < until


class HeldSockets(_Flood):
    def __init__(
        self,
        port: int,
        count: int,
        limit_s: float = 60.0,
        churn: bool = False,
        rate_per_s: float | None = None,
    ) -> None:
        super().__init__(port, limit_s, rate_per_s)
        self.count = count
        self.churn = churn
        self.closed_by_server = 0
        self.ready = threading.Event()  # the first ``count`` are open

    def run(self) -> None:
        until = time.monotonic() + self.limit_s
        selector = selectors.DefaultSelector()
        order: list[socket.socket] = []
        try:
            while self._running(until) and len(order) < self.count:
                self._add(selector, order)
            self.ready.set()
            while self._running(until):
                if self.churn:
                    self._add(selector, order)
                    while len(order) > self.count:
                        self._remove(selector, order, order[0])
                for key, _ in selector.select(timeout=0 if self.churn else 0.05):
                    sock = key.fileobj
                    assert isinstance(sock, socket.socket)
                    try:
                        closed = sock.recv(1024) == b""
                    except OSError:
                        closed = True
                    if closed:
                        self.closed_by_server += 1
                        self._remove(selector, order, sock)
                        if not self.churn:
                            self._add(selector, order)
        finally:
            self.ready.set()
            for sock in order:
                selector.unregister(sock)
                sock.close()
            selector.close()

    def _add(self, selector: selectors.BaseSelector, order: list[socket.socket]) -> None:
        sock = self._connect()
        if sock is not None:
            sock.setblocking(False)
            selector.register(sock, selectors.EVENT_READ)
            order.append(sock)

    @staticmethod
    def _remove(
        selector: selectors.BaseSelector, order: list[socket.socket], sock: socket.socket
    ) -> None:
        selector.unregister(sock)
        order.remove(sock)
        sock.close()


#: Connections a connect/close storm opens before it says it is ready: the holds are sent into
#: a storm under way, not raced against its first connections (on an idle machine twenty holds
#: are answered before a storm at 400/s has opened twenty).
STORM_WARMUP_CONNECTIONS = 50


class ConnectStorm(_Flood):
    def __init__(self, port: int, limit_s: float, rate_per_s: float | None = None) -> None:
        super().__init__(port, limit_s, rate_per_s)
        self.ready = threading.Event()

    def run(self) -> None:
        until = time.monotonic() + self.limit_s
        while self._running(until):
            sock = self._connect()
            if sock is not None:
                sock.close()
            if self.opened >= STORM_WARMUP_CONNECTIONS:
                self.ready.set()


def _flood_main(kind: str, port: int, options: dict[str, Any], channel: Any, halt: Any) -> None:
    flood: HeldSockets | ConnectStorm
    if kind == "connect-close":
        flood = ConnectStorm(port, **options)
    else:
        flood = HeldSockets(port, churn=kind == "churn", **options)
    with flood:
        flood.ready.wait(options.get("limit_s", 60.0))
        channel.put("ready")
        halt.wait(options.get("limit_s", 60.0))
    counts = {"opened": flood.opened, "failed": flood.failed}
    if isinstance(flood, HeldSockets):
        counts["closed_by_server"] = flood.closed_by_server
    channel.put(counts)


class FloodProcess:
    """A flood ("held", "churn" or "connect-close") in a process of its own; ``counts`` once
    it has stopped. The options are those of the flood's class (count, limit_s, rate_per_s)."""

    def __init__(self, kind: str, port: int, **options: Any) -> None:
        context = multiprocessing.get_context("spawn")
        self._channel = context.Queue()
        self._halt = context.Event()
        self._process = context.Process(
            target=_flood_main,
            args=(kind, port, options, self._channel, self._halt),
            daemon=True,
        )
        self.limit_s = float(options.get("limit_s", 60.0))
        self.counts: dict[str, int] = {}

    def __enter__(self) -> Self:
        self._process.start()
        ready = self._channel.get(timeout=self.limit_s + 30)
        assert ready == "ready", ready
        return self

    def __exit__(self, *_: object) -> None:
        self._halt.set()
        self.counts = self._channel.get(timeout=self.limit_s + 30)
        self._process.join(timeout=30)
        self._channel.close()
