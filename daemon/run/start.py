"""What a run is built from when the daemon starts it: the daemon's parts every kind's build
takes (daemon/run/kinds.py chooses the kind; each kind builds its work in its own package:
daemon/run/two_link/build.py, arm/build.py, followed/build.py) and the run's row in the run
database. Nothing here starts a run or changes a run's state: daemon/service.py builds under
its request lock and daemon/run/session.py runs what was built.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from config import Settings
from daemon import __version__
from daemon.run.arm.setup import ArmMeterFactory, ArmSetup
from daemon.run.devices_check import Devices
from daemon.run.events import ErrorLog
from daemon.run.sensors import Sensors
from daemon.run.states import RunParameters
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder
from drivers.clock import Clock


@dataclass(frozen=True, slots=True)
class RunBuilder:
    """The daemon's parts a new run is built from (one per start)."""

    settings: Settings
    clock: Clock
    #: the daemon's open devices, read where they are used (RuntimeError once it is closed)
    devices: Callable[[], Devices]
    sensors: Sensors | None  # None until the daemon's devices are open
    workers: Workers
    recorder: Recorder
    errors: ErrorLog
    #: the arm kind's seams (daemon/service.py Daemon's arguments, for tests): an arm run's
    #: model and poses (issue 20) and its tool measurement
    arm_setup: ArmSetup
    arm_meter: ArmMeterFactory

    async def create_run(
        self, parameters: RunParameters, snapshot: dict[str, Any] | None, *, kind: str
    ) -> int:
        """The run's row in the run database, with its parameters, settings, ``snapshot`` (its
        network or arm model) and its kind's name; returns its id."""
        return await self.workers.db(
            functools.partial(self.recorder.create_run, kind=kind),
            parameters.model_dump(mode="json"),
            self.settings.model_dump(mode="json"),
            snapshot,
            __version__,
        )
