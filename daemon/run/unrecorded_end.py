"""A run's end that could not be written (disk full, read-only database), kept and written
again until it is (issue 15, point 8): the run still ends in its final state at once, and the
database catches up; a new run is refused while the last one's end is still unrecorded.

The daemon (daemon/service.py) owns one; the session reports an end it could not write
through SessionServices.on_unrecorded_end. Nothing here changes a run's state: it only writes
the end the session already reached.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Any

from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder, RecorderError

logger = logging.getLogger(__name__)

#: A run's end as RunSession ends it: run id, final state, summary, reason.
RunEnd = tuple[int, str, dict[str, Any] | None, str | None]


class UnrecordedEnd:
    """The last run's end while it is not recorded, and the task that writes it again."""

    def __init__(
        self, storage: Callable[[], tuple[Workers, Recorder] | None], retry_s: float
    ) -> None:
        self._storage = storage  # the daemon's workers and recorder; None while not open
        self._retry_s = retry_s
        self._pending: RunEnd | None = None
        self._task: asyncio.Task[None] | None = None

    def remember(
        self, run_id: int, state: str, summary: dict[str, Any] | None, reason: str | None
    ) -> None:
        """Keep the end and write it as soon as writing works again."""
        self._pending = (run_id, state, summary, reason)
        if self._task is None or self._task.done():
            self._task = asyncio.get_running_loop().create_task(
                self._retry(), name="record-run-end"
            )

    async def _retry(self) -> None:
        while self._pending is not None:
            await asyncio.sleep(self._retry_s)
            await self.record()

    async def record(self, *, raise_on_failure: bool = False) -> None:
        """Write the kept end now, if there is one; RecorderError only if ``raise_on_failure``
        (a start: it waits for the end of the run before)."""
        pending, storage = self._pending, self._storage()
        if pending is None or storage is None:
            return
        workers, recorder = storage
        try:
            await workers.db(recorder.finish_run, *pending)
        except RecorderError as err:
            if raise_on_failure:
                raise RecorderError(
                    f"the end of run {pending[0]} is not recorded yet ({err}); "
                    "free the disk or fix the database, then start again"
                ) from err
            return
        if self._pending is pending:
            self._pending = None
        logger.info("run %d: its end is recorded now (%s)", pending[0], pending[1])

    async def stop_retrying(self) -> None:
        """Cancel the retry task (the daemon is closing; it tries once more itself)."""
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
