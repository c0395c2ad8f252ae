"""The fast path's framing (controller/PROTOCOL.md): CRC, length, sequence, resynchronisation."""

from __future__ import annotations

import re
import struct

import pytest

from config.settings import RobotSettings
from drivers.c500c import server_protocol as proto
from drivers.errors import ProtocolError
from tests.helpers import REPO_ROOT

POSE = (457.2, -12.3456, 254.0001, 0.5, 90.0, -179.9999)


def test_crc_is_ccitt_false_by_its_check_value() -> None:
    assert proto.crc16(b"123456789") == 0x29B1
    assert proto.crc16(b"") == 0xFFFF
    assert proto.crc16(b"\x00") == 0xE1F0  # catalogue of parametrised CRC algorithms, CCITT-FALSE


def test_heartbeat_frame_bytes_are_those_of_the_specification() -> None:
    # PROTOCOL.md "Worked example": HEARTBEAT, sequence 1.
    frame = proto.encode_request(1, proto.RequestType.HEARTBEAT)
    crc = proto.crc16(bytes([0x00, 0x01, 0x00, 0x01]))
    assert frame == bytes([0xA5, 0x5A, 0x00, 0x01, 0x00, 0x01]) + struct.pack("<H", crc)
    assert frame.hex(" ") == "a5 5a 00 01 00 01 " + struct.pack("<H", crc).hex(" ")
    assert len(frame) == proto.REQUEST_BYTES == 8


def test_move_request_round_trip_and_size() -> None:
    frame = proto.encode_request(
        0xBEEF, proto.RequestType.MOVE_GOAL, (0.0123, -0.0004, 1.5, 0.0, 0.0, 0.001)
    )
    assert len(frame) == proto.MOVE_REQUEST_BYTES == 33
    assert frame[2] == proto.MOVE_BODY.size == 25  # LEN counts the body only
    assert frame[3:5] == b"\xef\xbe"  # sequence little-endian
    request = proto.parse_request(proto.decode_frame(frame))
    assert request.sequence == 0xBEEF
    assert request.type is proto.RequestType.MOVE_GOAL
    assert request.offset == (0.0123, -0.0004, 1.5, 0.0, 0.0, 0.001)
    assert request.straight
    joint = proto.parse_request(
        proto.decode_frame(
            proto.encode_request(
                2, proto.RequestType.MOVE_RELATIVE, (1, 2, 3, 0, 0, 0), straight=False
            )
        )
    )
    assert not joint.straight and joint.offset == (1.0, 2.0, 3.0, 0.0, 0.0, 0.0)


def test_reply_round_trip_carries_status_flags_and_pose() -> None:
    flags = proto.Flag.GOAL_TAUGHT | proto.Flag.HELD
    data = proto.encode_reply(7, proto.RequestType.MOVE_GOAL, 44, flags, POSE)
    assert len(data) == proto.REPLY_BYTES == 35
    reply = proto.parse_reply(proto.decode_frame(data))
    assert reply.sequence == 7 and reply.request == proto.RequestType.MOVE_GOAL
    assert reply.status == 44 and not reply.ok
    assert reply.flags == flags
    assert reply.pose == POSE


def test_values_are_quantised_to_a_tenth_of_a_micrometre() -> None:
    assert proto.quantise((0.00004, 0.00006, -0.00005, 0, 0, 0))[:3] == (0.0, 0.0001, -0.0)
    with pytest.raises(ValueError, match="not finite"):
        proto.encode_request(1, proto.RequestType.MOVE_GOAL, (float("nan"), 0, 0, 0, 0, 0))
    with pytest.raises(ValueError, match="int32"):
        proto.encode_request(1, proto.RequestType.MOVE_GOAL, (300_000.0, 0, 0, 0, 0, 0))
    with pytest.raises(ValueError, match="needs offset"):
        proto.encode_request(1, proto.RequestType.MOVE_GOAL)
    with pytest.raises(ValueError, match="takes no offset"):
        proto.encode_request(1, proto.RequestType.HOLD, (0, 0, 0, 0, 0, 0))


