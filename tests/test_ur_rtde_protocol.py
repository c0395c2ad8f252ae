"""RTDE framing (drivers/ur/rtde_protocol.py) against exact bytes: the public RTDE guide's
layouts, and the bytes ur-rtde 1.6.5 was seen sending on connect (recorded with a plain socket
server: ``V`` with ``00 02``, ``v`` empty, ``O`` with the frequency as a big-endian double)."""

from __future__ import annotations

import math
import struct

import pytest

from drivers.ur import rtde_protocol as rtde
from drivers.ur.registers import RegisterMap
from drivers.ur.rtde_protocol import DataType, PackageType, Recipe
from drivers.ur.rtde_variables import INPUTS, OUTPUTS


def test_protocol_version_request_is_the_bytes_ur_rtde_sends() -> None:
    assert rtde.request_protocol_version() == bytes([0x00, 0x05, ord("V"), 0x00, 0x02])
    assert rtde.parse_protocol_version_request(b"\x00\x02") == 2
    assert rtde.accepted_reply(PackageType.REQUEST_PROTOCOL_VERSION, True) == b"\x00\x04V\x01"
    assert rtde.accepted_reply(PackageType.CONTROL_PACKAGE_START, False) == b"\x00\x04S\x00"
    assert rtde.parse_accepted(b"\x01") and not rtde.parse_accepted(b"\x00")


def test_controller_version_request_and_reply() -> None:
    assert rtde.get_urcontrol_version() == b"\x00\x03v"
    reply = rtde.urcontrol_version_reply((5, 15, 0, 1234))
    assert reply == b"\x00\x13v" + bytes.fromhex("00000005 0000000f 00000000 000004d2")
    assert rtde.parse_urcontrol_version(reply[3:]) == (5, 15, 0, 1234)
    with pytest.raises(rtde.RtdeFormatError):
        rtde.parse_urcontrol_version(reply[3:-1])


def test_output_setup_carries_the_frequency_as_a_big_endian_double() -> None:
    package = rtde.setup_outputs(500.0, ["timestamp", "actual_q"])
    # ur-rtde sent b'@\x7f@\x00\x00\x00\x00\x00timestamp,...' for 500 Hz
    assert package[:3] == struct.pack(">HB", len(package), ord("O"))
    assert package[3:11] == b"@\x7f@\x00\x00\x00\x00\x00"
    assert package[11:] == b"timestamp,actual_q"
    # ur-rtde ends its list with a comma: tolerated
    assert rtde.parse_setup_outputs(package[3:] + b",") == (500.0, ("timestamp", "actual_q"))
    with pytest.raises(rtde.RtdeFormatError):
        rtde.parse_setup_outputs(b"\x00\x00")


def test_setup_reply_and_recipe_refusals() -> None:
    reply = rtde.setup_reply(PackageType.CONTROL_PACKAGE_SETUP_INPUTS, 3, ["INT32", "DOUBLE"])
    assert reply == b"\x00\x10I\x03INT32,DOUBLE"  # 3 + 1 + 12 bytes
    recipe_id, types = rtde.parse_setup_reply(reply[3:])
    recipe = rtde.recipe_of(recipe_id, ["input_int_register_24", "input_double_register_24"], types)
    assert recipe == Recipe(3, recipe.names, (DataType.INT32, DataType.DOUBLE))
    with pytest.raises(rtde.RtdeFormatError, match="nope NOT_FOUND"):
        rtde.recipe_of(1, ["timestamp", "nope"], ["DOUBLE", "NOT_FOUND"])
    with pytest.raises(rtde.RtdeFormatError, match="IN_USE"):
        rtde.recipe_of(1, ["input_int_register_3"], ["IN_USE"])
    with pytest.raises(rtde.RtdeFormatError, match="2 variables"):
        rtde.recipe_of(1, ["a", "b"], ["DOUBLE"])


