"""The Universal Robots e-Series driver (``robot.driver = "ur-rtde"``, issue 31): a
drivers.base.OffsetRobot over RTDE, for a robot that plays its own taught program with
controller/ur/thermocomp_offset.script running beside it.

It streams the robot's state (joints, TCP pose and speed, joint temperatures, robot, safety
and program modes, and the program's registers: at which measured pose it is, which sequence
it accepted, its status, the offset it applies) at robot.rtde_frequency_hz, and writes the
correction, a sequence number and a hold flag into the input registers
(drivers/ur/registers.py) on every correction and at least every robot.ur_heartbeat_s.

**The hold** (drivers.base.Robot's contract). :meth:`URRobot.stop` holds from the moment it
is called: the hold flag is set and written to the controller in the same synchronous step
(one whole RTDE package into the socket, no await in between), and every later
:meth:`set_correction` is refused with MotionHeldError; the check and the write of a
correction have no await between them either, so no correction can slip past a hold. Only
:meth:`resume` releases a hold, and a hold that comes while a resume waits wins (holds are
counted, as drivers/c500c/robot.py counts them). What a hold means on a robot that plays its own
program: the program's offset freezes where it is (the program keeps playing; pausing it is
the Dashboard's ``pause``, ``URRobot.dashboard``); the robot-side program freezes it by
itself too when the PC goes silent for its watchdog's 0.5 s.

A lost link (no state package for robot.ur_timeout_s, a closed or garbled connection) is a
fault: the correction is held, the link reconnects in the background (drivers/reconnect.py)
and stays held until an explicit resume. Nothing here moves the robot: the robot moves by its
own program; this driver only shifts that program's path within the program's limits.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Coroutine
from types import TracebackType
from typing import Any, Self

from config.settings import RobotSettings
from drivers.base import ZERO_ROTATION, LinkState, OffsetRobotState, RobotStatus, Vector3
from drivers.errors import DeviceError, MotionHeldError, NotConnectedError
from drivers.goals import require_finite
from drivers.reconnect import RECONNECT_FIRST_BACKOFF_S, Reconnector
from drivers.ur import rtde_protocol as rtde
from drivers.ur.dashboard_client import DashboardClient
from drivers.ur.registers import RegisterMap
from drivers.ur.rtde_client import RtdeClient
from drivers.ur.rtde_protocol import Recipe, Value

logger = logging.getLogger(__name__)

DEVICE = "robot"
MM_PER_M = 1000.0
#: The sequence register is an INT32: it runs 1 .. 2^31 - 1 and wraps to 1 (0 is "no target
#: yet" for the program).
SEQUENCE_MAX = (1 << 31) - 1
STATE_OUTPUTS = (
    "timestamp",
    "actual_q",
    "actual_qd",
    "actual_TCP_pose",
    "actual_TCP_speed",
    "joint_temperatures",
    "robot_mode",
    "safety_mode",
    "runtime_state",
)


async def _done() -> None:
    """An awaitable that has nothing left to do."""


class URRobot:
    """A UR e-Series over RTDE (module docstring); an async context manager."""

    def __init__(
        self, settings: RobotSettings, *, first_backoff_s: float = RECONNECT_FIRST_BACKOFF_S
    ) -> None:
        self.settings = settings
        self.registers = RegisterMap(settings.register_base)
        self.dashboard = DashboardClient(
            settings.host, settings.dashboard_port, settings.command_timeout_s
        )
        self._client: RtdeClient | None = None
        self._outputs: Recipe | None = None
        self._inputs: Recipe | None = None
        self._link = LinkState.DISCONNECTED
        self._motion_held = False
        self._hold_reason: str | None = None
        self._holds = 0  # every hold ever: a resume that saw another one come stays held
        self._last_error: str | None = None
        self._sequence = 0  # the last one written
        self._target: tuple[float, ...] = (0.0,) * 6  # the correction on the wire (m, rad)
        self._state: OffsetRobotState | None = None
        self._lock = asyncio.Lock()  # resume and the reconnection, one at a time
        self._reader: asyncio.Task[None] | None = None
        self._heartbeat: asyncio.Task[None] | None = None
        self._reconnector = Reconnector(
            DEVICE,
            self._open_link,
            first_backoff_s=lambda: first_backoff_s,
            max_backoff_s=lambda: settings.reconnect_max_backoff_s,
            lock=self._lock,
            on_failure=lambda err: setattr(self, "_last_error", str(err)),
            task_name="ur-reconnect",
        )

    # -- the link ------------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        self._link = LinkState.CONNECTING
        try:
            await self._open_link()
        except BaseException:
            self._link = LinkState.FAULT
            raise
        self._heartbeat = asyncio.get_running_loop().create_task(
            self._heartbeat_loop(), name="ur-heartbeat"
        )
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._hold("closed", error=False)  # the program freezes the offset first
        await self._reconnector.cancel()
        for task in (self._heartbeat, self._reader):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        self._heartbeat = self._reader = None
        client, self._client = self._client, None
        if client is not None:
            await client.aclose()
        self._link = LinkState.DISCONNECTED

    async def _open_link(self) -> None:
        """Connect, set the recipes up, start, write the registers (the hold flag as it is)."""
        settings = self.settings
        client = RtdeClient(settings.host, settings.rtde_port, settings.ur_timeout_s)
        try:
            await client.connect()
            outputs = await client.setup_outputs(
                (*STATE_OUTPUTS, *self.registers.outputs), settings.rtde_frequency_hz
            )
            inputs = await client.setup_inputs(self.registers.inputs)
            await client.start()
        except BaseException:
            client.close()
            raise
        self._client, self._outputs, self._inputs = client, outputs, inputs
        self._link = LinkState.CONNECTED
        self._write()
        self._reader = asyncio.get_running_loop().create_task(
            self._read_loop(client, outputs), name="ur-rtde-reader"
        )
        logger.info(
            "UR %s connected (controller %s), registers from %d",
            settings.host,
            ".".join(map(str, client.controller_version or ())),
            self.registers.base,
        )

    async def _read_loop(self, client: RtdeClient, recipe: Recipe) -> None:
        try:
            while True:
                async with asyncio.timeout(self.settings.ur_timeout_s):
                    values = await client.read_data(recipe)
                self._state = self._state_of(recipe, values)
        except (DeviceError, TimeoutError) as err:
            message = str(err) or f"no RTDE package for {self.settings.ur_timeout_s} s"
            self._link_fault(client, message)

    def _link_fault(self, client: RtdeClient, message: str) -> None:
        if client is not self._client:
            return
        logger.warning("UR link lost (%s): correction held, reconnecting", message)
        self._hold(f"link lost: {message}")
        client.close()
        self._client = None
        self._link = LinkState.RECONNECTING
        self._reconnector.start()

    async def _heartbeat_loop(self) -> None:
        while True:
            await asyncio.sleep(self.settings.ur_heartbeat_s)
            if self._link is LinkState.CONNECTED:
                with contextlib.suppress(DeviceError):
                    self._write()

    # -- the registers -----------------------------------------------------------------------

    def _write(self) -> int:
        """One input package now: the next sequence, the hold flag, the target (synchronous:
        no await, so nothing can come between a caller's check and these bytes)."""
        client, inputs = self._client, self._inputs
        if client is None or inputs is None or not client.connected:
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")
        sequence = self._sequence % SEQUENCE_MAX + 1
        values: list[Value] = [sequence, 1 if self._motion_held else 0, *self._target]
        client.send(rtde.data_package(inputs, values))
        self._sequence = sequence
        return sequence

    def _checked(self, offset_mm: Vector3, rotation_rad: Vector3) -> tuple[float, ...]:
        require_finite(offset_mm, "correction", DEVICE)
        require_finite(rotation_rad, "correction rotation", DEVICE)
        length = math.hypot(*offset_mm)
        angle = math.hypot(*rotation_rad)
        if length > self.settings.correction_limit_mm:
            raise DeviceError(
                DEVICE,
                f"refused correction of {length:.4f} mm > robot.correction_limit_mm "
                f"{self.settings.correction_limit_mm}",
            )
        if angle > self.settings.correction_limit_rad:
            raise DeviceError(
                DEVICE,
                f"refused correction rotation of {angle:.6f} rad > robot.correction_limit_rad "
                f"{self.settings.correction_limit_rad}",
            )
        return (*(v / MM_PER_M for v in offset_mm), *(float(v) for v in rotation_rad))

    # -- the OffsetRobot protocol ------------------------------------------------------------

    def _require_allowed(self) -> None:
        if self._motion_held:
            raise MotionHeldError(DEVICE, f"correction held until resume(): {self._hold_reason}")
        if self._link is not LinkState.CONNECTED:
            raise NotConnectedError(DEVICE, f"not connected ({self._link.value})")

    async def set_correction(
        self, offset_mm: Vector3, rotation_rad: Vector3 = ZERO_ROTATION
    ) -> int:
        """Write the correction (mm and a rotation vector in rad, base frame); refused before
        any byte when not finite or over robot.correction_limit_*, when held or not connected.
        Returns the sequence it was written with (the program echoes it once accepted)."""
        target = self._checked(offset_mm, rotation_rad)
        self._require_allowed()  # no await from here to the write: a hold cannot slip in
        previous, self._target = self._target, target
        try:
            sequence = self._write()
        except DeviceError:
            self._target = previous
            raise
        assert self._client is not None
        await self._client.drain()
        return sequence

    def robot_state(self) -> OffsetRobotState:
        state = self._state
        if self._link is not LinkState.CONNECTED or state is None:
            raise NotConnectedError(DEVICE, f"no robot state ({self._link.value})")
        age = time.monotonic() - state.received_s
        if age > self.settings.ur_timeout_s:
            raise NotConnectedError(DEVICE, f"robot state {age:.2f} s old")
        return state

    def _hold(self, reason: str, *, error: bool = True) -> None:
        self._holds += 1
        self._motion_held = True
        self._hold_reason = reason
        if error:
            self._last_error = reason
        with contextlib.suppress(DeviceError, OSError):
            self._write()  # tell the program now (a lost link: its watchdog freezes it)

    def stop(self) -> Coroutine[Any, Any, None]:
        """Hold, from the moment this is called (module docstring). Awaiting it drains the
        hold's package to the socket."""
        self._hold("stopped by request", error=False)
        client = self._client
        return client.drain() if client is not None else _done()

    async def resume(self) -> None:
        """Release a hold: the link must be up with a fresh state; a hold that comes while
        this waits wins (MotionHeldError, the hold stays)."""
        holds_before = self._holds
        async with self._lock:
            self.robot_state()  # NotConnectedError when the link is not up and fresh
            if self._holds != holds_before:
                raise MotionHeldError(
                    DEVICE, f"held again while resuming, stays held: {self._hold_reason}"
                )
            self._motion_held = False
            self._hold_reason = None
            self._write()
        logger.info("UR correction resumed")

    def status(self) -> RobotStatus:
        client = self._client
        state = self._state
        extra = {
            "host": self.settings.host,
            "register_base": str(self.registers.base),
            "sequence": str(self._sequence),
            "reconnect_attempts": str(self._reconnector.attempts),
        }
        if client is not None and client.controller_version is not None:
            extra["controller_version"] = ".".join(map(str, client.controller_version))
            extra["bytes_sent"] = str(client.bytes_sent)
            extra["bytes_received"] = str(client.bytes_received)
        if state is not None:
            extra["robot_mode"] = str(state.robot_mode)
            extra["safety_mode"] = str(state.safety_mode)
            extra["runtime_state"] = str(state.runtime_state)
            extra["program_status"] = str(state.program_status)
        return RobotStatus(
            link=self._link,
            motion_held=self._motion_held,
            last_error=self._last_error,
            hold_reason=self._hold_reason if self._motion_held else None,
            extra=extra,
        )

    # -- state packages ----------------------------------------------------------------------

    def _state_of(self, recipe: Recipe, values: tuple[Value, ...]) -> OffsetRobotState:
        named = dict(zip(recipe.names, values, strict=True))
        regs = self.registers

        def floats(name: str) -> tuple[float, ...]:
            value = named[name]
            assert isinstance(value, tuple)
            return tuple(float(v) for v in value)

        def integer(name: str) -> int:
            return int(named[name])  # type: ignore[arg-type]

        pose = floats("actual_TCP_pose")
        speed = floats("actual_TCP_speed")
        applied = [float(named[name]) for name in regs.applied]  # type: ignore[arg-type]
        return OffsetRobotState(
            timestamp_s=float(named["timestamp"]),  # type: ignore[arg-type]
            received_s=time.monotonic(),
            joints_rad=floats("actual_q"),
            joint_speeds_rad_s=floats("actual_qd"),
            tcp_pose=(*(v * MM_PER_M for v in pose[:3]), *pose[3:]),  # type: ignore[arg-type]
            tcp_speed=(*(v * MM_PER_M for v in speed[:3]), *speed[3:]),  # type: ignore[arg-type]
            joint_temperatures_c=floats("joint_temperatures"),
            robot_mode=integer("robot_mode"),
            safety_mode=integer("safety_mode"),
            runtime_state=integer("runtime_state"),
            at_pose=integer(regs.at_pose),
            accepted_sequence=integer(regs.accepted_sequence),
            program_status=integer(regs.status),
            applied_offset_mm=(applied[0] * MM_PER_M, applied[1] * MM_PER_M, applied[2] * MM_PER_M),
            applied_rotation_rad=(applied[3], applied[4], applied[5]),
        )
