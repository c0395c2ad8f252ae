"""The C500C console's `w0`/`w2` position read-out as pure functions: the parser the driver
reads the pose with and the formatter the emulator prints with (docs/reference/c500c-console.md;
ASSUMED 8 in drivers/c500c/texts.py where the layout is not exact).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from drivers.base import Pose
from drivers.c500c.texts import (
    ACTUAL_TITLE,
    AXIS_HEADER,
    DEVICE,
    ROW_LABEL_WIDTH,
    WORLD_HEADER,
    WORLD_UNITS_MM,
    WORLD_VALUES_INDENT,
)
from drivers.errors import ProtocolError

_DECIMAL = r"[+-]?\d+\.\d+"
_INTEGER = r"[+-]?\d+"

# --- `w0` / `w2` position read-out -------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PositionTable:
    """What a `w0`/`w2` read-out says: WORLD (mm, degrees), and the joint rows when printed."""

    world: tuple[float, ...]
    joints: tuple[float, ...] | None = None
    pulses: tuple[int, ...] | None = None
    units: str = "mm"


_ROW = re.compile(r"^(?P<label>PULSES|JOINTS|WORLD):?(?P<rest>.*)$")
_WORLD_UNITS = re.compile(r"^WORLD:?\s*\((?P<unit>mm|in)\)")


_NUMBER = re.compile(r"[+-]?\d+(?:\.\d+)?")


def _six(text: str, pattern: str, what: str) -> list[str]:
    """Six numbers of a row; fixed-width cells may touch (`%+10.3f` of a wide value)."""
    cells = _NUMBER.findall(text)
    if (
        len(cells) != 6
        or _NUMBER.sub("", text).strip()
        or not all(re.fullmatch(pattern, cell) for cell in cells)
    ):
        raise ProtocolError(DEVICE, f"unreadable position read-out {what}: {text!r}")
    return cells


def parse_position_table(lines: Sequence[str]) -> PositionTable:
    """The read-out of `w0`/`w2` (docs/reference/c500c-console.md): the WORLD values are on the
    first non-empty line after the `WORLD (mm) ...` units line; the older single-line form `WORLD  v
    v v v v v` is accepted too. PULSES are integers, JOINTS and WORLD decimals. A read-out in inches
    is refused: at 0.001 in (25.4 um) the console's resolution is too coarse to compensate with,
    and a silent conversion would hide that (switch the controller to metric)."""
    world: tuple[float, ...] | None = None
    joints: tuple[float, ...] | None = None
    pulses: tuple[int, ...] | None = None
    units: str | None = None
    expect_world_values = False
    for line in lines:
        stripped = line.strip()
        if not stripped:
            continue
        if expect_world_values:
            if world is not None:
                raise ProtocolError(DEVICE, f"position read-out has WORLD twice: {line!r}")
            world = tuple(float(v) for v in _six(stripped, _DECIMAL, "WORLD values"))
            expect_world_values = False
            continue
        unit_line = _WORLD_UNITS.match(stripped)
        if unit_line is not None:
            units = unit_line["unit"]
            if units == "in":
                raise ProtocolError(
                    DEVICE,
                    "the console prints WORLD in inches (0.001 in = 25.4 um): switch the "
                    "controller to metric units",
                )
            expect_world_values = True
            continue
        row = _ROW.match(stripped)
        if row is None:
            continue  # title, column headers
        label, rest = row["label"], row["rest"]
        if label == "WORLD":  # the older single-line form
            if world is not None:
                raise ProtocolError(DEVICE, f"position read-out has WORLD twice: {line!r}")
            world = tuple(float(v) for v in _six(rest, _DECIMAL, "WORLD row"))
        elif label == "JOINTS":
            if joints is not None:
                raise ProtocolError(DEVICE, f"position read-out has JOINTS twice: {line!r}")
            joints = tuple(float(v) for v in _six(rest, _DECIMAL, "JOINTS row"))
        else:
            if pulses is not None:
                raise ProtocolError(DEVICE, f"position read-out has PULSES twice: {line!r}")
            pulses = tuple(int(float(v)) for v in _six(rest, rf"{_INTEGER}(?:\.\d+)?", "PULSES"))
    if expect_world_values:
        raise ProtocolError(DEVICE, "position read-out ends after the WORLD units line")
    if world is None:
        raise ProtocolError(DEVICE, "position read-out has no WORLD values")
    return PositionTable(world=world, joints=joints, pulses=pulses, units=units or "mm")


def parse_world_pose(lines: Sequence[str]) -> Pose:
    """The WORLD values of a `w0`/`w2` read-out as a :class:`Pose` (mm, degrees)."""
    return Pose(*parse_position_table(lines).world)


Layout = Literal["firmware", "single-line"]


def format_w_table(
    world: Sequence[float],
    joints: Sequence[float],
    pulses: Sequence[int],
    *,
    title: str = ACTUAL_TITLE,
    layout: Layout = "firmware",
) -> list[str]:
    """The lines of a `w0`/`w2` read-out as the emulator prints them: the firmware layout of
    docs/reference/c500c-console.md (ASSUMED 8 where it is not exact), or the older single-line
    layout this project used before (kept only for the parser's compatibility test)."""
    for label, values in (("PULSES", pulses), ("JOINTS", joints), ("WORLD", world)):
        if len(values) != 6:
            raise ValueError(f"{label}: six values expected, not {len(values)}")
    if layout == "single-line":
        header = " " * ROW_LABEL_WIDTH + "".join(f"{n:>10}" for n in "123456")
        return [
            header,
            f"{'PULSES:':<{ROW_LABEL_WIDTH}}" + "".join(f"{float(v):+10.3f}" for v in pulses),
            f"{'JOINTS:':<{ROW_LABEL_WIDTH}}" + "".join(f"{v:+10.3f}" for v in joints),
            f"{'WORLD:':<{ROW_LABEL_WIDTH}}" + "".join(f"{v:+10.3f}" for v in world),
        ]
    indent = " " * ROW_LABEL_WIDTH
    return [
        title,
        "",
        indent + "  " + AXIS_HEADER,
        f"{'PULSES':<{ROW_LABEL_WIDTH}}" + " ".join(f"{int(v):+10d}" for v in pulses),
        f"{'JOINTS':<{ROW_LABEL_WIDTH}}" + " ".join(f"{v:+10.3f}" for v in joints),
        "",
        indent + "  " + WORLD_HEADER,
        f"{'WORLD':<{ROW_LABEL_WIDTH}}" + " ".join(f"{unit:>10}" for unit in WORLD_UNITS_MM),
        " " * WORLD_VALUES_INDENT + " ".join(f"{v:+10.3f}" for v in world),
    ]
