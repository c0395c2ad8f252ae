"""The camera, the IR reader and the room thermometer as a step uses them: bounded waits and
how each last went."""

from __future__ import annotations

from collections.abc import Awaitable
from typing import TypeVar

from config import Settings
from daemon.run.events import ErrorLog
from drivers.base import Camera, Frame, IrReader, IrReading, RoomReading, RoomThermometer
from drivers.deadline import bounded
from drivers.errors import DeviceError

_T = TypeVar("_T")

#: The state GET /health gives a sensor the configuration does without.
NO_DEVICE = "none"


class Sensors:
    """Grabs and reads bounded in wall time (issue 10), with the state of each sensor's last
    grab/read for GET /health: "open" before the first, then "ok", "stale" or
    "<error kind> error" (e.g. "timeout error"); "none" for a sensor the robot does without."""

    def __init__(
        self,
        settings: Settings,
        camera: Camera,
        ir: IrReader,
        errors: ErrorLog,
        room: RoomThermometer | None = None,
    ) -> None:
        self._settings = settings
        self._camera = camera
        self._ir = ir
        self._errors = errors
        self._room = room
        # a device the robot does without (drivers/factory.py AbsentDevice: a UR followed by
        # its joint temperatures) is "none", never "open" as if a grab were still to come
        self.states: dict[str, str] = {
            name: NO_DEVICE if getattr(device, "absent", False) else "open"
            for name, device in (("camera", camera), ("ir", ir))
        }
        if room is not None:
            self.states["room"] = "open"

    @property
    def has_room(self) -> bool:
        """Whether a room thermometer is open (room.driver is not none)."""
        return self._room is not None

    async def read_room(self) -> RoomReading:
        """One reading of the room thermometer (DeviceError: none, or it failed)."""
        if self._room is None:
            raise DeviceError("room", "no room thermometer (room.driver none)")
        timeout_s = self._settings.room.read_timeout_s
        return await self._bounded(self._room.read(), "room", "reading", timeout_s)

    async def grab(self) -> Frame:
        timeout_s = self._settings.camera.grab_timeout_s
        return await self._bounded(self._camera.grab(), "camera", "frame", timeout_s)

    async def read_ir(self) -> IrReading:
        timeout_s = self._settings.ir.read_timeout_s
        return await self._bounded(self._ir.read(), "ir", "reading", timeout_s)

    async def _bounded(
        self, operation: Awaitable[_T], device: str, what: str, timeout_s: float
    ) -> _T:
        """Await a grab/read for at most ``timeout_s`` of wall time, else DeviceTimeoutError.
        Wall time, as the robot's command timeout: a hung device or thread does not run on the
        bench's clock, and a virtual clock would jump a run-clock timeout forward at once; the
        simulated bench's own computing (a render) does not count (drivers/deadline.py)."""
        try:
            result = await bounded(operation, device, what, timeout_s)
        except DeviceError as err:
            self.states[device] = f"{err.kind} error"
            raise
        self.states[device] = "ok"
        return result

    def stale(self, device: str, what: str, age_s: float) -> str:
        """A stale frame/reading is a sensor error: note it, return the step's error text."""
        err = DeviceError(device, f"stale {what}: {age_s:.3g} s old (limit {device}.max_age_s)")
        self.states[device] = "stale"
        self._errors.note(err)
        return str(err)
