"""The fast path's binary protocol (controller/PROTOCOL.md) as pure functions: frames, CRC,
requests, replies and a streaming decoder that resynchronises after garbage.

No I/O here: the host driver (drivers/c500c/server.py), the emulator
(drivers/sim/server_emulator.py) and the tests build on these functions; the RAPL-3 program
(controller/thermocomp_server.r3) implements the same specification on the controller.

Frame (every multi-byte field little-endian, the 486's own byte order):

    A5 5A | LEN (1) | SEQ (2) | TYPE (1) | BODY (LEN bytes) | CRC (2)

CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor) over LEN, SEQ, TYPE
and BODY; check value of ``b"123456789"`` is 0x29B1.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from drivers.errors import ProtocolError

DEVICE = "robot"

SYNC = b"\xa5\x5a"
#: Sync (2) + LEN (1) + SEQ (2) + TYPE (1) before the body, CRC (2) after it.
HEADER_BYTES = 6
CRC_BYTES = 2
FRAME_OVERHEAD_BYTES = HEADER_BYTES + CRC_BYTES
#: No frame of the protocol has a longer body; a larger LEN is garbage (resynchronise at once
#: instead of waiting for 255 bytes that never come).
MAX_BODY_BYTES = 32
#: Sequence numbers are 16 bits and wrap; the host never reuses one still outstanding.
SEQUENCE_MODULO = 1 << 16
#: Replies carry the request's type with this bit set.
REPLY_BIT = 0x80

#: Fixed-point units on the wire: 0.1 um and 0.0001 degree per count (int32, +-214 m range).
#: Ten times finer than the console's 0.001 mm (docs/reference/c500c-console.md `%+10.3f`), so the
#: fast path never rounds an offset the thesis's model asks for (sub-micrometre, thesis 6.4.4).
COUNTS_PER_MM = 10_000
COUNTS_PER_DEG = 10_000
_INT32_MIN, _INT32_MAX = -(1 << 31), (1 << 31) - 1

CRC_INIT = 0xFFFF
CRC_POLY = 0x1021


class RequestType(enum.IntEnum):
    HEARTBEAT = 0x01
    TEACH_GOAL = 0x02  # here(goal k): goal k (0 if no body) is the pose now
    MOVE_GOAL = 0x03  # goal k shifted by the offset, in world coordinates (thesis 6.4.4)
    MOVE_RELATIVE = 0x04  # the actual pose shifted by the offset (incremental, thesis 6.4.4)
    READ_POSE = 0x05
    HOLD = 0x06  # halt() a motion in progress; refuse motion until RELEASE
    RELEASE = 0x07


class Status(enum.IntEnum):
    """Reply status. 1..999 are the controller's motion catalogue numbers passed through
    (docs/reference/c500c-console.md: 001, 003, 005, 007, 015, 027, 043, 044); the program's own
    codes are >= 1000."""

    OK = 0
    HALTED = 44  # catalogue 044 `Halt() command invoked`: a hold or the silence timeout
    NO_GOAL = 1001  # a move to a goal never taught
    HELD = 1002  # motion refused: held (HOLD or silence) until RELEASE
    BAD_REQUEST = 1003  # unknown type or wrong body length
    NO_CONTROL = 1004  # the program could not take the point of control
    BUSY = 1005  # a motion request while a motion is still in progress


#: Texts of the program's own codes (catalogue texts are in drivers/c500c/protocol.py).
STATUS_TEXTS: dict[int, str] = {
    Status.NO_GOAL: "that goal was never taught",
    Status.HELD: "motion held until release",
    Status.BAD_REQUEST: "bad request",
    Status.NO_CONTROL: "the program has no point of control",
    Status.BUSY: "a motion is already in progress",
}


class Flag(enum.IntFlag):
    """State bits in every reply."""

    GOAL_TAUGHT = 0x01  # at least one goal is taught (a restarted program has none)
    HELD = 0x02
    MOVING = 0x04
    POINT_OF_CONTROL = 0x08
    SILENCE_HALTED = 0x10  # the hold came from the host's silence, not from a HOLD request


#: Body layouts (after SEQ and TYPE).
MOVE_BODY = struct.Struct("<6iB")  # offset x, y, z (0.1 um), z-rot, y-rot, x-rot (1e-4 deg), mode
#: The goal index that may follow a MOVE_GOAL body or be a TEACH_GOAL's body (PROTOCOL.md
#: "Goals"): absent, the goal is 0, so the default goal's frames are those of a single goal.
GOAL_INDEX = struct.Struct("<B")
#: Goals the program holds: indices 0 .. MAX_GOALS - 1 (thermocomp_server.r3 MAX_GOALS).
MAX_GOALS = 16
REPLY_BODY = struct.Struct("<HB6i")  # status, flags, actual pose x..x-rot
_HEADER = struct.Struct("<2sBHB")
_CRC = struct.Struct("<H")

#: MOVE mode byte: 1 = straight line (`moves`, needs online mode), 0 = joint-interpolated.
MODE_STRAIGHT = 1
MODE_JOINT = 0

Pose6 = tuple[float, float, float, float, float, float]


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ CRC_POLY) if crc & 0x8000 else crc << 1
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray | memoryview, crc: int = CRC_INIT) -> int:
    """CRC-16/CCITT-FALSE; ``crc16(b"123456789") == 0x29B1``."""
    for byte in bytes(data):
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[(crc >> 8) ^ byte]
    return crc


@dataclass(frozen=True, slots=True)
class Frame:
    sequence: int
    type: int
    body: bytes

    @property
    def is_reply(self) -> bool:
        return bool(self.type & REPLY_BIT)

    @property
    def wire_bytes(self) -> int:
        return FRAME_OVERHEAD_BYTES + len(self.body)


def encode_frame(sequence: int, frame_type: int, body: bytes = b"") -> bytes:
    if not 0 <= sequence < SEQUENCE_MODULO:
        raise ValueError(f"sequence {sequence} outside 0..{SEQUENCE_MODULO - 1}")
    if not 0 <= frame_type <= 0xFF:
        raise ValueError(f"frame type {frame_type} is not a byte")
    if len(body) > MAX_BODY_BYTES:
        raise ValueError(f"body of {len(body)} bytes exceeds {MAX_BODY_BYTES}")
    header = _HEADER.pack(SYNC, len(body), sequence, frame_type)
    crc = crc16(header[len(SYNC) :] + body)
    return header + body + _CRC.pack(crc)


def decode_frame(data: bytes) -> Frame:
    """Exactly one frame, nothing before or after it; ProtocolError otherwise (short frame,
    bad sync, bad length, bad CRC)."""
    if len(data) < FRAME_OVERHEAD_BYTES:
        raise ProtocolError(DEVICE, f"short frame: {len(data)} bytes: {data.hex(' ')}")
    sync, length, sequence, frame_type = _HEADER.unpack_from(data)
    if sync != SYNC:
        raise ProtocolError(DEVICE, f"no sync at the start of {data[:8].hex(' ')}")
    if length > MAX_BODY_BYTES:
        raise ProtocolError(DEVICE, f"frame length {length} exceeds {MAX_BODY_BYTES}")
    expected = FRAME_OVERHEAD_BYTES + length
    if len(data) != expected:
        kind = "short" if len(data) < expected else "long"
        raise ProtocolError(DEVICE, f"{kind} frame: {len(data)} bytes, length says {expected}")
    body = data[HEADER_BYTES : HEADER_BYTES + length]
    (received,) = _CRC.unpack_from(data, HEADER_BYTES + length)
    computed = crc16(data[len(SYNC) : HEADER_BYTES + length])
    if received != computed:
        raise ProtocolError(DEVICE, f"bad CRC {received:04x} (computed {computed:04x})")
    return Frame(sequence, frame_type, bytes(body))


@dataclass(frozen=True, slots=True)
class Discarded:
    """Bytes the decoder threw away while resynchronising, and why."""

    byte_count: int
    reason: str  # "garbage" (no sync), "crc" (a frame with a bad CRC), "length" (LEN too big)


class FrameDecoder:
    """Bytes in, frames out, whatever the chunking. After garbage, a bad CRC or an impossible
    length it drops bytes up to the next sync candidate (the sync of a corrupt frame only,
    since a good frame may start inside it) and reports what it dropped."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a frame (a short frame stays here)."""
        return len(self._buffer)

    def clear(self) -> None:
        self._buffer.clear()

    def feed(self, data: bytes) -> list[Frame | Discarded]:
        self._buffer += data
        events: list[Frame | Discarded] = []
        buffer = self._buffer
        while True:
            start = buffer.find(SYNC)
            if start < 0:
                # Keep a trailing first sync byte: its partner may be in the next chunk.
                keep = 1 if buffer[-1:] == SYNC[:1] else 0
                dropped = len(buffer) - keep
                if dropped:
                    events.append(Discarded(dropped, "garbage"))
                    del buffer[:dropped]
                return events
            if start:
                events.append(Discarded(start, "garbage"))
                del buffer[:start]
            if len(buffer) < HEADER_BYTES:
                return events
            length = buffer[len(SYNC)]
            if length > MAX_BODY_BYTES:
                events.append(Discarded(len(SYNC), "length"))
                del buffer[: len(SYNC)]
                continue
            total = FRAME_OVERHEAD_BYTES + length
            if len(buffer) < total:
                return events
            try:
                frame = decode_frame(bytes(buffer[:total]))
            except ProtocolError:
                events.append(Discarded(len(SYNC), "crc"))
                del buffer[: len(SYNC)]
                continue
            events.append(frame)
            del buffer[:total]


