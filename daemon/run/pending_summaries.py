"""Summaries a shutdown deferred, computed when the daemon starts next.

A day at a 20 ms step is 4.32 M steps to read back for the summary: more than a shutdown may
take within systemd's TimeoutStopSec (deploy/thermocomp.service, 30 s; daemon/service.py
SHUTDOWN_SUMMARY_BUDGET_S). The run's end is committed first; a summary the shutdown gives up
is deferred, not lost: the session keeps what only its memory held (overruns, skipped
deadlines, the timing, the kind's own figures: daemon/run/summary.py SummaryBasis) with the run
(daemon/storage/recorder.py ``pending_summaries``), and the next start computes it here, from
the same values, so it is the summary the end would have written.

Off the event loop and after the daemon is ready: the steps are read on a thread of their own
(daemon/run/workers.py ``summary``: never the recorder's one writing thread, which a new run's
steps need, nor an API read's, whose pool a day's summary held ~87 s), the summary is written
on the recorder's thread (one writer), and a shutdown gives it up again at once -- the pending
row is removed only in the transaction that writes the summary, so it survives any number of
those.
"""

from __future__ import annotations

import asyncio
import logging
import threading

from daemon.run.events import ErrorLog
from daemon.run.kinds import summary_from_basis
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder
from daemon.storage.report_queue import ReportQueue
from daemon.storage.series import SummaryAbandonedError

__all__ = ["PendingSummaries"]

logger = logging.getLogger(__name__)


class PendingSummaries:
    """The one task that computes the deferred summaries; :meth:`stop` gives it up."""

    def __init__(
        self,
        workers: Workers,
        recorder: Recorder,
        reports: ReportQueue,
        errors: ErrorLog,
        *,
        report_at_end: bool,
    ) -> None:
        self._workers = workers
        self._recorder = recorder
        self._reports = reports
        self._errors = errors
        self._report_at_end = report_at_end
        self._abandon = threading.Event()  # checked by the chunked reader between chunks
        self._task: asyncio.Task[None] | None = None

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(
            self._compute_all(), name="pending-summaries"
        )

    def give_up(self) -> None:
        """A shutdown: the reading in progress ends at its next chunk; nothing is lost."""
        self._abandon.set()

    async def stop(self) -> None:
        self.give_up()
        task, self._task = self._task, None
        if task is not None:
            await task  # ends within a chunk's read: never cancelled mid-write

    async def wait(self) -> None:
        """Until every pending summary is computed or given up (tests, ``thermocomp run``)."""
        if self._task is not None:
            await asyncio.shield(self._task)

    async def _compute_all(self) -> None:
        try:
            pending = await self._workers.summary(self._recorder.pending_summaries)
        except Exception as err:  # the database: the rows stay for the next start
            logger.error("deferred summaries: cannot read them: %s", err)
            self._errors.note(err, device="storage")
            return
        for run_id, basis in pending:
            if self._abandon.is_set() or not await self._compute(run_id, basis):
                return

    async def _compute(self, run_id: int, basis: dict[str, object]) -> bool:
        """False: given up (a shutdown); the pending row stays."""
        try:
            summary = await self._workers.summary(
                summary_from_basis, self._recorder, basis, self._abandon
            )
            await self._workers.db(self._recorder.set_summary, run_id, summary)
        except SummaryAbandonedError:
            logger.info("run %d: summary still deferred (the daemon stops)", run_id)
            return False
        except Exception as err:  # kept pending: tried again at the next start
            logger.error("run %d: cannot compute its deferred summary: %s", run_id, err)
            self._errors.note(err, device="storage")
            return True
        logger.info("run %d: deferred summary computed and recorded", run_id)
        if self._report_at_end:
            self._reports.submit(run_id)
        return True
