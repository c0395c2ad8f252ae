"""The UR bench's room thermometer (issue 31, room.driver "sim" with robot.driver ur-rtde): the
lab's DS18B20 in the air the emulated UR stands in, as drivers/sim/arm_devices.py SimArmRoom is
on the A465's arm bench. A UR reports no air temperature over RTDE; a cell adds a 1-Wire
sensor (room.driver w1, drivers/room.py) so that a warming room is not read as the joints
heating (the joint sensors' offsets would absorb it: issue 31's closing note, -3.2 and -4.6 degC
with a room drifting +1 degC/h). The reading is the emulated controller's bench truth's room
at its current cycle (drivers/sim/ur/controller.py room_temperature), stamped with the run's
clock."""

from __future__ import annotations

from typing import Self

from drivers.base import RoomReading
from drivers.clock import Clock
from drivers.sim.ur.controller import URController


class SimURRoom:
    """``async with SimURRoom(controller, clock) as room: await room.read()``."""

    def __init__(self, controller: URController, clock: Clock) -> None:
        self._controller = controller
        self._clock = clock

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def read(self) -> RoomReading:
        """One reading at the controller's current cycle: microseconds of arithmetic on the
        event loop, where the emulator's cycles run (no thread: the controller is the loop's)."""
        controller = self._controller
        value = controller.room_temperature(controller.time_s)
        return RoomReading(value, self._clock.now(), "sim")


__all__ = ["SimURRoom"]
