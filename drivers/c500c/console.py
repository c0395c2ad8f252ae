"""One open C500C console link: bytes out and in (counted, optionally transcribed), and a
command's reply read up to its prompt, with the point-of-control wait and the questions, and the
probe-line synchronisation that finds where the console's output ends.

The console link (drivers/c500c/link.py) builds its state machine on this; ``thermocomp robot check
--transcript FILE`` writes the :class:`Transcript`, and tests replay one (every byte the host
sends must be the recorded one, every recorded answer is fed back).

A transcript file is JSON lines, one per chunk in the order it crossed the line:
``{"t": seconds since the port opened, "dir": "host" | "console", "data": "..."}`` where
``data`` holds the exact bytes as a latin-1 string (JSON escapes CR, LF and Ctrl-E).
"""

from __future__ import annotations

import asyncio
import functools
import json
import re
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from drivers.c500c import protocol as proto
from drivers.errors import (
    DeviceError,
    DeviceTimeoutError,
    NotConnectedError,
    PointOfControlError,
    ProtocolError,
)

DEVICE = proto.DEVICE
#: An unrecognised question (a line ending in "? " or ": " without a line end) is taken as one
#: when nothing more arrives for this long (s); a known question is recognised at once.
QUESTION_SETTLE_S = 0.5
#: Probe lines tried before synchronisation gives up (each waits robot.command_timeout_s).
SYNC_ATTEMPTS = 3

Direction = Literal["host", "console"]


class LinkLost(Exception):
    """The port closed or failed under us (internal; surfaces as NotConnectedError)."""


@dataclass(frozen=True, slots=True)
class TranscriptEntry:
    t_s: float
    direction: Direction
    data: bytes

    def as_json(self) -> str:
        return json.dumps(
            {"t": round(self.t_s, 6), "dir": self.direction, "data": self.data.decode("latin-1")}
        )


@dataclass
class Transcript:
    """Every byte exchanged with the console, in order."""

    entries: list[TranscriptEntry] = field(default_factory=list)
    started_s: float = field(default_factory=time.perf_counter)

    def record(self, direction: Direction, data: bytes) -> None:
        self.entries.append(TranscriptEntry(time.perf_counter() - self.started_s, direction, data))

    def sent(self) -> bytes:
        return b"".join(e.data for e in self.entries if e.direction == "host")

    def received(self) -> bytes:
        return b"".join(e.data for e in self.entries if e.direction == "console")

    def write(self, path: Path) -> None:
        path.write_text("".join(entry.as_json() + "\n" for entry in self.entries), "utf-8")

    @classmethod
    def read(cls, path: Path) -> Transcript:
        return cls.from_lines(path.read_text("utf-8").splitlines())

    @classmethod
    def from_lines(cls, lines: Iterable[str]) -> Transcript:
        entries = []
        for number, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                item = json.loads(line)
                direction = item["dir"]
                if direction not in ("host", "console"):
                    raise ValueError(f"dir must be host or console, not {direction!r}")
                entries.append(
                    TranscriptEntry(float(item["t"]), direction, item["data"].encode("latin-1"))
                )
            except (ValueError, KeyError, TypeError, UnicodeEncodeError) as err:
                raise ValueError(f"transcript line {number}: {err}") from err
        return cls(entries=entries)

    def exchanges(self) -> list[tuple[bytes, bytes]]:
        """The transcript as (what the host wrote, everything the console answered before the
        host's next write): the script of a replay."""
        script: list[tuple[bytes, bytes]] = []
        answer_before = b""
        for entry in self.entries:
            if entry.direction == "host":
                script.append((entry.data, b""))
            elif script:
                sent, answer = script[-1]
                script[-1] = (sent, answer + entry.data)
            else:
                answer_before += entry.data  # printed before the host said anything
        if answer_before and script:
            raise ValueError("the console spoke before the host's first write")
        return script


@dataclass
class ByteCounters:
    """Bytes moved over every connection of one driver."""

    sent: int = 0
    received: int = 0


