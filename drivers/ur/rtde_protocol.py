"""UR's Real-Time Data Exchange (RTDE) protocol as pure functions: package framing, the
control packages of protocol version 2 and the data packages of recipes.

No I/O here: the asyncio client (drivers/ur/rtde_client.py), the emulator
(drivers/sim/ur/rtde_server.py) and the tests build on these functions. The source is UR's
public "Real-Time Data Exchange (RTDE) Guide" (docs.universal-robots.com, tutorials/
communication-protocol-tutorials/rtde-guide; "the guide" below). What the emulator answers
where the guide is silent is marked ASSUMED there.

Every package (the guide, "Protocol"):

    size: uint16 (the whole package, header included) | type: uint8 | payload

Every number is big-endian (network order). Strings are raw ASCII without a terminator; a
list of variable names is one comma-separated string (a trailing comma, as ur-rtde sends it,
is tolerated). Package types are ASCII letters:

    REQUEST_PROTOCOL_VERSION 'V' 86  client: uint16 version      server: uint8 accepted
    GET_URCONTROL_VERSION    'v' 118 client: -                   server: uint32 x4 (major,
                                                                  minor, bugfix, build)
    TEXT_MESSAGE             'M' 77  both (v2): uint8 length, message, uint8 length, source,
                                     uint8 warning level (0 exception, 1 error, 2 warning,
                                     3 info)
    DATA_PACKAGE             'U' 85  both: uint8 recipe id, the recipe's values in order
    CONTROL_PACKAGE_SETUP_OUTPUTS
                             'O' 79  client (v2): double frequency (Hz), names
                                     server (v2): uint8 recipe id, types
    CONTROL_PACKAGE_SETUP_INPUTS
                             'I' 73  client: names        server: uint8 recipe id, types
    CONTROL_PACKAGE_START    'S' 83  client: -            server: uint8 accepted
    CONTROL_PACKAGE_PAUSE    'P' 80  client: -            server: uint8 accepted

The setup replies give each variable's type name, or ``NOT_FOUND`` (no such variable on this
controller) or ``IN_USE`` (an input already written by another client or a fieldbus).
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

#: The protocol version the client asks for and the emulator speaks (the guide: version 2 adds
#: the output frequency and the recipe ids).
PROTOCOL_VERSION = 2
HEADER = struct.Struct(">HB")
HEADER_BYTES = HEADER.size  # 3
#: The largest package the 16-bit size field can describe.
MAX_PACKAGE_BYTES = 0xFFFF
#: The e-Series controller's real-time loop (the guide: "500 Hz on e-Series"): the highest
#: output frequency, and one controller cycle is 1/500 s.
MAX_FREQUENCY_HZ = 500.0
CONTROLLER_CYCLE_S = 1.0 / MAX_FREQUENCY_HZ
NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"


class RtdeFormatError(ValueError):
    """Bytes that are not a valid RTDE package (the drivers raise ProtocolError from it)."""


class PackageType(enum.IntEnum):
    REQUEST_PROTOCOL_VERSION = 86  # 'V'
    GET_URCONTROL_VERSION = 118  # 'v'
    TEXT_MESSAGE = 77  # 'M'
    DATA_PACKAGE = 85  # 'U'
    CONTROL_PACKAGE_SETUP_OUTPUTS = 79  # 'O'
    CONTROL_PACKAGE_SETUP_INPUTS = 73  # 'I'
    CONTROL_PACKAGE_START = 83  # 'S'
    CONTROL_PACKAGE_PAUSE = 80  # 'P'


class MessageLevel(enum.IntEnum):
    """A text message's warning level (the guide, TEXT_MESSAGE v2)."""

    EXCEPTION = 0
    ERROR = 1
    WARNING = 2
    INFO = 3


class DataType(enum.Enum):
    """The guide's data types: the name on the wire and the struct format of one value."""

    BOOL = ("BOOL", "?")
    UINT8 = ("UINT8", "B")
    UINT32 = ("UINT32", "I")
    UINT64 = ("UINT64", "Q")
    INT32 = ("INT32", "i")
    DOUBLE = ("DOUBLE", "d")
    VECTOR3D = ("VECTOR3D", "3d")
    VECTOR6D = ("VECTOR6D", "6d")
    VECTOR6INT32 = ("VECTOR6INT32", "6i")
    VECTOR6UINT32 = ("VECTOR6UINT32", "6I")

    @property
    def wire_name(self) -> str:
        return self.value[0]

    @property
    def format(self) -> str:
        return self.value[1]

    @property
    def width(self) -> int:
        """Values per variable: 1 for a scalar, 3 or 6 for a vector."""
        return int(self.format[:-1]) if len(self.format) > 1 else 1


DATA_TYPES = {data_type.wire_name: data_type for data_type in DataType}

Scalar = bool | int | float
Value = Scalar | tuple[Scalar, ...]


@dataclass(frozen=True, slots=True)
class Package:
    type: int  # a PackageType, or an unknown code as received
    payload: bytes


@dataclass(frozen=True, slots=True)
class TextMessage:
    message: str
    source: str
    level: int  # a MessageLevel


