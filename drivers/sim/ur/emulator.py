"""The UR e-Series emulator (issue 31): the emulated controller (drivers/sim/ur/controller.py)
run at its 500 Hz cycle, served over RTDE (port 30004) and the Dashboard Server (port 29999)
on a loopback address: 127.0.0.1 by default, any 127.0.0.N when asked (tests use one per test,
since ur-rtde's clients always dial UR's fixed ports).

The clock is the asyncio loop's, from the emulator's start. Each wake-up runs every controller
cycle that is due (a late wake-up catches up, each cycle at its own time, so a package's
``timestamp`` is always its cycle's: 2 ms apart at 500 Hz), then sleeps until the next cycle.

Faults (methods, and signals under ``thermocomp emulate ur``): ``drop_connections()`` (a cable
pulled: every RTDE and Dashboard connection closed), ``silence(on)`` (the network goes quiet:
no packages out, inputs dropped), ``protective_stop()`` (the arm halts, the program pauses,
safety mode PROTECTIVE_STOP until the Dashboard's "unlock protective stop"),
``operator_stop()`` (the program stopped on the teach pendant).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from types import TracebackType
from typing import Self

from drivers.sim.ur.controller import URController, URControllerConfig
from drivers.sim.ur.dashboard import DASHBOARD_PORT, DashboardServer
from drivers.sim.ur.rtde_server import RTDE_PORT, RtdeServer
from drivers.ur.rtde_protocol import CONTROLLER_CYCLE_S

logger = logging.getLogger(__name__)

DEFAULT_HOST = "127.0.0.1"
#: Cycles caught up at most in one wake-up; a loop stalled longer than this (1 s) skips the
#: rest (and the clients see a gap in the timestamps, as from a controller that was starved).
MAX_CATCH_UP_CYCLES = 500


class UREmulator:
    """``async with UREmulator(config, host=...) as ur:`` serves until the block ends."""

    def __init__(
        self,
        config: URControllerConfig | None = None,
        *,
        host: str = DEFAULT_HOST,
        rtde_port: int = RTDE_PORT,
        dashboard_port: int = DASHBOARD_PORT,
        controller: URController | None = None,
    ) -> None:
        self.controller = controller or URController(config)
        self.host = host
        self._t0 = 0.0
        self.rtde = RtdeServer(self.controller, host, rtde_port)
        self.dashboard = DashboardServer(self.controller, self.now, host, dashboard_port)
        self._task: asyncio.Task[None] | None = None
        self.skipped_cycles = 0
        #: called after every controller cycle with (cycle, t): benchmarks watch the program
        self.observers: list[Callable[[int, float], None]] = []

    @property
    def rtde_port(self) -> int:
        return self.rtde.port

    @property
    def dashboard_port(self) -> int:
        return self.dashboard.port

    def now(self) -> float:
        """Emulator time (s since the start)."""
        return asyncio.get_running_loop().time() - self._t0

    async def __aenter__(self) -> Self:
        loop = asyncio.get_running_loop()
        self._t0 = loop.time()
        await self.rtde.start()
        try:
            await self.dashboard.start()
        except BaseException:
            await self.rtde.close()
            raise
        self._task = loop.create_task(self._run(), name="ur-emulator")
        logger.info(
            "UR emulator on %s: RTDE %d, Dashboard %d",
            self.host,
            self.rtde.port,
            self.dashboard.port,
        )
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        await self.rtde.close()
        await self.dashboard.close()

    async def _run(self) -> None:
        controller = self.controller
        cycle = controller.cycles
        while True:
            now = self.now()
            due = int(now / CONTROLLER_CYCLE_S)
            if due - cycle > MAX_CATCH_UP_CYCLES:
                self.skipped_cycles += due - cycle - MAX_CATCH_UP_CYCLES
                cycle = due - MAX_CATCH_UP_CYCLES
            while cycle < due:
                cycle += 1
                t = cycle * CONTROLLER_CYCLE_S
                controller.cycle(t)
                self.rtde.tick(cycle, t)
                for observer in self.observers:
                    observer(cycle, t)
            await asyncio.sleep((cycle + 1) * CONTROLLER_CYCLE_S - self.now())

    # -- faults ------------------------------------------------------------------------------

    def drop_connections(self) -> None:
        self.rtde.drop_connections()
        self.dashboard.drop_connections()

    def silence(self, on: bool = True) -> None:
        self.rtde.silent = on

    def protective_stop(self) -> None:
        self.controller.protective_stop(self.now())

    def operator_stop(self) -> None:
        self.controller.stop(self.now())
