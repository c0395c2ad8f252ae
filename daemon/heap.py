"""The garbage collector and the control loop's deadlines (issue 17).

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

import gc
import logging
import time

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