@dataclass(frozen=True, slots=True)
class Recipe:
    """A set-up recipe: its id and its variables' names and types (in package order).

    Its struct and each variable's width are computed once here: a data package is packed or
    parsed every controller cycle (500 Hz), and rebuilding the struct from the types' enum
    properties was most of a package's parsing cost (benchmarks/bench_ur.py, issue 31)."""

    id: int
    names: tuple[str, ...]
    types: tuple[DataType, ...]
    struct: struct.Struct = field(init=False, repr=False, compare=False)
    #: each variable's number of values (1: a scalar), in package order
    widths: tuple[int, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "struct", recipe_struct(self.types))
        object.__setattr__(self, "widths", tuple(t.width for t in self.types))


# --- framing ------------------------------------------------------------------------------


def pack(package_type: int, payload: bytes = b"") -> bytes:
    """One package: the header (size of the whole package, type) and the payload."""
    size = HEADER_BYTES + len(payload)
    if size > MAX_PACKAGE_BYTES:
        raise RtdeFormatError(f"payload of {len(payload)} bytes does not fit one package")
    return HEADER.pack(size, package_type) + payload


class PackageDecoder:
    """Splits a byte stream into packages. A size below the header's is garbage the stream
    cannot be resynchronised from (RTDE has no sync bytes): RtdeFormatError, and the caller
    drops the connection."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[Package]:
        self._buffer += data
        packages: list[Package] = []
        while len(self._buffer) >= HEADER_BYTES:
            size, package_type = HEADER.unpack_from(self._buffer)
            if size < HEADER_BYTES:
                raise RtdeFormatError(f"package size {size} < header size {HEADER_BYTES}")
            if len(self._buffer) < size:
                break
            packages.append(Package(package_type, bytes(self._buffer[HEADER_BYTES:size])))
            del self._buffer[:size]
        return packages

    @property
    def pending(self) -> int:
        """Bytes received that do not yet make a package."""
        return len(self._buffer)


# --- control packages ---------------------------------------------------------------------


def request_protocol_version(version: int = PROTOCOL_VERSION) -> bytes:
    return pack(PackageType.REQUEST_PROTOCOL_VERSION, struct.pack(">H", version))


def parse_protocol_version_request(payload: bytes) -> int:
    return int(_unpack(">H", payload, "protocol version request")[0])


def accepted_reply(package_type: PackageType, accepted: bool) -> bytes:
    """The server's uint8 answer to REQUEST_PROTOCOL_VERSION, START or PAUSE."""
    return pack(package_type, struct.pack(">B", 1 if accepted else 0))


def parse_accepted(payload: bytes) -> bool:
    return bool(_unpack(">B", payload, "accepted reply")[0])


def get_urcontrol_version() -> bytes:
    return pack(PackageType.GET_URCONTROL_VERSION)


def urcontrol_version_reply(version: tuple[int, int, int, int]) -> bytes:
    return pack(PackageType.GET_URCONTROL_VERSION, struct.pack(">4I", *version))


def parse_urcontrol_version(payload: bytes) -> tuple[int, int, int, int]:
    major, minor, bugfix, build = _unpack(">4I", payload, "controller version")
    return int(major), int(minor), int(bugfix), int(build)


def text_message(message: str, source: str, level: MessageLevel = MessageLevel.INFO) -> bytes:
    """A TEXT_MESSAGE of protocol version 2 (either direction); strings cut to 255 bytes."""
    body = message.encode("ascii", "replace")[:255]
    origin = source.encode("ascii", "replace")[:255]
    payload = bytes([len(body)]) + body + bytes([len(origin)]) + origin + bytes([int(level)])
    return pack(PackageType.TEXT_MESSAGE, payload)


def parse_text_message(payload: bytes) -> TextMessage:
    try:
        length = payload[0]
        message = payload[1 : 1 + length]
        source_length = payload[1 + length]
        source = payload[2 + length : 2 + length + source_length]
        level = payload[2 + length + source_length]
    except IndexError as err:
        raise RtdeFormatError(f"truncated text message ({len(payload)} bytes)") from err
    if len(payload) != 3 + length + source_length:
        raise RtdeFormatError(f"text message of {len(payload)} bytes: trailing bytes")
    return TextMessage(message.decode("ascii", "replace"), source.decode("ascii", "replace"), level)


def _names(text: str) -> tuple[str, ...]:
    names = text.split(",")
    if names and names[-1] == "":  # ur-rtde ends the list with a comma
        names.pop()
    if not names or any(not name for name in names):
        raise RtdeFormatError(f"bad variable list {text!r}")
    return tuple(names)


def _ascii(payload: bytes, what: str) -> str:
    try:
        return payload.decode("ascii")
    except UnicodeDecodeError as err:
        raise RtdeFormatError(f"{what}: not ASCII") from err


def setup_outputs(frequency_hz: float, names: Sequence[str]) -> bytes:
    return pack(
        PackageType.CONTROL_PACKAGE_SETUP_OUTPUTS,
        struct.pack(">d", frequency_hz) + ",".join(names).encode("ascii"),
    )


