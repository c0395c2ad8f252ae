"""The emulated controller running controller/thermocomp_server.r3: the fast path's binary
protocol (controller/PROTOCOL.md) on a real pseudo-terminal or a TCP port.

It is the console emulator (drivers/sim/emulator.py) with another conversation: the pty or TCP
link, the symlink that survives a `close` fault, the baud-rate pacing, and above all the arm —
`Console`, its state, its motion time, its positioning noise, its reach, power, homed and online
checks — are the console emulator's own, reused by subclassing and by running the motion
through ``Console.execute("moves cur")``; only the framing differs. Like the RAPL-3 program it
serves frames while a move runs (the program polls the port between ``robotisfinished()``
checks), so a HOLD halts the move: the move is answered with catalogue 044 `Halt() command
invoked`. If the host is silent longer than ``silence_timeout_s`` it halts and holds until a
RELEASE.

Emulator simplification (as the console emulator's): without an arm a halted move leaves the
arm where it started (the emulated arm jumps to its target when the move time has passed); with
one (joint space, drivers/sim/joint_arm.py) the arm stops where its joints are.

Faults (strike the reply of the N-th non-heartbeat request, or ``inject()`` for the next
request of any type): crc (one CRC byte flipped), short (only the first half of the reply,
then nothing), sequence (the reply carries a sequence number the host never used), silence
(no reply to this request and nothing read or answered for SECONDS), close (the link closes).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
from collections import deque
from collections.abc import Awaitable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, Protocol, Self

from config import faults as fault_specs
from config.faults import Fault
from drivers.c500c import protocol as console_proto
from drivers.c500c import server_protocol as proto
from drivers.errors import ProtocolError
from drivers.sim.emulator import C500CEmulator, EmulatorConfig
from drivers.sim.emulator_link import BITS_PER_CHARACTER, Link, LinkClosed

logger = logging.getLogger(__name__)

#: The program's constant (controller/thermocomp_server.r3 SILENCE_MS) in seconds.
DEFAULT_SILENCE_TIMEOUT_S = 1.0
#: The fast path's port speed (docs/reference/c500c-console.md: the repository's programs open
#: /dev/sio1 at 115200).
SERVER_BAUDRATE = 115200
#: How long a `silence` fault lasts when the spec gives no duration (s).
DEFAULT_SILENCE_FAULT_S = 5.0
#: Names of the goal and the per-step target among the console's locations.
GOAL_LOCATION = "opgoal"
TARGET_LOCATION = "cur"
#: Requests the emulator keeps for inspection (tests): the latest ones only.
REQUEST_LOG = 10_000


class _Answer(Protocol):
    """How a request is answered: the reply's bytes, and the loop time before which its first
    byte cannot go out (None: once the request has arrived)."""

    def __call__(self, data: bytes, not_before: float | None = None) -> Awaitable[None]: ...


ServerFaultKind = Literal["crc", "short", "sequence", "silence", "close"]
SERVER_FAULT_KINDS: tuple[ServerFaultKind, ...] = ("crc", "short", "sequence", "silence", "close")


def parse_server_faults(spec: str) -> tuple[Fault[ServerFaultKind], ...]:
    """``KIND[=SECONDS][@N|%P],...`` (config/faults.py) with the kinds above; @N counts the
    non-heartbeat requests (heartbeats come on a timer, so counting them is not reproducible)."""
    return fault_specs.parse_faults(spec, SERVER_FAULT_KINDS)


@dataclass(frozen=True, slots=True)
class ServerEmulatorConfig:
    """``console``: the arm and the link (seed, noise, move time, baud rate, pacing...)."""

    console: EmulatorConfig = field(
        default_factory=lambda: EmulatorConfig(baudrate=SERVER_BAUDRATE, online=True)
    )
    silence_timeout_s: float = DEFAULT_SILENCE_TIMEOUT_S
    faults: tuple[Fault[ServerFaultKind], ...] = ()


def goal_location(index: int) -> str:
    """The console location the program's goal ``index`` is kept in (goal 0: `opgoal`)."""
    return GOAL_LOCATION if index == 0 else f"{GOAL_LOCATION}{index}"


def _catalogue_code(lines: list[str]) -> int:
    """The catalogue number of the console's error line (the program passes it through)."""
    text = " ".join(lines)
    for code, message in console_proto.MOTION_ERRORS.items():
        if re.search(re.escape(message).replace(r"\$1", r"\d+"), text):
            return code
    return proto.Status.BAD_REQUEST