class Connection:
    """An open port as a reader and a writer, and a pending buffer of what was read but not yet
    consumed (the next command's reply, when commands were written together)."""

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        transcript: Transcript | None = None,
        counters: ByteCounters | None = None,
    ) -> None:
        self.reader = reader
        self.writer = writer
        self.transcript = transcript
        self.counters = counters if counters is not None else ByteCounters()
        self.pending = bytearray()

    def write(self, data: bytes) -> None:
        """Hand ``data`` to the transport: synchronous, so no other task can write in between."""
        self.writer.write(data)
        self.counters.sent += len(data)
        if self.transcript is not None:
            self.transcript.record("host", data)

    async def read_more(self) -> bytes:
        """Wait for the next chunk and append it to ``pending`` (cancellation-safe: a cancelled
        read consumes nothing)."""
        try:
            chunk = await self.reader.read(4096)
        except OSError as err:
            raise LinkLost(str(err)) from err
        if not chunk:
            raise LinkLost("end of file")
        self.pending += chunk
        self.counters.received += len(chunk)
        if self.transcript is not None:
            self.transcript.record("console", chunk)
        return chunk

    def take(self, end: int) -> bytes:
        """Remove and return the first ``end`` pending bytes."""
        data = bytes(self.pending[:end])
        del self.pending[:end]
        return data

    def close(self) -> None:
        transport = self.writer.transport
        if not transport.is_closing():  # a lost port has already closed its transport
            transport.abort()


# --- reading replies ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Prompts:
    """The prompts that end a reply: the application's `ash` prompt (both forms) and the
    system shell's `$ ` (ash exited or the controller restarted)."""

    ash: re.Pattern[bytes]

    @classmethod
    def of(cls, application: str) -> Prompts:
        return cls(proto.prompt_pattern(application))

    def first(self, buffer: bytes) -> tuple[int, bool] | None:
        """The end of the first reply in ``buffer`` and whether the shell's prompt ended it."""
        ash = proto.find_prompt(buffer, self.ash)
        shell = proto.find_shell_prompt(buffer)
        if shell is not None and (ash is None or shell < ash):
            return shell, True
        if ash is not None:
            return ash, False
        return None

    def end_of_answer(self, buffer: bytes) -> int | None:
        """Where the console's answer to a question's answer ends: a prompt, or another
        question."""
        found = self.first(buffer)
        if found is not None:
            return found[0]
        return len(buffer) if proto.find_question(buffer) is not None else None


class QuestionAsked(Exception):
    """The console asked a question instead of answering (internal; the link answers it or
    interrupts it and raises ConsoleQuestionError)."""

    def __init__(self, text: str, question: proto.Question | None) -> None:
        super().__init__(text)
        self.text = text
        self.question = question


@dataclass(frozen=True, slots=True)
class ReadOptions:
    """How long to wait: for a reply, and for the operator once the controller asked for the
    PAUSE/CONTINUE button; and who to tell when the wait for the operator starts and ends."""

    timeout_s: float
    point_of_control_timeout_s: float
    on_waiting_for_operator: Callable[[], None]
    on_operator_done: Callable[[], None]


async def read_until(
    connection: Connection,
    complete: Callable[[bytes], int | None],
    timeout_s: float,
    what: str,
    port: str,
) -> int:
    """Read until ``complete(pending)`` gives the end index of a reply."""
    try:
        async with asyncio.timeout(timeout_s):
            while (end := complete(bytes(connection.pending))) is None:
                chunk = await connection.read_more()
                if not proto.is_console_text(chunk):  # garbage: say so now, not at timeout
                    raise ProtocolError(
                        DEVICE, f"{what}: unexpected bytes: {bytes(connection.pending)!r}"
                    )
    except TimeoutError as err:
        raise DeviceTimeoutError(
            DEVICE, f"no answer {timeout_s:g} s after {what} (got {bytes(connection.pending)!r})"
        ) from err
    except LinkLost as err:
        raise NotConnectedError(DEVICE, f"link lost on {port} during {what}") from err
    return end


async def synchronise(
    connection: Connection,
    prompts: re.Pattern[bytes],
    next_probe: Callable[[], str],
    timeout_s: float,
    *,
    port: str,
    application: str,
) -> bytes:
    """Bring the console to a clean prompt: Ctrl-E and a probe line; the reply is complete at
    the prompt (one of ``prompts``) after the probe's echo (ASSUMED 6). Bounded: SYNC_ATTEMPTS
    probes (``next_probe()`` names each), each waiting ``timeout_s`` (the first after Ctrl-E,
    the others alone). Returns the bytes taken, up to and including that prompt; whatever came
    before the probe's echo is discarded with them."""
    last: DeviceError | None = None
    for attempt in range(SYNC_ATTEMPTS):
        probe = next_probe()
        # Ctrl-E first ends a continuous display; a retry goes alone (ASSUMED 6)
        interrupt = proto.CTRL_E if attempt == 0 else b""
        connection.write(interrupt + proto.encode_command(probe))
        try:
            end = await read_until(
                connection,
                functools.partial(proto.find_probe_answer, probe=probe, prompt=prompts),
                timeout_s,
                f"synchronisation probe {probe!r}",
                port,
            )
        except DeviceTimeoutError as err:
            last = err
            continue
        return connection.take(end)
    tail = proto.pending_line(bytes(connection.pending))
    hint = (
        f"; the console's prompt is {tail!r}, not {application!r}: check robot.application"
        if tail.endswith("> ")
        else ""
    )
    raise DeviceTimeoutError(
        DEVICE, f"console not synchronised after {SYNC_ATTEMPTS} probe lines{hint}: {last}"
    )


