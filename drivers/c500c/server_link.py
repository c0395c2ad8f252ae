"""The fast path's link: frames to and from controller/thermocomp_server.r3 over
pyserial-asyncio (controller/PROTOCOL.md), under the robot driver drivers/c500c/server.py.

Requests are sequence-numbered and several may be outstanding: a reader task matches every reply
to its request by sequence number. So a HOLD is written while a move still awaits its reply,
heartbeats go out on a timer whatever else is in flight, and a cancelled request never
desynchronises the link (its late reply is recognised and dropped). Frames are written whole
under a write lock; the hold contract (drivers/base.py) is checked under that lock immediately
before a motion frame is written.

Any reply that cannot be trusted — bad CRC, garbage, an impossible length, a sequence number
never used, a timeout, a lost port — is a link fault: every outstanding request fails with it,
motion is held until the robot's ``resume()``, and the link reconnects in the background with a
capped exponential back-off (drivers/c500c/link_states.py, as the console driver's).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
from dataclasses import dataclass
from typing import Self

import serial

from config.settings import RobotSettings
from drivers.base import LinkState
from drivers.c500c import server_protocol as proto
from drivers.c500c.link_states import SERVER_TRANSITIONS as TRANSITIONS
from drivers.c500c.link_states import LinkLifecycle
from drivers.errors import (
    DeviceError,
    DeviceTimeoutError,
    NotConnectedError,
    ProtocolError,
)
from drivers.permit import MotionPermit, Ticket
from drivers.reconnect import RECONNECT_FIRST_BACKOFF_S, Reconnector
from drivers.serial_port import open_serial

logger = logging.getLogger(__name__)

DEVICE = proto.DEVICE
#: Cancelled requests whose replies may still arrive are remembered this many at most.
ABANDONED_LIMIT = 1024

_MOTION = (proto.RequestType.MOVE_GOAL, proto.RequestType.MOVE_RELATIVE)


class _LinkFault(Exception):
    """Internal: the reader found the link unusable; carries the DeviceError to report."""

    def __init__(self, error: DeviceError) -> None:
        super().__init__(str(error))
        self.error = error


@dataclass
class _Connection:
    reader: asyncio.StreamReader
    writer: asyncio.StreamWriter
    task: asyncio.Task[None] | None = None  # the reply reader

    def close(self) -> None:
        transport = self.writer.transport
        if not transport.is_closing():
            transport.abort()


class ServerLink(LinkLifecycle):
    """The link to the server program: requests, replies, heartbeats, faults, reconnection."""

    def __init__(
        self,
        settings: RobotSettings,
        *,
        port: str | None = None,
        first_backoff_s: float = RECONNECT_FIRST_BACKOFF_S,
        permit: MotionPermit | None = None,
    ) -> None:
        self.settings = settings
        #: the one owner of "may the robot move" (drivers/permit.py): every hold goes through it
        self.permit = permit if permit is not None else MotionPermit(DEVICE)
        self.port = port if port is not None else settings.server_port
        self.first_backoff_s = first_backoff_s
        self._connection: _Connection | None = None
        self._write_lock = asyncio.Lock()  # one whole frame at a time
        # sequence -> (request type, its reply to come)
        self._pending: dict[int, tuple[proto.RequestType, asyncio.Future[proto.Reply]]] = {}
        self._abandoned: dict[int, None] = {}  # insertion-ordered set, oldest dropped first
        self._sequence = itertools.count()
        self._link = LinkState.DISCONNECTED
        self.link_history: list[LinkState] = [self._link]
        self._last_error: str | None = None
        self._flags: proto.Flag | None = None  # of the latest reply
        self._reconnector = Reconnector(  # drivers/reconnect.py, as the console driver's
            DEVICE,
            self._connect,
            first_backoff_s=lambda: self.first_backoff_s,
            max_backoff_s=lambda: self.settings.reconnect_max_backoff_s,
            on_failure=lambda _: self._enter(LinkState.RECONNECTING),
            on_success=lambda: logger.info("reconnected; motion stays held until resume()"),
            on_fatal=self._reconnection_failed,
            task_name="c500c-server-reconnect",
        )
        self._heartbeat_task: asyncio.Task[None] | None = None
        self._connected_event = asyncio.Event()
        self._last_write = 0.0  # loop time of the latest frame written
        self._bytes_sent = 0
        self._bytes_received = 0
        self.heartbeats = 0
        self.stray_replies = 0  # late replies of cancelled requests or an old link, dropped
        self._synchronised = False
        self._stall: str | None = None  # a move's reply that never came, until reconnected

    # --- lifecycle ---

    def _enter(self, state: LinkState) -> None:
        if state is self._link:
            return
        if state not in TRANSITIONS[self._link]:
            raise RuntimeError(
                f"C500C server link: no transition {self._link.value} -> {state.value}"
            )
        logger.debug("C500C server link: %s -> %s", self._link.value, state.value)
        self._link = state
        self.link_history.append(state)

    async def __aenter__(self) -> Self:
        self._enter(LinkState.CONNECTING)
        try:
            await self._connect()
        except BaseException:
            await self._close()
            raise
        self._heartbeat_task = asyncio.get_running_loop().create_task(
            self._heartbeats(), name="c500c-server-heartbeat"
        )
        return self

    async def _close(self) -> None:
        task, self._heartbeat_task = self._heartbeat_task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        await self._reconnector.cancel()
        self._drop_connection(NotConnectedError(DEVICE, "closed"))
        if self._link is not LinkState.DISCONNECTED:
            self._enter(LinkState.DISCONNECTED)
        self._connected_event.clear()

    async def _open_port(self) -> _Connection:
        # XON/XOFF stays off (drivers/serial_port.py): binary frames, 0x11/0x13 are data
        reader, writer = await open_serial(
            DEVICE,
            self.port,
            baudrate=self.settings.server_baudrate,
            bytesize=8,
            parity="N",
            stopbits=1,
            rtscts=False,  # the program turns flow control off (controller/PROTOCOL.md)
        )
        return _Connection(reader, writer)

    async def _connect(self) -> None:
        """Open the port and exchange one heartbeat: the program answers with its state."""
        connection = await self._open_port()
        self._synchronised = False  # until the handshake's reply: see _dispatch
        connection.task = asyncio.get_running_loop().create_task(
            self._read_replies(connection), name="c500c-server-reader"
        )
        self._connection = connection
        self._abandoned.clear()
        try:
            reply = await self._request(
                proto.RequestType.HEARTBEAT,
                timeout_s=self.settings.command_timeout_s,
                handshake=True,
            )
        except BaseException:
            self._drop_connection(NotConnectedError(DEVICE, "handshake failed"))
            raise
        self._enter(LinkState.CONNECTED)
        self._stall = None
        self._connected_event.set()
        logger.info(
            "connected to the C500C server program on %s (flags %s)", self.port, reply.flags
        )

    def _drop_connection(self, error: DeviceError) -> None:
        connection, self._connection = self._connection, None
        if connection is not None:
            connection.close()
            if connection.task is not None and connection.task is not asyncio.current_task():
                connection.task.cancel()
        pending, self._pending = self._pending, {}
        for _, future in pending.values():
            if not future.done():
                future.set_exception(error)

    # --- the reader: every reply to its request ---

    async def _read_replies(self, connection: _Connection) -> None:
        decoder = proto.FrameDecoder()
        try:
            while True:
                try:
                    chunk = await connection.reader.read(4096)
                except (OSError, serial.SerialException) as err:
                    raise _LinkFault(
                        NotConnectedError(DEVICE, f"link lost on {self.port}: {err}")
                    ) from err
                if not chunk:
                    raise _LinkFault(NotConnectedError(DEVICE, f"link closed on {self.port}"))
                self._bytes_received += len(chunk)
                for event in decoder.feed(chunk):
                    self._dispatch(event)
        except _LinkFault as fault:
            if self._connection is connection:
                self._link_fault(fault.error)

    def _dispatch(self, event: proto.Frame | proto.Discarded) -> None:
        if not self._synchronised:
            # Before the handshake's reply, bytes still in flight from an earlier connection
            # (a reply to a request of the link that failed) are dropped: resynchronising.
            reply = None
            if isinstance(event, proto.Frame):
                with contextlib.suppress(ProtocolError):
                    reply = proto.parse_reply(event)
            if reply is None or reply.sequence not in self._pending:
                self.stray_replies += reply is not None
                return
            self._synchronised = True
        if isinstance(event, proto.Discarded):
            # The line carries only frames: dropped bytes are a garbled reply, never a guess.
            raise _LinkFault(
                ProtocolError(DEVICE, f"{event.byte_count} bytes dropped ({event.reason})")
            )
        try:
            reply = proto.parse_reply(event)
        except ProtocolError as err:
            raise _LinkFault(err) from err
        outstanding = self._pending.pop(reply.sequence, None)
        if outstanding is None:
            if reply.sequence in self._abandoned:
                del self._abandoned[reply.sequence]
                self.stray_replies += 1
                return
            raise _LinkFault(
                ProtocolError(DEVICE, f"reply out of sequence: {reply.sequence} never asked")
            )
        request_type, future = outstanding
        if reply.request != request_type:
            raise _LinkFault(
                ProtocolError(
                    DEVICE,
                    f"reply {reply.sequence} is 0x{reply.request:02x}, not {request_type.name}",
                )
            )
        self._note_flags(reply.flags)
        if not future.done():
            future.set_result(reply)

    def _note_flags(self, flags: proto.Flag) -> None:
        self._flags = flags
        if flags & proto.Flag.HELD and not self.permit.held:
            reason = "host silent" if flags & proto.Flag.SILENCE_HALTED else "hold"
            self._hold(f"the controller program is holding motion ({reason})")

    # --- faults and reconnection ---

    def _hold(self, reason: str, *, error: bool = True) -> None:
        """Refuse motion from now on until resume() (synchronous). A requested hold (every
        run's end) is routine: logged at INFO, and not an error in ``last_error``."""
        if not self.permit.held:
            log = logger.warning if error else logger.info
            log("robot motion held until resume(): %s", reason)
        self.permit.hold(reason)
        if error:
            self._last_error = reason

    def _link_fault(self, error: DeviceError) -> None:
        """The link cannot be trusted: fail what is outstanding, hold motion, reconnect."""
        self._hold(str(error))
        self._drop_connection(error)
        self._connected_event.clear()
        if self._link is not LinkState.CONNECTED:
            return  # connecting: the handshake fails with the error; closed: nothing to do
        self._enter(LinkState.RECONNECTING)
        self._reconnector.start()

    # --- one request ---

    def _next_sequence(self) -> int:
        while True:
            sequence = next(self._sequence) % proto.SEQUENCE_MODULO
            if sequence not in self._pending and sequence not in self._abandoned:
                return sequence

    async def _request(
        self,
        request_type: proto.RequestType,
        offset: proto.Pose6 | None = None,
        *,
        timeout_s: float,
        handshake: bool = False,
        goal: int = 0,
        ticket: Ticket | None = None,
    ) -> proto.Reply:
        """Write one request and await its reply (other requests may be outstanding). A timeout
        or a garbled link is a link fault (the handshake's failure is its caller's). A cancelled
        request's sequence number is remembered so its late reply is dropped, not a fault."""
        connection = self._connection
        ready = self._link is LinkState.CONNECTED or (handshake and connection is not None)
        if connection is None or not ready:
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")
        sequence = self._next_sequence()
        data = proto.encode_request(
            sequence, request_type, offset, straight=self.settings.online, goal=goal
        )
        future: asyncio.Future[proto.Reply] = asyncio.get_running_loop().create_future()
        written = False
        try:
            async with self._write_lock:
                if request_type in _MOTION:
                    # The hold contract: checked under the lock, immediately before the write.
                    self._require_motion_allowed()
                if ticket is not None and not self.permit.is_current(ticket):
                    # a RELEASE for a request older than the latest hold is never written
                    self.permit.release(ticket)  # raises MotionHeldError
                if self._connection is not connection:
                    raise NotConnectedError(DEVICE, f"link lost on {self.port}")
                # checked again with the write, atomic against a hold from another thread
                with self.permit.guard(request_type in _MOTION, ticket):
                    self._pending[sequence] = (request_type, future)
                    connection.writer.write(data)
                written = True
                self._last_write = asyncio.get_running_loop().time()
                self._bytes_sent += len(data)
            try:
                async with asyncio.timeout(timeout_s):
                    return await future
            except TimeoutError as err:
                error = DeviceTimeoutError(
                    DEVICE, f"no reply {timeout_s:g} s after {request_type.name} #{sequence}"
                )
                if not handshake:
                    if request_type in _MOTION:
                        self._stall = str(error)  # reported "stalled" until reconnected
                    self._link_fault(error)
                raise error from err
        except asyncio.CancelledError:
            if written and self._pending.pop(sequence, None) is not None:
                self._abandoned[sequence] = None
                while len(self._abandoned) > ABANDONED_LIMIT:
                    del self._abandoned[next(iter(self._abandoned))]
            raise
        finally:
            self._pending.pop(sequence, None)

    def _reconnection_failed(self, error: BaseException) -> None:
        """The reconnection ended on an unexpected error (logged with its traceback): the
        link is failed, motion held, until it is closed and opened again."""
        self._hold(f"the reconnection failed: {error!r}")
        self._enter(LinkState.FAULT)

    def _reported_link(self) -> LinkState:
        """``stalled`` after a move's reply timed out, until connected again."""
        if self._stall is not None and self._link is not LinkState.CONNECTED:
            return LinkState.STALLED
        return self._link

    def _require_motion_allowed(self) -> None:
        self.permit.require()
        if self._link is not LinkState.CONNECTED:
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")

    async def _heartbeats(self) -> None:
        """A HEARTBEAT whenever nothing was written for heartbeat_s, so the program's silence
        timeout only strikes when the host is really gone (PROTOCOL.md "Silence")."""
        loop = asyncio.get_running_loop()
        period_s = self.settings.heartbeat_s
        while True:
            idle_s = loop.time() - self._last_write
            if idle_s < period_s:
                await asyncio.sleep(period_s - idle_s)
                continue
            if self._link is not LinkState.CONNECTED:
                await asyncio.sleep(period_s)
                continue
            with contextlib.suppress(DeviceError):
                await self._request(
                    proto.RequestType.HEARTBEAT, timeout_s=self.settings.command_timeout_s
                )
                self.heartbeats += 1