def parse_setup_outputs(payload: bytes) -> tuple[float, tuple[str, ...]]:
    if len(payload) < 8:
        raise RtdeFormatError(f"output setup of {len(payload)} bytes: no frequency")
    (frequency,) = struct.unpack_from(">d", payload)
    return float(frequency), _names(_ascii(payload[8:], "output setup"))


def setup_inputs(names: Sequence[str]) -> bytes:
    return pack(PackageType.CONTROL_PACKAGE_SETUP_INPUTS, ",".join(names).encode("ascii"))


def parse_setup_inputs(payload: bytes) -> tuple[str, ...]:
    return _names(_ascii(payload, "input setup"))


def setup_reply(package_type: PackageType, recipe_id: int, type_names: Sequence[str]) -> bytes:
    """The server's answer to a setup: the recipe id and each variable's type (or NOT_FOUND,
    IN_USE)."""
    return pack(package_type, bytes([recipe_id]) + ",".join(type_names).encode("ascii"))


def parse_setup_reply(payload: bytes) -> tuple[int, tuple[str, ...]]:
    if not payload:
        raise RtdeFormatError("empty setup reply")
    return payload[0], tuple(_ascii(payload[1:], "setup reply").split(","))


def recipe_of(recipe_id: int, names: Sequence[str], type_names: Sequence[str]) -> Recipe:
    """The recipe a setup reply describes; RtdeFormatError naming the variables the
    controller did not accept (NOT_FOUND, IN_USE) or when the counts differ."""
    if len(type_names) != len(names):
        raise RtdeFormatError(f"{len(names)} variables set up, {len(type_names)} types back")
    refused = [f"{n} {t}" for n, t in zip(names, type_names, strict=True) if t not in DATA_TYPES]
    if refused:
        raise RtdeFormatError("refused: " + ", ".join(refused))
    return Recipe(recipe_id, tuple(names), tuple(DATA_TYPES[t] for t in type_names))


def start() -> bytes:
    return pack(PackageType.CONTROL_PACKAGE_START)


def pause() -> bytes:
    return pack(PackageType.CONTROL_PACKAGE_PAUSE)


# --- data packages ------------------------------------------------------------------------


def recipe_struct(types: Iterable[DataType]) -> struct.Struct:
    """The struct of a data package's values (after the recipe id byte)."""
    return struct.Struct(">" + "".join(t.format for t in types))


def _flatten(recipe: Recipe, values: Sequence[Value]) -> list[Scalar]:
    if len(values) != len(recipe.widths):
        raise RtdeFormatError(f"{len(recipe.widths)} values expected, got {len(values)}")
    flat: list[Scalar] = []
    for data_type, width, value in zip(recipe.types, recipe.widths, values, strict=True):
        if width == 1:
            if isinstance(value, tuple):
                raise RtdeFormatError(f"{data_type.wire_name}: one value expected")
            flat.append(value)
        else:
            if not isinstance(value, tuple) or len(value) != width:
                raise RtdeFormatError(f"{data_type.wire_name}: {width} values expected")
            flat.extend(value)
    return flat


def data_package(recipe: Recipe, values: Sequence[Value]) -> bytes:
    """A DATA_PACKAGE of ``recipe`` with ``values`` in the recipe's order."""
    try:
        body = recipe.struct.pack(*_flatten(recipe, values))
    except struct.error as err:
        raise RtdeFormatError(f"values do not fit recipe {recipe.id}: {err}") from err
    return pack(PackageType.DATA_PACKAGE, bytes([recipe.id]) + body)


def data_recipe_id(payload: bytes) -> int:
    if not payload:
        raise RtdeFormatError("empty data package")
    return payload[0]


def parse_data_package(payload: bytes, recipe: Recipe) -> tuple[Value, ...]:
    """The values of a DATA_PACKAGE of ``recipe`` (its id checked), vectors as tuples."""
    if data_recipe_id(payload) != recipe.id:
        raise RtdeFormatError(f"data package of recipe {payload[0]}, expected {recipe.id}")
    layout = recipe.struct
    if len(payload) - 1 != layout.size:
        raise RtdeFormatError(
            f"data package of recipe {recipe.id}: {len(payload) - 1} bytes, {layout.size} expected"
        )
    flat = layout.unpack_from(payload, 1)
    values: list[Value] = []
    index = 0
    for width in recipe.widths:
        values.append(flat[index] if width == 1 else flat[index : index + width])
        index += width
    return tuple(values)


def finite_frequency(frequency_hz: float) -> bool:
    """Whether an output frequency is one the controller accepts (the guide: up to the
    real-time loop's frequency; ASSUMED: positive and finite)."""
    return math.isfinite(frequency_hz) and 0.0 < frequency_hz <= MAX_FREQUENCY_HZ


def _unpack(layout: str, payload: bytes, what: str) -> tuple[int, ...]:
    try:
        values: tuple[int, ...] = struct.unpack(layout, payload)
    except struct.error as err:
        raise RtdeFormatError(f"{what}: {len(payload)} bytes ({err})") from err
    return values