async def read_reply(
    connection: Connection,
    prompts: Prompts,
    command: str,
    options: ReadOptions,
    port: str,
) -> tuple[bytes, bool]:
    """The bytes of ``command``'s reply up to its prompt (the rest stays pending), and whether
    the system shell's prompt ended it.

    The PAUSE/CONTINUE request means the controller waits for the operator
    (docs/reference/c500c-console.md "Point of control"): the deadline becomes
    ``point_of_control_timeout_s`` and the callbacks say when the wait starts and ends; past it,
    PointOfControlError. A question raises QuestionAsked at once when known, after QUESTION_SETTLE_S
    of silence when it only looks like one."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + options.timeout_s
    awaiting_operator = False
    try:
        while True:
            buffer = bytes(connection.pending)
            found = prompts.first(buffer)
            before_prompt = buffer if found is None else buffer[: found[0]]
            if not awaiting_operator and proto.needs_point_of_control(before_prompt):
                awaiting_operator = True
                options.on_waiting_for_operator()
                deadline = loop.time() + options.point_of_control_timeout_s
            if found is not None:
                end, at_shell = found
                if awaiting_operator:
                    options.on_operator_done()
                return connection.take(end), at_shell
            question = proto.find_question(buffer)
            if question is not None:
                raise QuestionAsked(question.text, question)
            remaining = deadline - loop.time()
            if remaining <= 0:
                if awaiting_operator:
                    raise PointOfControlError(
                        DEVICE,
                        f"nobody pressed PAUSE/CONTINUE within "
                        f"{options.point_of_control_timeout_s:g} s after {command!r}",
                    )
                raise DeviceTimeoutError(
                    DEVICE, f"no prompt {options.timeout_s:g} s after {command!r} (got {buffer!r})"
                )
            maybe_question = proto.may_be_question(buffer)
            wait_s = min(remaining, QUESTION_SETTLE_S) if maybe_question else remaining
            try:
                # asyncio.timeout, not wait_for: on Python 3.11 wait_for swallows a
                # cancellation that lands as the read completes (a chunk arriving just then),
                # and a cancelled command then ran on to its timeout (tests/contract/)
                async with asyncio.timeout(wait_s):
                    chunk = await connection.read_more()
            except TimeoutError:
                if maybe_question and bytes(connection.pending) == buffer:
                    raise QuestionAsked(proto.pending_line(buffer), None) from None
                continue
            if not proto.is_console_text(chunk):  # garbage: say so now, not at timeout
                raise ProtocolError(
                    DEVICE, f"{command!r}: unexpected bytes in reply: {bytes(connection.pending)!r}"
                )
    except LinkLost as err:
        raise NotConnectedError(DEVICE, f"link lost on {port} during {command!r}") from err


async def answer_question(
    connection: Connection, prompts: Prompts, asked: QuestionAsked, timeout_s: float, port: str
) -> bool:
    """Give a known question its deliberate answer and wait for the prompt after it; anything
    else (or an answer that does not bring a prompt back) gets Ctrl-E. Returns whether the
    console is back at a prompt; if not, the link must be resynchronised."""
    connection.take(len(connection.pending))
    question = asked.question
    if question is not None and question.answer is not None:
        connection.write(proto.encode_command(question.answer))
        try:
            end = await read_until(
                connection,
                prompts.end_of_answer,
                timeout_s,
                f"the answer {question.answer!r}",
                port,
            )
        except DeviceTimeoutError:
            pass  # no prompt after the answer: interrupt it below
        else:
            if proto.find_question(connection.take(end)) is None:
                return True
    connection.write(proto.CTRL_E)
    return False
