"""Real-time scheduling of the calling thread when the host permits it, else a lower niceness,
said in one line: the control loop's thread (daemon/run/control_loop.py) and the emulated
controller's process (drivers/sim/emulator_process.py, issue 30) ask for it alike. And the way
out of it for the daemon's background work (:func:`background_priority`): Linux hands a
thread's or a process's policy on to the threads and processes it starts, and exports,
reports and deferred summaries are long, CPU-heavy and never on a step's path; at a real-time
priority they would take a core from every ordinary process of the lab PC for seconds.

Linux applies ``sched_setscheduler(0, ...)`` and ``setpriority(PRIO_PROCESS, tid, ...)`` to the
calling thread alone; SCHED_FIFO needs CAP_SYS_NICE or LimitRTPRIO (deploy/thermocomp.service).
"""

from __future__ import annotations

import contextlib
import os
import threading

#: Niceness change tried when real-time scheduling is not permitted (relative to the thread's;
#: lowering it needs CAP_SYS_NICE or LimitNICE too).
FALLBACK_NICENESS = -10


def realtime_scheduling(priority: int) -> str:
    """Ask for ``SCHED_FIFO`` at ``priority`` for the calling thread, else a lower niceness;
    return what it runs with (for the one log line)."""
    if priority <= 0:
        return "normal scheduling (realtime_priority = 0)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError, AttributeError) as err:
        reason = getattr(err, "strerror", None) or str(err)
    else:
        return f"SCHED_FIFO priority {priority}"
    try:
        niceness = lower_niceness(FALLBACK_NICENESS)
    except (PermissionError, OSError, AttributeError):
        return (
            f"normal scheduling: SCHED_FIFO not permitted ({reason}) nor niceness "
            f"{FALLBACK_NICENESS:+d}; grant CAP_SYS_NICE or LimitRTPRIO "
            "(deploy/thermocomp.service)"
        )
    return f"niceness {niceness}: SCHED_FIFO not permitted ({reason})"


def lower_niceness(change: int) -> int:
    """The calling thread's niceness changed by ``change`` (Linux: PRIO_PROCESS with a thread
    id sets that thread's alone; threads it starts later inherit it); the new niceness."""
    thread = threading.get_native_id()
    niceness = max(os.getpriority(os.PRIO_PROCESS, thread) + change, -20)
    os.setpriority(os.PRIO_PROCESS, thread, niceness)
    return niceness


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