# --- values ----------------------------------------------------------------------------------


def _to_counts(value: float, per_unit: int, what: str) -> int:
    if not math.isfinite(value):
        raise ValueError(f"{what} {value} is not finite")
    counts = round(value * per_unit)
    if not _INT32_MIN <= counts <= _INT32_MAX:
        raise ValueError(f"{what} {value} out of the int32 range of the protocol")
    return counts


def pose_to_counts(pose: Sequence[float]) -> tuple[int, ...]:
    """x, y, z (mm) and z-rot, y-rot, x-rot (degrees) -> six wire integers."""
    if len(pose) != 6:
        raise ValueError(f"a pose has six values, not {len(pose)}")
    return tuple(
        _to_counts(v, COUNTS_PER_MM if i < 3 else COUNTS_PER_DEG, "coordinate")
        for i, v in enumerate(pose)
    )


def counts_to_pose(counts: Sequence[int]) -> Pose6:
    x, y, z, zr, yr, xr = counts
    # A division is correctly rounded: 4572000 counts give 457.2 exactly as printed.
    return (
        x / COUNTS_PER_MM,
        y / COUNTS_PER_MM,
        z / COUNTS_PER_MM,
        zr / COUNTS_PER_DEG,
        yr / COUNTS_PER_DEG,
        xr / COUNTS_PER_DEG,
    )


