"""The garbage collector, the locked memory and the control loop's deadlines (issues 17, 30).

CPython 3.11's cyclic collector is not incremental: a full (generation-2) collection walks
every tracked object of the process at once. A daemon that has imported its stack (FastAPI,
pydantic, NumPy, the drivers) holds a few hundred thousand of them, and one full collection
then stops the event loop for 10-15 ms. Measured on the fast path (benchmarks/bench_fast_path.py,
20 ms step, emulator in-process, load 0.0-0.3 on 2 cores): the one overrun of a 60 s run was a
23.0 ms step containing a 14.1 ms generation-2 collection, and every other step was <= 13.8 ms;
with the start-up heap frozen the same run had no collection inside any step and no overrun.

``gc.freeze()`` (Python docs, "gc — Garbage Collector interface": "freeze all the objects
tracked by gc; move them to a permanent generation and ignore all the future collections")
takes what start-up built out of every later collection. What the daemon allocates afterwards
is still collected as usual, and full collections then only walk that (generation 2 is
collected when it grew by a quarter since the last full one, so they stay proportionate).
"""

from __future__ import annotations

import ctypes
import gc
import logging
import os
import resource
import sys
import time
from pathlib import Path

logger = logging.getLogger(__name__)


def freeze_startup_heap() -> float:
    """Collect once (cycles left by start-up are not frozen forever), then freeze what is
    left; returns the time the collection took (s). Call it once the devices are open and
    before the control loop's first deadline; calling it again later freezes what has
    accumulated since (it never unfreezes)."""
    started = time.perf_counter()
    gc.collect()
    gc.freeze()
    elapsed_s = time.perf_counter() - started
    logger.info(
        "start-up heap frozen: %d objects out of the collector's reach (%.1f ms)",
        gc.get_freeze_count(),
        elapsed_s * 1000.0,
    )
    return elapsed_s


#: mlockall(2) flags (Linux, every architecture thermocomp runs on: x86-64, AArch64; the
#: values differ only on Alpha, PowerPC and SPARC): the pages mapped now, those mapped later,
#: and each only once first touched (Linux 4.4). Without MCL_ONFAULT every mapping is filled
#: in when made: each thread's whole 8 MiB stack, every malloc arena (measured: a served
#: daemon's resident memory 821 MiB instead of ~200).
MCL_CURRENT = 1
MCL_FUTURE = 2
MCL_ONFAULT = 4
#: CAP_IPC_LOCK's bit in /proc/self/status CapEff (linux/capability.h): locking ignores the limit
CAP_IPC_LOCK = 14


def lock_memory() -> str:
    """Lock every page of the process in RAM, now and later (``mlockall(MCL_CURRENT |
    MCL_FUTURE | MCL_ONFAULT)`` through ctypes: the standard library has no binding), so that
    a step never waits for a page to come back from swap or a file; return the one line that
    says what was done. Only when nothing it will map later can exceed the locking limit
    (the limit is unlimited, or the process holds CAP_IPC_LOCK): with a finite limit,
    MCL_FUTURE makes any allocation past it fail, a crash waiting to happen; then nothing is
    locked and the line
    says what to grant (deploy/thermocomp.service sets LimitMEMLOCK=infinity)."""
    if not sys.platform.startswith("linux"):
        return f"memory not locked: mlockall is Linux's ({sys.platform})"
    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    if soft != resource.RLIM_INFINITY and not _has_capability(CAP_IPC_LOCK):
        return (
            f"memory not locked: the locking limit is {soft // 1024} KiB and the process "
            "lacks CAP_IPC_LOCK (grant LimitMEMLOCK=infinity: deploy/thermocomp.service)"
        )
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT) != 0:
        error = ctypes.get_errno()
        return f"memory not locked: mlockall failed ({os.strerror(error)})"
    return "memory locked in RAM (mlockall: current and future pages, as they are touched)"


def log_memory_lock(outcome: str) -> None:
    """:func:`lock_memory`'s line in the log: a warning when nothing was locked."""
    if outcome.startswith("memory locked"):
        logger.info("%s", outcome)
    else:
        logger.warning("%s (scheduler.lock_memory = false silences this)", outcome)


def _has_capability(bit: int) -> bool:
    try:
        status = Path("/proc/self/status").read_text()
    except OSError:
        return False
    for line in status.splitlines():
        if line.startswith("CapEff:"):
            return bool(int(line.split()[1], 16) >> bit & 1)
    return False
