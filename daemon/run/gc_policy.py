"""Full garbage collections kept out of a run's steps: done between steps, where there is slack.

The start-up heap is frozen (daemon/heap.py), so a full (generation-2) collection walks only
what the daemon allocated since; but CPython 3.11's collector still does it all at once, in
whichever thread's allocation crossed the threshold, holding the GIL: a full collection started
by the API's thread stops the control thread as surely as one started by the step itself.
While a run steps, automatic full collections are therefore deferred (the third threshold
raised, :data:`DEFERRED_THRESHOLD2`: the young generations are still collected as usual, they
take tens of microseconds), and the control loop collects generation 2 itself right after a
step when one is due (as many generation-1 collections as CPython's own threshold) and the time
left before the next deadline is at least :data:`SLACK_FACTOR` times the longest full
collection seen so far. Memory stays bounded: past :data:`MAX_DEFERRED` generation-1
collections without a full one, it is done after the next step whatever the slack (a step too
tight for it at every turn pays for one, instead of the memory growing). Outside the step loop
(idle, paused, held) CPython's thresholds are back.

:class:`GcWatch` measures every collection through ``gc.callbacks`` (Python docs, "gc —
Garbage Collector interface": called before and after each collection with its generation),
and whether a step was under way: the /metrics figures and benchmarks/bench_gc_pauses.py.
"""

from __future__ import annotations

import gc
import threading
import time
from collections import deque
from typing import Any

#: Generation-2 threshold while a run steps: automatic full collections effectively never
#: happen (10^6 generation-1 collections are some 10^10 allocations).
DEFERRED_THRESHOLD2 = 1_000_000
#: Collect between steps only with this many times the longest full collection seen left
#: before the next deadline.
SLACK_FACTOR = 2.0
#: The first full collection's expected length, before one was measured (s): the frozen
#: daemon's heap took 0.3 ms (docs/explanation/decisions/0007-freeze-the-heap.md).
FIRST_FULL_GUESS_S = 0.002
#: Generation-1 collections without a full one after which it is done whatever the slack:
#: ten times CPython's default (10), the bound on what deferring may keep in memory.
MAX_DEFERRED = 100
#: Pauses kept per generation for the percentiles (bounded memory).
PAUSE_WINDOW = 10_000


class GcWatch:
    """Every collection of the process: how long it took, by generation, and whether a step
    was under way (``step_running``, set by the step loop). Install once, remove at the end;
    the callback only appends and counts (no lock, no logging: it runs inside the collector,
    in any thread)."""

    def __init__(self) -> None:
        self.pauses_s: tuple[deque[float], ...] = tuple(
            deque(maxlen=PAUSE_WINDOW) for _ in range(3)
        )
        self.collections = [0, 0, 0]
        self.in_step = [0, 0, 0]  # of them, while a step was under way
        self.longest_full_s = 0.0
        self.step_running = False
        self._started = 0.0

    def reset(self) -> None:
        """Count from now (after the start-up heap's one collection, daemon/heap.py)."""
        for pauses in self.pauses_s:
            pauses.clear()
        self.collections = [0, 0, 0]
        self.in_step = [0, 0, 0]
        self.longest_full_s = 0.0

    def install(self) -> None:
        if self._callback not in gc.callbacks:
            gc.callbacks.append(self._callback)

    def remove(self) -> None:
        if self._callback in gc.callbacks:
            gc.callbacks.remove(self._callback)

    def _callback(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._started = time.perf_counter()
            return
        elapsed = time.perf_counter() - self._started
        generation = int(info.get("generation", 2))
        self.collections[generation] += 1
        self.pauses_s[generation].append(elapsed)
        if self.step_running:
            self.in_step[generation] += 1
        if generation == 2:
            self.longest_full_s = max(self.longest_full_s, elapsed)


class GcPolicy:
    """The step loop's collector policy (one per daemon; the thresholds are the process's).
    ``enabled`` False (``scheduler.gc_between_steps``): CPython's own thresholds throughout,
    the collections still watched."""

    def __init__(self, *, enabled: bool) -> None:
        self.enabled = enabled
        self.watch = GcWatch()
        self.between_steps = 0  # full collections done here with the slack for them
        self.forced = 0  # ... done here past MAX_DEFERRED whatever the slack
        self._saved: tuple[int, int, int] | None = None
        self._lock = threading.Lock()

    def install(self) -> None:
        self.watch.install()

    def remove(self) -> None:
        self.resume_automatic()
        self.watch.remove()

    def defer_full(self) -> None:
        """A run steps from now on: automatic full collections deferred."""
        if not self.enabled:
            return
        with self._lock:
            if self._saved is None:
                self._saved = gc.get_threshold()
                gc.set_threshold(self._saved[0], self._saved[1], DEFERRED_THRESHOLD2)

    def resume_automatic(self) -> None:
        """The run no longer steps (paused, held, ended): CPython's thresholds again."""
        with self._lock:
            if self._saved is not None:
                gc.set_threshold(*self._saved)
                self._saved = None

    def step(self, running: bool) -> None:
        """Mark a step as under way (True) or done (False), for the watch."""
        self.watch.step_running = running

    def after_step(self, slack_s: float) -> str | None:
        """Right after a step, ``slack_s`` wall seconds before the next wake-up: a due full
        collection if there is room for it, or if it is overdue; what was done (None: none)."""
        saved = self._saved
        if saved is None:
            return None
        pending = gc.get_count()[2]  # generation-1 collections since the last full one
        if pending < max(saved[2], 1):
            return None
        expected_s = self.watch.longest_full_s or FIRST_FULL_GUESS_S
        if slack_s >= SLACK_FACTOR * expected_s:
            gc.collect(2)
            self.between_steps += 1
            return "between steps"
        if pending >= MAX_DEFERRED:
            gc.collect(2)
            self.forced += 1
            return "forced"
        return None
