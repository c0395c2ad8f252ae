"""The ``[room]`` section (issue 29): the thermometer in the air the arm stands in, whose
reading the arm model follows as its ambient (docs/how-to/room-thermometer.md)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from config.section import MAX_TIMEOUT_S, Section

#: The Linux kernel's 1-Wire devices (w1 bus driver + w1_therm).
W1_DEVICES_DIR = "/sys/bus/w1/devices"


class RoomSettings(Section):
    """The room thermometer: none (the model holds model.ambient_c), the arm bench's simulated
    one (sim), or a 1-Wire DS18B20 family sensor read through Linux sysfs (w1)."""

    driver: Literal["none", "sim", "w1"] = Field(
        "none",
        description="none: no room thermometer (arm runs hold model.ambient_c and say so in "
        "their summary); sim: the arm bench's (its truth's room, lag and noise); w1: a 1-Wire "
        "DS18B20 through Linux sysfs.",
    )
    w1_device: Annotated[str, Field(pattern=r"^[0-9a-f]{2}-[0-9a-f]{12}$")] | None = Field(
        None,
        description="w1: the sensor's id (e.g. 28-0316a2794aff, its folder under "
        "room.w1_devices_dir); none: the only thermometer there.",
    )
    w1_devices_dir: str = Field(
        W1_DEVICES_DIR, max_length=4096, description="w1: where the kernel lists 1-Wire devices."
    )
    read_timeout_s: Annotated[float, Field(gt=0, le=MAX_TIMEOUT_S)] = Field(
        5.0,
        description="Longest wait for one reading (s, wall time): a DS18B20 converts in 750 ms "
        "at 12 bits; then the step is flagged room-error and the model keeps the last room.",
    )