def test_data_package_bytes_of_every_type() -> None:
    types = (
        DataType.BOOL,
        DataType.UINT8,
        DataType.UINT32,
        DataType.UINT64,
        DataType.INT32,
        DataType.DOUBLE,
        DataType.VECTOR3D,
        DataType.VECTOR6D,
        DataType.VECTOR6INT32,
    )
    recipe = Recipe(7, tuple(f"v{i}" for i in range(len(types))), types)
    values = (
        True,
        200,
        0xDEADBEEF,
        1 << 40,
        -5,
        1.5,
        (1.0, 2.0, 3.0),
        (0.0, -1.0, 0.5, 0.25, 2.0, -0.125),
        (1, -2, 3, -4, 5, -6),
    )
    package = rtde.data_package(recipe, values)
    body = (
        b"\x07\x01\xc8"
        + bytes.fromhex("deadbeef")
        + bytes.fromhex("0000010000000000")
        + bytes.fromhex("fffffffb")
        + struct.pack(">d", 1.5)
        + struct.pack(">3d", 1.0, 2.0, 3.0)
        + struct.pack(">6d", 0.0, -1.0, 0.5, 0.25, 2.0, -0.125)
        + struct.pack(">6i", 1, -2, 3, -4, 5, -6)
    )
    assert package == struct.pack(">HB", 3 + len(body), ord("U")) + body
    assert rtde.parse_data_package(package[3:], recipe) == values
    with pytest.raises(rtde.RtdeFormatError, match="recipe 8"):
        rtde.parse_data_package(b"\x08" + package[4:], recipe)
    with pytest.raises(rtde.RtdeFormatError, match="bytes"):
        rtde.parse_data_package(package[3:-1], recipe)
    with pytest.raises(rtde.RtdeFormatError):
        rtde.data_package(recipe, values[:-1])


def test_the_driver_input_package_is_what_the_program_reads() -> None:
    registers = RegisterMap(24)
    recipe = rtde.recipe_of(2, registers.inputs, [INPUTS[n].wire_name for n in registers.inputs])
    package = rtde.data_package(recipe, (17, 1, 1e-4, 0.0, -2e-5, 0.0, 1e-6, 0.0))
    assert package[:4] == b"\x00\x3cU\x02"  # 3 + 1 + 2 x 4 + 6 x 8 = 60 bytes
    assert package[4:12] == bytes.fromhex("00000011 00000001")
    assert struct.unpack(">6d", package[12:]) == (1e-4, 0.0, -2e-5, 0.0, 1e-6, 0.0)
    assert registers.inputs[:2] == ("input_int_register_24", "input_int_register_25")
    assert registers.outputs[0] == "output_int_register_24"
    with pytest.raises(ValueError):
        RegisterMap(23)  # the fieldbus range
    with pytest.raises(ValueError):
        RegisterMap(42)  # would reach register 47, ur-rtde's command register


def test_text_message_version_2_layout() -> None:
    package = rtde.text_message("hello", "emu", rtde.MessageLevel.WARNING)
    assert package == b"\x00\x0eM\x05hello\x03emu\x02"
    message = rtde.parse_text_message(package[3:])
    assert (message.message, message.source, message.level) == ("hello", "emu", 2)
    with pytest.raises(rtde.RtdeFormatError):
        rtde.parse_text_message(package[3:-1])


def test_decoder_splits_a_stream_at_any_byte() -> None:
    stream = (
        rtde.request_protocol_version()
        + rtde.get_urcontrol_version()
        + rtde.text_message("x", "y")
        + rtde.start()
    )
    for cut in range(len(stream) + 1):
        decoder = rtde.PackageDecoder()
        packages = decoder.feed(stream[:cut]) + decoder.feed(stream[cut:])
        assert [p.type for p in packages] == [ord("V"), ord("v"), ord("M"), ord("S")]
        assert packages[0].payload == b"\x00\x02" and decoder.pending == 0
    with pytest.raises(rtde.RtdeFormatError, match="size 2"):
        rtde.PackageDecoder().feed(b"\x00\x02V")


def test_variable_tables_have_the_guides_types() -> None:
    assert OUTPUTS["joint_temperatures"] is DataType.VECTOR6D
    assert OUTPUTS["runtime_state"] is DataType.UINT32
    assert OUTPUTS["robot_mode"] is DataType.INT32
    assert OUTPUTS["actual_digital_input_bits"] is DataType.UINT64
    assert OUTPUTS["output_int_register_47"] is DataType.INT32
    assert INPUTS["input_double_register_24"] is DataType.DOUBLE
    assert "input_int_register_48" not in INPUTS
    assert rtde.finite_frequency(500.0) and not rtde.finite_frequency(500.5)
    assert not rtde.finite_frequency(math.nan) and not rtde.finite_frequency(0.0)