class C500CServerEmulator(C500CEmulator):
    """The emulated C500C running the thermocomp server program (a pty by default)."""

    def __init__(
        self,
        config: ServerEmulatorConfig | None = None,
        *,
        transport: Literal["pty", "tcp"] = "pty",
        tcp_port: int = 0,
        link_path: Path | None = None,
    ) -> None:
        self.server_config = config or ServerEmulatorConfig()
        # The program turns online mode on at start (as robot_control_server.r3 does): straight
        # moves never fail with 043 unless a test turns it off again.
        console = replace(self.server_config.console, online=True, faults=())
        super().__init__(console, transport=transport, tcp_port=tcp_port, link_path=link_path)
        self.held = False
        self.silence_halted = False
        self.halts = 0  # moves halted (HOLD or silence)
        self.requests: deque[proto.Request] = deque(maxlen=REQUEST_LOG)
        self.discarded: list[proto.Discarded] = []
        self.server_faults_applied: list[tuple[int, ServerFaultKind]] = []
        self._server_faults = list(self.server_config.faults)
        self._server_pending: list[Fault[ServerFaultKind]] = []
        # reply gate (tests): every reply waits while it is closed, as the console emulator's
        self._replies_open = asyncio.Event()
        self._replies_open.set()
        self.reply_held = asyncio.Event()  # set once a reply waits at the gate
        self._counted_requests = 0
        self._move_task: asyncio.Task[None] | None = None
        self._halt = asyncio.Event()
        #: Set when a move has started (tests wait for it instead of sleeping).
        self.motion_started = asyncio.Event()
        #: Set when a move has been halted (cleared when the next move starts).
        self.motion_halted = asyncio.Event()
        self._last_heard: float | None = None
        self._silent_until = 0.0
        self._watchdog: asyncio.Task[None] | None = None

    # --- control from tests ---

    def inject_server_fault(self, kind: ServerFaultKind, seconds: float | None = None) -> None:
        """Apply ``kind`` to the reply of the next request (heartbeats included)."""
        self._server_pending.append(Fault(kind, seconds))

    def hold_replies(self) -> None:
        """Tests: every reply from now on waits until :meth:`release_replies` (the requests
        are still read and served: a command in flight)."""
        self._replies_open.clear()
        self.reply_held.clear()

    def release_replies(self) -> None:
        self._replies_open.set()

    @property
    def moving(self) -> bool:
        return self._move_task is not None and not self._move_task.done()

    @property
    def goal(self) -> proto.Pose6 | None:
        """Goal 0 (the default goal), if taught."""
        return self.state.locations.get(GOAL_LOCATION)

    def goal_at(self, index: int) -> proto.Pose6 | None:
        """Goal ``index`` (PROTOCOL.md "Goals"), if taught."""
        return self.state.locations.get(goal_location(index))

    # --- lifecycle ---

    async def __aenter__(self) -> Self:
        await super().__aenter__()
        self._watchdog = asyncio.get_running_loop().create_task(self._watch_silence())
        return self

    async def aclose(self) -> None:
        for task in (self._watchdog, self._move_task):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        await super().aclose()

    # --- the silence watchdog (PROTOCOL.md "Silence") ---

    async def _watch_silence(self) -> None:
        loop = asyncio.get_running_loop()
        timeout_s = self.server_config.silence_timeout_s
        while True:
            await asyncio.sleep(min(timeout_s / 4, 0.05))
            if self._last_heard is None or self.held:
                continue
            if loop.time() - self._last_heard > timeout_s:
                # Let the reader drain what the loop may have queued while this task waited
                # (emulator and host share one loop on the bench); then judge again.
                await asyncio.sleep(0.01)
                if self._last_heard is not None and loop.time() - self._last_heard > timeout_s:
                    logger.warning("host silent for %.2f s: halting and holding", timeout_s)
                    self._enter_hold(silence=True)

    def _enter_hold(self, *, silence: bool) -> None:
        self.held = True
        self.silence_halted = self.silence_halted or silence
        if self.moving:
            self._halt.set()

    # --- the conversation ---

    def _flags(self) -> proto.Flag:
        flags = proto.Flag(0)
        if any(goal_location(i) in self.state.locations for i in range(proto.MAX_GOALS)):
            flags |= proto.Flag.GOAL_TAUGHT
        if self.held:
            flags |= proto.Flag.HELD
        if self.moving:
            flags |= proto.Flag.MOVING
        if self.state.point_of_control:
            flags |= proto.Flag.POINT_OF_CONTROL
        if self.silence_halted:
            flags |= proto.Flag.SILENCE_HALTED
        return flags

    def _reply(self, sequence: int, request: int, status: int) -> bytes:
        return proto.encode_reply(sequence, request, status, self._flags(), self.actual_pose())

    def _server_fault_for(self, request: proto.Request | None) -> Fault[ServerFaultKind] | None:
        if self._server_pending:
            return self._server_pending.pop(0)
        if request is None or request.type is proto.RequestType.HEARTBEAT:
            return None
        self._counted_requests += 1
        for fault in self._server_faults:
            if fault.strikes(self._counted_requests, self._fault_rng):
                return fault
        return None

    async def _session(self, link: Link) -> None:
        # Pacing is bookkeeping plus one timer per reply: a request is read at once but counts
        # as arrived when its last byte would have (``arrived``); its reply goes out when its
        # own last byte would have left. A timer per direction would add the event loop's
        # timer granularity (epoll: 1 ms) twice per exchange, which no real line has.
        byte_s = BITS_PER_CHARACTER / self.config.baudrate if self.config.paced else 0.0
        line_free_at = 0.0  # when the last byte written so far has left (loop time)
        in_free_at = 0.0  # when the last byte read so far has arrived (loop time)
        decoder = proto.FrameDecoder()
        write_lock = asyncio.Lock()
        loop = asyncio.get_running_loop()

        async def send(data: bytes, not_before: float | None) -> None:
            """Write ``data`` once its last byte would have crossed the line: it starts when
            the line is free, and not before ``not_before`` (a move's reply is framed when the
            motion ends, so its line time may already have passed: no second timer)."""
            nonlocal line_free_at
            if not self._replies_open.is_set():
                self.reply_held.set()
                await self._replies_open.wait()
            async with write_lock:  # one frame at a time on the wire, never interleaved
                start = max(line_free_at, loop.time() if not_before is None else not_before)
                line_free_at = start + len(data) * byte_s
                delay_s = line_free_at - loop.time()
                if delay_s > 0:
                    await asyncio.sleep(delay_s)
                await link.write(data)

        async def answer(
            data: bytes, fault: Fault[ServerFaultKind] | None, not_before: float | None
        ) -> None:
            if fault is None:
                await send(data, not_before)
            elif fault.kind == "crc":
                await send(data[:-1] + bytes([data[-1] ^ 0xFF]), not_before)
            elif fault.kind == "short":
                await send(data[: len(data) // 2], not_before)
            elif fault.kind == "sequence":
                frame = proto.decode_frame(data)
                stray = (frame.sequence + proto.SEQUENCE_MODULO // 2) % proto.SEQUENCE_MODULO
                await send(proto.encode_frame(stray, frame.type, frame.body), not_before)
            # silence: the reply is never sent (the link was already marked silent)

        def replier(fault: Fault[ServerFaultKind] | None, arrived: float) -> _Answer:
            async def reply(data: bytes, not_before: float | None = None) -> None:
                await answer(data, fault, arrived if not_before is None else not_before)

            return reply

        try:
            while True:
                chunk = await link.read()
                if not chunk:
                    return
                in_free_at = max(in_free_at, loop.time()) + len(chunk) * byte_s
                arrived = in_free_at
                if loop.time() < self._silent_until:
                    continue  # a silent controller drops what it is sent
                self._last_heard = loop.time()
                for event in decoder.feed(chunk):
                    if isinstance(event, proto.Discarded):
                        self.discarded.append(event)
                        logger.info("discarded %d bytes (%s)", event.byte_count, event.reason)
                        continue
                    try:
                        request: proto.Request | None = proto.parse_request(event)
                    except ProtocolError:
                        request = None
                    fault = self._server_fault_for(request)
                    if fault is not None:
                        self.server_faults_applied.append((self._counted_requests, fault.kind))
                        logger.info("injecting %s into the reply to %s", fault.kind, request)
                        if fault.kind == "close":
                            link.close()
                            raise LinkClosed
                        if fault.kind == "silence":
                            seconds = fault.seconds or DEFAULT_SILENCE_FAULT_S
                            self._silent_until = loop.time() + seconds
                    if request is None:
                        reply = self._reply(event.sequence, event.type, proto.Status.BAD_REQUEST)
                        await answer(reply, fault, arrived)
                        continue
                    self.requests.append(request)
                    await self._serve(request, replier(fault, arrived), arrived)
                    if loop.time() < self._silent_until:
                        break
        except LinkClosed:
            return

    async def _serve(
        self,
        request: proto.Request,
        answer: _Answer,
        arrived: float,
    ) -> None:
        """Serve one request; ``arrived``: when its last byte arrived (paced loop time)."""
        kind = proto.RequestType
        seq, request_type = request.sequence, request.type
        if request_type is kind.HEARTBEAT or request_type is kind.READ_POSE:
            await answer(self._reply(seq, request_type, proto.Status.OK))
        elif request_type is kind.TEACH_GOAL:
            # here(opgoal): the goal is where the arm is now (a move in progress is refused).
            status = proto.Status.BUSY if self.moving else proto.Status.OK
            if status == proto.Status.OK:
                self.state.locations[goal_location(request.goal)] = self.actual_pose()
            await answer(self._reply(seq, request_type, status))
        elif request_type is kind.HOLD:
            early_s = arrived - asyncio.get_running_loop().time()
            if early_s > 0:
                await asyncio.sleep(early_s)  # a halt never precedes its frame's last byte
            self._enter_hold(silence=False)
            await answer(self._reply(seq, request_type, proto.Status.OK))
        elif request_type is kind.RELEASE:
            self.held = False
            self.silence_halted = False
            await answer(self._reply(seq, request_type, proto.Status.OK))
        else:
            refusal = self._motion_refusal(request)
            if refusal is not None:
                await answer(self._reply(seq, request_type, refusal))
                return
            self._halt.clear()
            self.motion_started.clear()
            self.motion_halted.clear()
            self._move_task = asyncio.get_running_loop().create_task(
                self._move(request, answer, arrived)
            )

    def _motion_refusal(self, request: proto.Request) -> int | None:
        if self.held:
            return proto.Status.HELD
        if self.moving:
            return proto.Status.BUSY
        if request.type is proto.RequestType.MOVE_GOAL and self.goal_at(request.goal) is None:
            return proto.Status.NO_GOAL
        if not self.state.point_of_control:
            return proto.Status.NO_CONTROL
        return None

    async def _move(self, request: proto.Request, answer: _Answer, arrived: float) -> None:
        assert request.offset is not None
        state = self.state
        moves_to_goal = request.type is proto.RequestType.MOVE_GOAL
        base = self.goal_at(request.goal) if moves_to_goal else self.actual_pose()
        assert base is not None
        # shift_w(cur, offset): world-frame shift of every coordinate
        # (docs/reference/c500c-console.md `wshift`).
        state.locations[TARGET_LOCATION] = self.console.shift_location(base, request.offset)
        # The motion starts once the request has arrived (paced line), in both arm models.
        self.console.motion_not_before = arrived
        lines = await self.console.execute(f"{'moves' if request.straight else 'move'} cur")
        status: int = proto.Status.OK
        ended: float | None = None
        if lines:
            status = _catalogue_code(lines)
        else:
            loop = asyncio.get_running_loop()
            loop.call_at(arrived, self.motion_started.set)
            ended = state.motion_end_s
            # One timer to the end of the reply's line time (the reply is framed when the
            # motion ends); a halt before the motion's end wakes it early.
            reply_s = proto.REPLY_BYTES * BITS_PER_CHARACTER / self.config.baudrate
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout_at(ended + (reply_s if self.config.paced else 0.0)):
                    await self._halt.wait()
            if self._halt.is_set() and loop.time() < ended:
                # halt(): the arm stops where it is (an emulator without an arm: where the
                # move started; with one: where its joints are, drivers/sim/joint_arm.py).
                ended = loop.time()
                self.console.halt_motion(ended)
                self.halts += 1
                self.motion_halted.set()
                status = proto.Status.HALTED
        self._move_task = None  # answered below: MOVING is clear in this reply's flags
        await answer(self._reply(request.sequence, request.type, status), ended)


def server_emulator_config(
    *,
    seed: int = 1,
    noise_um: float = 0.9,
    move_ms: float = 5.0,
    baudrate: int = SERVER_BAUDRATE,
    paced: bool = True,
    silence_timeout_s: float = DEFAULT_SILENCE_TIMEOUT_S,
    faults: str = "",
) -> ServerEmulatorConfig:
    """A :class:`ServerEmulatorConfig` from the command line's or the settings' plain values."""
    if noise_um < 0 or move_ms < 0 or silence_timeout_s <= 0:
        raise ValueError("noise and move time must not be negative, the silence timeout > 0")
    console = replace(
        EmulatorConfig(),
        seed=seed,
        noise_um=noise_um,
        move_ms=move_ms,
        baudrate=baudrate,
        paced=paced,
        online=True,
    )
    return ServerEmulatorConfig(
        console=console, silence_timeout_s=silence_timeout_s, faults=parse_server_faults(faults)
    )
