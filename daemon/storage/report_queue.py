"""End-of-run reports, produced only here, one at a time, in a child process (issue 15/16).

A report reads every step back and draws figures (seconds for a long run): done inside the run's
ending it would delay the stop and the shutdown, and a reader of the API could race the daemon
into the same folder. So the run ends first, then its report is queued; a child process (not a
thread) writes it, bounded by ``REPORT_TIMEOUT_S`` and killed at shutdown, so neither a slow
report nor systemd's stop timeout ever wait on the other. ``GET /runs/{id}/report`` asks
:meth:`ReportQueue.status`: 202 while queued or writing, the file once written, 404 otherwise.
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import logging
import os
import sys
from pathlib import Path

from daemon.storage.reports import report_dir

logger = logging.getLogger(__name__)

#: Longest a report may take (s); the end of a 180,000-step run takes ~10 s here
#: (benchmarks/bench_run_end.py), so this only stops a report that hangs.
REPORT_TIMEOUT_S = 600.0
#: How long a shutdown waits for the child to go after SIGTERM before SIGKILL (s).
KILL_GRACE_S = 1.0


class ReportStatus(enum.Enum):
    QUEUED = "queued"
    WRITING = "writing"
    WRITTEN = "written"
    FAILED = "failed"


class ReportQueue:
    def __init__(self, data_dir: Path) -> None:
        self._data_dir = Path(data_dir)
        self._queue: asyncio.Queue[int] = asyncio.Queue()
        self._status: dict[int, ReportStatus] = {}
        self._done: dict[int, asyncio.Event] = {}
        self._worker: asyncio.Task[None] | None = None

    def start(self) -> None:
        self._worker = asyncio.get_running_loop().create_task(self._serve(), name="reports")

    async def close(self) -> None:
        """Abandon queued reports and end the one being written (shutdown never waits)."""
        worker, self._worker = self._worker, None
        if worker is not None:
            worker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await worker

    def submit(self, run_id: int) -> None:
        self._status[run_id] = ReportStatus.QUEUED
        self._done[run_id] = asyncio.Event()
        self._queue.put_nowait(run_id)

    def status(self, run_id: int) -> ReportStatus | None:
        """This daemon's knowledge of the run's report; None: never queued here."""
        return self._status.get(run_id)

    def html_path(self, run_id: int) -> Path:
        return report_dir(self._data_dir, run_id) / "report.html"

    async def wait(self, run_id: int) -> ReportStatus | None:
        """Wait until the run's report is written or has failed (for ``thermocomp run``)."""
        done = self._done.get(run_id)
        if done is not None:
            await done.wait()
        return self._status.get(run_id)

    async def _serve(self) -> None:
        while True:
            run_id = await self._queue.get()
            self._status[run_id] = ReportStatus.WRITING
            written = False
            try:
                written = await self._write(run_id)
            except OSError as err:
                logger.warning("run %d: no report: cannot start its writer: %s", run_id, err)
            finally:
                self._status[run_id] = ReportStatus.WRITTEN if written else ReportStatus.FAILED
                self._done[run_id].set()

    async def _write(self, run_id: int) -> bool:
        child = await asyncio.create_subprocess_exec(
            sys.executable,
            "-m",
            "daemon.storage.report_worker",
            str(self._data_dir),
            str(run_id),
            stdin=asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.DEVNULL,
            stderr=asyncio.subprocess.PIPE,
            env={**os.environ, "MPLBACKEND": "Agg"},
        )
        try:
            async with asyncio.timeout(REPORT_TIMEOUT_S):
                _, stderr = await child.communicate()
        except TimeoutError:
            await _end(child)
            logger.warning("run %d: no report: not written within %g s", run_id, REPORT_TIMEOUT_S)
            return False
        except asyncio.CancelledError:  # a shutdown: the child goes too, at once
            await _end(child)
            raise
        if child.returncode != 0:
            last = stderr.decode(errors="replace").strip().splitlines()[-1:] or ["(no message)"]
            logger.warning("run %d: no report: %s", run_id, last[0])
            return False
        logger.info("run %d: report %s", run_id, self.html_path(run_id))
        return True


async def _end(child: asyncio.subprocess.Process) -> None:
    if child.returncode is not None:
        return
    child.terminate()
    try:
        async with asyncio.timeout(KILL_GRACE_S):
            await child.wait()
    except TimeoutError:
        child.kill()
        await child.wait()