def quantise(pose: Sequence[float]) -> Pose6:
    """What the wire carries of ``pose``: every value rounded to its unit."""
    return counts_to_pose(pose_to_counts(pose))


# --- requests ------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Request:
    sequence: int
    type: RequestType
    offset: Pose6 | None = None  # MOVE_GOAL / MOVE_RELATIVE only
    straight: bool = True
    goal: int = 0  # TEACH_GOAL / MOVE_GOAL: which taught goal


def encode_request(
    sequence: int,
    request_type: RequestType,
    offset: Sequence[float] | None = None,
    *,
    straight: bool = True,
    goal: int = 0,
) -> bytes:
    moves = request_type in (RequestType.MOVE_GOAL, RequestType.MOVE_RELATIVE)
    if moves != (offset is not None):
        raise ValueError(f"{request_type.name} {'needs' if moves else 'takes no'} offset")
    if not 0 <= goal < MAX_GOALS:
        raise ValueError(f"goal {goal} outside 0..{MAX_GOALS - 1}")
    if goal and request_type not in (RequestType.TEACH_GOAL, RequestType.MOVE_GOAL):
        raise ValueError(f"{request_type.name} takes no goal")
    body = b""
    if offset is not None:
        mode = MODE_STRAIGHT if straight else MODE_JOINT
        body = MOVE_BODY.pack(*pose_to_counts(offset), mode)
    if goal:  # goal 0 is the absent byte: the frame of a single goal
        body += GOAL_INDEX.pack(goal)
    return encode_frame(sequence, request_type, body)


