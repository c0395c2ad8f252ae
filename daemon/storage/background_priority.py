"""The daemon's background work leaves real-time scheduling (issue 30).

When real-time scheduling is granted, the daemon's threads run at ``SCHED_FIFO``
(daemon/run/control_loop.py), and Linux hands a thread's or a process's scheduling policy on to
the threads and processes it starts. Exports, reports and deferred summaries are long, CPU-heavy
and never on a step's path: at a real-time priority they would take a core from every ordinary
process of the lab PC for seconds. They call :func:`background_priority` first.
"""

from __future__ import annotations

import contextlib
import os
import threading


def background_priority(niceness: int) -> None:
    """The calling thread (in a new process: the process) back to normal scheduling, at least
    ``niceness``. Leaving real-time scheduling and raising one's niceness need no privilege;
    where the host refuses anyway, the work runs as it is (slower elsewhere, never wrong)."""
    with contextlib.suppress(OSError, AttributeError):
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    thread = threading.get_native_id()  # Linux: PRIO_PROCESS with a thread id: that thread's
    with contextlib.suppress(OSError):
        os.setpriority(
            os.PRIO_PROCESS, thread, max(os.getpriority(os.PRIO_PROCESS, thread), niceness)
        )