def test_sequence_must_fit_sixteen_bits() -> None:
    proto.encode_frame(proto.SEQUENCE_MODULO - 1, 1)
    with pytest.raises(ValueError, match="sequence"):
        proto.encode_frame(proto.SEQUENCE_MODULO, 1)
    with pytest.raises(ValueError, match="sequence"):
        proto.encode_frame(-1, 1)


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda f: f[:-1], "short frame"),
        (lambda f: f[:5], "short frame"),
        (lambda f: f + b"\x00", "long frame"),
        (lambda f: b"\xa5\x00" + f[2:], "no sync"),
        (lambda f: f[:2] + bytes([proto.MAX_BODY_BYTES + 1]) + f[3:], "exceeds"),
        (lambda f: f[:-1] + bytes([f[-1] ^ 0x01]), "bad CRC"),
        (lambda f: f[:4] + bytes([f[4] ^ 0x80]) + f[5:], "bad CRC"),  # sequence flipped
        (lambda f: f[:2] + bytes([f[2] - 1]) + f[3:], "long frame"),  # length lies
    ],
)
def test_decode_frame_refuses_every_damaged_frame(mutate: object, message: str) -> None:
    frame = proto.encode_reply(3, proto.RequestType.READ_POSE, 0, 0, POSE)
    with pytest.raises(ProtocolError, match=message):
        proto.decode_frame(mutate(frame))  # type: ignore[operator]


def test_parse_request_refuses_unknown_type_and_bad_bodies() -> None:
    with pytest.raises(ProtocolError, match="unknown request type 0x42"):
        proto.parse_request(proto.Frame(1, 0x42, b""))
    with pytest.raises(ProtocolError, match="body of 3 bytes"):
        proto.parse_request(proto.Frame(1, proto.RequestType.MOVE_GOAL, b"abc"))
    with pytest.raises(ProtocolError, match="unexpected body"):
        proto.parse_request(proto.Frame(1, proto.RequestType.HOLD, b"x"))
    bad_mode = proto.MOVE_BODY.pack(0, 0, 0, 0, 0, 0, 9)
    with pytest.raises(ProtocolError, match="unknown mode 9"):
        proto.parse_request(proto.Frame(1, proto.RequestType.MOVE_GOAL, bad_mode))
    with pytest.raises(ProtocolError, match="not a reply"):
        proto.parse_reply(proto.Frame(1, proto.RequestType.HOLD, b""))
    with pytest.raises(ProtocolError, match="reply body"):
        proto.parse_reply(proto.Frame(1, 0x80 | proto.RequestType.HOLD, b""))


# --- the streaming decoder -------------------------------------------------------------------


def _frames(events: list[proto.Frame | proto.Discarded]) -> list[proto.Frame]:
    return [e for e in events if isinstance(e, proto.Frame)]


def _discarded(events: list[proto.Frame | proto.Discarded]) -> list[tuple[int, str]]:
    return [(e.byte_count, e.reason) for e in events if isinstance(e, proto.Discarded)]


def test_decoder_reassembles_frames_split_at_every_byte() -> None:
    stream = b"".join(
        proto.encode_reply(n, proto.RequestType.HEARTBEAT, 0, 0, POSE) for n in range(3)
    ) + proto.encode_request(9, proto.RequestType.MOVE_GOAL, POSE)
    for cut in range(1, 12):
        decoder = proto.FrameDecoder()
        events: list[proto.Frame | proto.Discarded] = []
        for start in range(0, len(stream), cut):
            events += decoder.feed(stream[start : start + cut])
        assert [f.sequence for f in _frames(events)] == [0, 1, 2, 9]
        assert _discarded(events) == []
        assert decoder.pending == 0


def test_decoder_resynchronises_after_garbage_including_false_syncs() -> None:
    good = proto.encode_reply(5, proto.RequestType.READ_POSE, 0, 0, POSE)
    garbage = b"\x00\xff\xa5\x13\xa5\x5a\x40hello"  # a lone A5, then a sync with LEN 64
    decoder = proto.FrameDecoder()
    events = decoder.feed(garbage + good + b"\xa5")
    assert [f.sequence for f in _frames(events)] == [5]
    assert sum(n for n, _ in _discarded(events)) == len(garbage)
    assert "length" in {reason for _, reason in _discarded(events)}
    assert decoder.pending == 1  # a trailing A5 may start the next frame
    assert _frames(decoder.feed(good[1:])) == [proto.decode_frame(good)]