def _goal_index(request_type: RequestType, data: bytes) -> int:
    if not data:
        return 0
    (goal,) = GOAL_INDEX.unpack(data)
    if goal >= MAX_GOALS:
        raise ProtocolError(DEVICE, f"{request_type.name}: goal {goal} >= {MAX_GOALS}")
    return int(goal)


def parse_request(frame: Frame) -> Request:
    """A request frame -> Request; ProtocolError for an unknown type or a wrong body length
    (the program answers those with BAD_REQUEST)."""
    try:
        request_type = RequestType(frame.type)
    except ValueError:
        raise ProtocolError(DEVICE, f"unknown request type 0x{frame.type:02x}") from None
    body = frame.body
    if request_type in (RequestType.MOVE_GOAL, RequestType.MOVE_RELATIVE):
        sizes = (MOVE_BODY.size, MOVE_BODY.size + GOAL_INDEX.size)
        if len(body) not in sizes[: 2 if request_type is RequestType.MOVE_GOAL else 1]:
            raise ProtocolError(DEVICE, f"{request_type.name}: body of {len(body)} bytes")
        *counts, mode = MOVE_BODY.unpack_from(body)
        if mode not in (MODE_STRAIGHT, MODE_JOINT):
            raise ProtocolError(DEVICE, f"{request_type.name}: unknown mode {mode}")
        goal = _goal_index(request_type, body[MOVE_BODY.size :])
        offset = counts_to_pose(counts)
        return Request(frame.sequence, request_type, offset, mode == MODE_STRAIGHT, goal)
    if request_type is RequestType.TEACH_GOAL and len(body) <= GOAL_INDEX.size:
        return Request(frame.sequence, request_type, goal=_goal_index(request_type, body))
    if frame.body:
        raise ProtocolError(DEVICE, f"{request_type.name}: unexpected body of {len(frame.body)}")
    return Request(frame.sequence, request_type)


# --- replies -------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Reply:
    sequence: int
    request: int  # the request type answered (or the raw byte of an unknown one)
    status: int
    flags: Flag
    pose: Pose6  # the actual pose when the reply was written (after the move for a move)

    @property
    def ok(self) -> bool:
        return self.status == Status.OK


def encode_reply(
    sequence: int, request: int, status: int, flags: Flag | int, pose: Sequence[float]
) -> bytes:
    body = REPLY_BODY.pack(status, int(flags), *pose_to_counts(pose))
    return encode_frame(sequence, (request | REPLY_BIT) & 0xFF, body)


def parse_reply(frame: Frame) -> Reply:
    if not frame.is_reply:
        raise ProtocolError(DEVICE, f"frame type 0x{frame.type:02x} is not a reply")
    if len(frame.body) != REPLY_BODY.size:
        raise ProtocolError(DEVICE, f"reply body of {len(frame.body)} bytes")
    status, flags, *counts = REPLY_BODY.unpack(frame.body)
    return Reply(
        frame.sequence, frame.type & ~REPLY_BIT, status, Flag(flags), counts_to_pose(counts)
    )


#: Bytes on the wire: one request of each kind, and every reply.
REQUEST_BYTES = FRAME_OVERHEAD_BYTES
MOVE_REQUEST_BYTES = FRAME_OVERHEAD_BYTES + MOVE_BODY.size
REPLY_BYTES = FRAME_OVERHEAD_BYTES + REPLY_BODY.size
