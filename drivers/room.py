"""The room thermometer (issue 29): a 1-Wire DS18B20 read through Linux sysfs.

Why this sensor: the DS18B20 is what labs already have for air temperature (a few euros,
digital, factory calibrated to +-0.5 degC, 0.0625 degC steps at 12 bits; Maxim datasheet
19-7487), and what matters to the arm model is the room's *change* over a run, which its
resolution and stability resolve far better than its absolute accuracy. The Linux kernel
reads it with no user-space library: the w1 bus master (w1-gpio on a single-board computer,
ds2490 for the USB DS9490R adapter on any PC) and the w1_therm driver list each sensor as
``/sys/bus/w1/devices/<family>-<serial>/`` and a read of its ``w1_slave`` file converts and
prints (Linux Documentation/w1/slaves/w1_therm.rst)::

    72 01 4b 46 7f ff 0e 10 57 : crc=57 YES
    72 01 4b 46 7f ff 0e 10 57 t=23125

the scratchpad and its CRC check, then the temperature in millidegrees. A read blocks for the
conversion (750 ms at 12 bits): it runs on a worker thread. A failed CRC ("NO"), the
power-on value 85.000 degC (a conversion that never happened: usually the sensor's power) or
a value outside the sensor's range is a DeviceError naming the sensor.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Self

from config.room_settings import RoomSettings
from drivers.base import RoomReading
from drivers.clock import Clock
from drivers.errors import DeviceError

DEVICE = "room"
#: 1-Wire family codes of the w1_therm thermometers (Linux drivers/w1/slaves/w1_therm.c):
#: DS18S20, DS1822, DS18B20, DS1825, DS28EA00.
THERMOMETER_FAMILIES = ("10", "22", "28", "3b", "42")
#: The DS18B20's power-on reset value of its temperature register (datasheet, "Operation").
POWER_ON_MILLI_C = 85_000
#: The sensor's measuring range (degC).
MIN_C, MAX_C = -55.0, 125.0


def parse_w1_slave(text: str, sensor: str) -> float:
    """The temperature (degC) of a ``w1_slave`` file's text; DeviceError when it is not a good
    reading (module docstring)."""
    lines = [line.strip() for line in text.strip().splitlines()]
    if len(lines) < 2 or "crc=" not in lines[0]:
        raise DeviceError(DEVICE, f"{sensor}: not a w1_therm reading: {text.strip()[:80]!r}")
    if not lines[0].endswith("YES"):
        raise DeviceError(DEVICE, f"{sensor}: CRC check failed (a bad read on the 1-Wire bus)")
    _, found, value = lines[1].rpartition("t=")
    try:
        milli = int(value)
    except ValueError:
        milli = None
    if not found or milli is None:
        raise DeviceError(DEVICE, f"{sensor}: no temperature in the reading: {lines[1][:80]!r}")
    if milli == POWER_ON_MILLI_C:
        raise DeviceError(
            DEVICE, f"{sensor}: 85.000 degC is the power-on value: no conversion (check its power)"
        )
    celsius = milli / 1000.0
    if not MIN_C <= celsius <= MAX_C:
        raise DeviceError(DEVICE, f"{sensor}: {celsius:g} degC is outside the sensor's range")
    return celsius


def find_thermometer(devices_dir: Path, device: str | None) -> Path:
    """The folder of the sensor ``device`` (else of the only thermometer) under
    ``devices_dir``; DeviceError naming what is there when it cannot be chosen."""
    if device is not None:
        folder = devices_dir / device
        if not (folder / "w1_slave").is_file():
            raise DeviceError(DEVICE, f"no 1-Wire thermometer {device} under {devices_dir}")
        return folder
    try:
        found = sorted(
            entry
            for entry in devices_dir.iterdir()
            if entry.name[:2] in THERMOMETER_FAMILIES and (entry / "w1_slave").is_file()
        )
    except OSError as err:
        raise DeviceError(
            DEVICE,
            f"cannot list {devices_dir}: {err.strerror} (is the w1 bus driver loaded, e.g. "
            "w1-gpio or ds2490, and w1_therm?)",
        ) from err
    if not found:
        raise DeviceError(
            DEVICE, f"no 1-Wire thermometer under {devices_dir} (is w1_therm loaded?)"
        )
    if len(found) > 1:
        names = ", ".join(entry.name for entry in found)
        raise DeviceError(
            DEVICE, f"several thermometers under {devices_dir} ({names}): set room.w1_device"
        )
    return found[0]


class W1Thermometer:
    """A 1-Wire thermometer of the w1_therm family, read through sysfs (module docstring)."""

    def __init__(self, settings: RoomSettings, clock: Clock) -> None:
        self._settings = settings
        self._clock = clock
        self._path: Path | None = None
        self.sensor = settings.w1_device or "w1"

    async def __aenter__(self) -> Self:
        settings = self._settings
        folder = await asyncio.to_thread(
            find_thermometer, Path(settings.w1_devices_dir), settings.w1_device
        )
        self._path = folder / "w1_slave"
        self.sensor = folder.name
        return self

    async def __aexit__(self, *exc: object) -> None:
        self._path = None

    async def read(self) -> RoomReading:
        path = self._path
        if path is None:
            raise DeviceError(DEVICE, "the thermometer is not open")
        text = await asyncio.to_thread(self._read_text, path)
        return RoomReading(parse_w1_slave(text, self.sensor), self._clock.now(), self.sensor)

    def _read_text(self, path: Path) -> str:
        try:
            return path.read_text(encoding="ascii", errors="replace")
        except OSError as err:
            raise DeviceError(DEVICE, f"{self.sensor}: cannot read: {err.strerror}") from err


__all__ = ["W1Thermometer", "find_thermometer", "parse_w1_slave"]
