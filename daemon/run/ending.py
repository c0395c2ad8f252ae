"""What a run's end writes (daemon/run/session.py ``_finish``): the final state, then the
summary -- computed, recorded with the run, or deferred to the next start when a shutdown gives
it up -- each on the recorder's thread. Nothing here raises for a storage failure: the failure
is logged and noted, what could not be written is kept for later (daemon/run/unrecorded_end.py,
daemon/run/pending_summaries.py), and the run still ends (issue 15, point 5).

The state machine is not touched here: the session changes the state, this only stores.
"""

from __future__ import annotations

import functools
import logging
import threading
from typing import Any

from daemon.run.kind import RunKind
from daemon.run.services import SessionServices
from daemon.run.states import RunState
from daemon.run.summary import SummaryBasis
from daemon.storage.series import SummaryAbandonedError

logger = logging.getLogger(__name__)


async def record_end(
    services: SessionServices, run_id: int, final: RunState, reason: str | None
) -> bool:
    """The final state, committed; False when it could not be (kept and written again by
    daemon/run/unrecorded_end.py, with the summary once there is one)."""
    try:
        await services.workers.db(services.recorder.finish_run, run_id, final.value, None, reason)
    except Exception as err:
        logger.error("run %d: cannot record its end yet: %s", run_id, err)
        services.errors.note(err, device="storage")
        services.post_home(
            lambda: services.unrecorded_end.remember(run_id, final.value, None, reason)
        )
        return False
    return True


async def summarize(
    services: SessionServices, kind: RunKind, basis: SummaryBasis, abandon: threading.Event
) -> dict[str, Any] | None:
    """The run's summary, read back on the recorder's thread; None when there is none (given
    up through ``abandon`` by a shutdown, or failed: logged)."""
    run_summary = functools.partial(kind.summary, services.recorder, basis, abandon=abandon)
    try:
        return await services.workers.db(run_summary)
    except SummaryAbandonedError as err:
        if not abandon.is_set():  # not a shutdown's: nothing to defer to
            logger.warning("run %d: no summary: %s", kind.run_id, err)
    except Exception as err:
        logger.exception("run %d: no summary", kind.run_id)
        services.errors.note(err, device="storage")
    return None


async def store_summary(
    services: SessionServices,
    run_id: int,
    summary: dict[str, Any],
    *,
    recorded: bool,
    final: RunState,
    reason: str | None,
) -> None:
    """The summary with its run; with the end kept for later when the end itself could not be
    ``recorded`` (both written again by daemon/run/unrecorded_end.py)."""
    if recorded:
        try:
            await services.workers.db(services.recorder.set_summary, run_id, summary)
        except Exception as err:
            logger.error("run %d: cannot record its summary: %s", run_id, err)
            services.errors.note(err, device="storage")
    else:
        services.post_home(
            lambda: services.unrecorded_end.remember(run_id, final.value, summary, reason)
        )


async def defer_summary(services: SessionServices, run_id: int, basis: SummaryBasis) -> bool:
    """A shutdown gave the summary up: keep what only memory holds with the run, for the
    next start to compute it (daemon/run/pending_summaries.py). One row, milliseconds."""
    try:
        await services.workers.db(services.recorder.defer_summary, run_id, basis)
    except Exception as err:
        logger.error("run %d: no summary: cannot defer it: %s", run_id, err)
        services.errors.note(err, device="storage")
        return False
    logger.warning("run %d: summary deferred to the next start (the stop's budget ran out)", run_id)
    return True
