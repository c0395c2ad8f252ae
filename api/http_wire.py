"""The bytes the connection guard (api/connections.py) reads and writes itself, before
uvicorn sees a connection: its own closing answers, the facts of a first request head, and the
transport uvicorn's protocol gets once a connection is handed over. Pure, apart from the
transport wrapper."""

from __future__ import annotations

import asyncio
from typing import Protocol

#: Largest first request head read before handing over (bytes): browsers send a few KiB.
MAX_HEAD_BYTES = 64 * 1024

_SERVICE_UNAVAILABLE = (
    b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\n"
    b"retry-after: 1\r\ncache-control: no-store\r\nx-content-type-options: nosniff\r\n"
    b"connection: close\r\ncontent-length: %d\r\n\r\n%s"
)


def error_answer(status: int, reason: str, kind: str, message: str) -> bytes:
    """A whole HTTP/1.1 answer in the API's error shape (api/errors.py), closing."""
    body = b'{"status":%d,"kind":"%s","message":"%s","details":null}' % (
        status,
        kind.encode(),
        message.encode(),
    )
    return (
        b"HTTP/1.1 %d %s\r\ncontent-type: application/json\r\ncache-control: no-store\r\n"
        b"x-content-type-options: nosniff\r\nconnection: close\r\n"
        b"content-length: %d\r\n\r\n%s" % (status, reason.encode(), len(body), body)
    )


def busy_answer(max_connections: int) -> bytes:
    body = (
        b'{"status":503,"kind":"too-many-connections","message":"the server is serving its '
        b'maximum of %d connections (api.max_connections); retry later","details":null}'
        % max_connections
    )
    return _SERVICE_UNAVAILABLE % (len(body), body)


HEAD_TOO_LARGE = error_answer(
    431, "Request Header Fields Too Large", "too-large", f"request head over {MAX_HEAD_BYTES} bytes"
)


def head_facts(head: bytes | bytearray) -> tuple[str, str, str | None]:
    """The method, the path (without the query) and the Authorization header of the first
    request in ``head``, which the parser has found whole (its head, that is; body bytes may
    follow)."""
    lines = bytes(head).split(b"\n")
    method, _, rest = lines[0].rstrip(b"\r").partition(b" ")
    target = rest.partition(b" ")[0]
    authorization = None
    for raw in lines[1:]:
        line = raw.rstrip(b"\r")
        if not line:
            break
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"authorization":
            authorization = value.strip().decode("latin-1")
    path = target.partition(b"?")[0].decode("latin-1")
    return method.decode("latin-1"), path, authorization


class Forwarding(Protocol):
    """What the handed-over transport needs of the guarded connection that owns it."""

    def forward_to(self, protocol: asyncio.BaseProtocol) -> None: ...

    def current_protocol(self) -> asyncio.BaseProtocol: ...


#: What uvicorn's protocols and websockets call on a transport, passed straight through.
PASSED_THROUGH = (
    "write",
    "writelines",
    "write_eof",
    "can_write_eof",
    "abort",
    "close",
    "is_closing",
    "get_extra_info",
    "pause_reading",
    "resume_reading",
    "is_reading",
    "get_write_buffer_size",
    "get_write_buffer_limits",
    "set_write_buffer_limits",
)


class Handover(asyncio.Transport):
    """The transport uvicorn's protocol gets: the real one, except that a protocol switch
    (the WebSocket upgrade) changes where the guarded connection forwards to instead of
    replacing the guarded connection, so the guard still sees the connection end."""

    def __init__(self, transport: asyncio.Transport, owner: Forwarding) -> None:
        super().__init__()
        self._owner = owner
        for name in PASSED_THROUGH:  # bound once: a call costs what it costs unguarded
            setattr(self, name, getattr(transport, name))

    def set_protocol(self, protocol: asyncio.BaseProtocol) -> None:
        self._owner.forward_to(protocol)

    def get_protocol(self) -> asyncio.BaseProtocol:
        return self._owner.current_protocol()