def test_decoder_drops_a_bad_crc_frame_and_finds_the_next_inside_it() -> None:
    good = proto.encode_reply(6, proto.RequestType.HEARTBEAT, 0, 0, POSE)
    # A frame cut short by line noise, immediately followed by a good one: the cut frame's LEN
    # swallows the good frame's start, its CRC fails, and the decoder rescans from byte 2.
    cut = proto.encode_reply(4, proto.RequestType.HEARTBEAT, 0, 0, POSE)[:10]
    events = proto.FrameDecoder().feed(cut + good)
    assert [f.sequence for f in _frames(events)] == [6]
    assert "crc" in {reason for _, reason in _discarded(events)}


def test_decoder_holds_a_short_frame_until_the_rest_comes() -> None:
    frame = proto.encode_request(11, proto.RequestType.TEACH_GOAL)
    decoder = proto.FrameDecoder()
    assert decoder.feed(frame[:-1]) == []
    assert decoder.pending == len(frame) - 1
    assert _frames(decoder.feed(frame[-1:]))[0].sequence == 11
    decoder.feed(frame[:4])
    decoder.clear()
    assert decoder.pending == 0


def test_the_worked_examples_of_the_specification_are_what_the_code_sends() -> None:
    spec = (REPO_ROOT / "controller" / "PROTOCOL.md").read_text()
    example = spec[spec.index("## Worked example") :]
    lines = re.findall(r"((?:[0-9a-f]{2} ){7,}[0-9a-f]{2})", example)
    assert [bytes.fromhex(line) for line in lines] == [
        proto.encode_request(1, proto.RequestType.HEARTBEAT),
        proto.encode_request(2, proto.RequestType.MOVE_GOAL, (0.0123, 0, 0, 0, 0, 0)),
    ]
    assert "0x29B1" in spec and "CRC-16/CCITT-FALSE" in spec  # the check value quoted above


def test_the_controller_program_uses_the_same_numbers() -> None:
    """The RAPL-3 program cannot be compiled here; its constants are checked against the
    Python implementation of the same specification instead."""
    program = (REPO_ROOT / "controller" / "thermocomp_server.r3").read_text()
    consts = {
        name: int(value, 0)
        for name, value in re.findall(r"^const (\w+) = (0x[0-9A-Fa-f]+|\d+)", program, re.M)
    }
    types: dict[str, int] = {
        "T_HEARTBEAT": proto.RequestType.HEARTBEAT,
        "T_TEACH": proto.RequestType.TEACH_GOAL,
        "T_MOVE_GOAL": proto.RequestType.MOVE_GOAL,
        "T_MOVE_REL": proto.RequestType.MOVE_RELATIVE,
        "T_READ": proto.RequestType.READ_POSE,
        "T_HOLD": proto.RequestType.HOLD,
        "T_RELEASE": proto.RequestType.RELEASE,
        "S_OK": proto.Status.OK,
        "S_HALTED": proto.Status.HALTED,
        "S_NO_GOAL": proto.Status.NO_GOAL,
        "S_HELD": proto.Status.HELD,
        "S_BAD": proto.Status.BAD_REQUEST,
        "S_NO_CONTROL": proto.Status.NO_CONTROL,
        "S_BUSY": proto.Status.BUSY,
        "F_GOAL": proto.Flag.GOAL_TAUGHT,
        "F_HELD": proto.Flag.HELD,
        "F_MOVING": proto.Flag.MOVING,
        "F_CONTROL": proto.Flag.POINT_OF_CONTROL,
        "F_SILENCE": proto.Flag.SILENCE_HALTED,
        "MAX_BODY": proto.MAX_BODY_BYTES,
        "MAX_GOALS": proto.MAX_GOALS,
        "MOVE_LEN": proto.MOVE_BODY.size,
        "SILENCE_MS": round(RobotSettings().server_silence_s * 1000),
    }
    assert {name: consts.get(name) for name in types} == {k: int(v) for k, v in types.items()}
    # Frame sizes and fields as the program writes and reads them.
    assert f"str_len_set(g_tx, {proto.REPLY_BYTES})" in program
    assert f"str_chr_set(g_tx, 2, {proto.REPLY_BODY.size})" in program
    assert "if len == MOVE_LEN + 1 and type == T_MOVE_GOAL then" in program  # the goal byte
    assert "elseif len != MOVE_LEN then" in program
    assert "0x1021" in program and "0xFFFF" in program  # CRC-16/CCITT-FALSE
    assert "0xA5" in program and "0x5A" in program
    assert f"* {proto.COUNTS_PER_MM}.0" in program  # 0.1 um counts
