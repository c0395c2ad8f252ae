"""The runs of ``thermocomp calibrate model``'s chains, two-link
(daemon/commands/calibrate_model.py) and arm (daemon/commands/calibrate_arm_model.py): each run
in a daemon of its own, a failed step as :class:`StepFailedError` with its exit status."""

from __future__ import annotations

import asyncio
from typing import TYPE_CHECKING, Any

from config import Settings
from config.cli import EXIT_FAILURE, EXIT_USAGE
from daemon.commands.run import _supervise
from daemon.run.states import RunParameters, RunState
from drivers.errors import DeviceError

if TYPE_CHECKING:
    from daemon.service import Daemon

PROG = "thermocomp calibrate model"


class StepFailedError(Exception):
    """A step of the chain failed: the message says which; ``status`` is the exit status."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(message)
        self.status = status


async def one_run(daemon: Daemon, settings: Settings, what: str, **values: Any) -> dict[str, Any]:
    # lazy: the run's set-up (NumPy, SciPy) loads when a run starts, not for --help (issue
    # 16): `thermocomp calibrate --help` imports this module
    from daemon.run.setup import RunParameterError

    try:
        parameters = RunParameters.from_settings(settings, **values)
        await daemon.start_run(parameters)
    except (RunParameterError, ValueError) as err:
        raise StepFailedError(f"{what}: {err}", EXIT_USAGE) from err
    final = await _supervise(daemon, asyncio.Event())
    if final["state"] != RunState.FINISHED.value:
        raise StepFailedError(
            f"{what} (run {final['id']}) {final['state']}: {final.get('reason')}", EXIT_FAILURE
        )
    return final


async def run_alone(settings: Settings, what: str, **values: Any) -> dict[str, Any]:
    """One run in its own daemon (opened and closed around it: identification runs between
    the runs with no device open, so a virtual clock never jumps while it computes)."""
    # lazy: the daemon (NumPy, SciPy, the drivers) loads when a run starts, not for --help
    from daemon.service import Daemon
    from daemon.storage.recorder import RecorderError

    try:
        async with Daemon(settings) as daemon:
            return await one_run(daemon, settings, what, **values)
    except (DeviceError, RecorderError, OSError) as err:
        raise StepFailedError(f"{what}: {err}", EXIT_FAILURE) from err
