"""Full garbage collections kept out of a run's steps: done between steps, where there is slack.

The start-up heap is frozen (daemon/heap.py), so a full (generation-2) collection walks only
what the daemon allocated since; but CPython 3.11's collector still does it all at once, in
whichever thread's allocation crossed the threshold, holding the GIL: a full collection started
by the API's thread stops the control thread as surely as one started by the step itself.
While a run steps, automatic full collections are therefore deferred (the third threshold
raised, :data:`DEFERRED_THRESHOLD2`: the young generations are still collected as usual, they
take tens of microseconds), and the control loop collects generation 2 itself right after a
step when one is due (by CPython's own rule: enough generation-1 collections and the oldest
generation grown by a quarter) and the time left before the next deadline is at least
:data:`SLACK_FACTOR` times the longest full collection seen so far. Memory stays bounded: a
due one that waited :data:`MAX_DEFERRED` generation-1 collections for slack is done after the
next step whatever the slack (a step too tight for it at every turn pays for one, instead of
the memory growing). Outside the step loop
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
#: Generation-1 collections a due full collection may wait for slack; past them it is done
#: whatever the slack: ten times CPython's third threshold (10), the bound on what deferring
#: may keep in memory.
MAX_DEFERRED = 100
#: A full collection is due when the oldest generation has grown by this factor since the
#: last one (CPython's rule: long_lived_pending > long_lived_total / 4).
GROWTH_FOR_FULL = 1.25
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
        # the oldest generation's size after the last full collection, and that collection
        # (the watch's count of them) it was taken after
        self._baseline: int | None = None
        self._baseline_fulls = -1
        self._checked_at = 0  # the generation-1 count the rule was last checked at
        self._due_since: int | None = None  # ... and first found due at

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
        collection if there is room for it, or if it is overdue; what was done (None: none).

        Due is CPython's own rule (Modules/gcmodule.c ``collect_generations``): as many
        generation-1 collections as its third threshold since the last full one, *and* the
        oldest generation grown by a quarter since then (without the second condition a
        large heap would be walked ten times as often as CPython walks it: measured in the
        test process, full collections of 150 ms that starved the API's thread). The size
        is counted (``len(gc.get_objects(2))``, a list of the generation's objects: under a
        millisecond for a frozen daemon's, ~10 ms for a test process's million) once per
        third-threshold generation-1 collections at most (once per each, the test process's
        API thread was starved of the GIL)."""
        saved = self._saved
        if saved is None:
            return None
        pending = gc.get_count()[2]  # generation-1 collections since the last full one
        if self._baseline is None or self._baseline_fulls != self.watch.collections[2]:
            # never sized, or a full collection ran elsewhere since: its size from now
            self._rebase()
            return None
        if self._due_since is None:
            every = max(saved[2], 1)
            if pending < every or pending - self._checked_at < every:
                return None
            self._checked_at = pending
            if len(gc.get_objects(2)) <= self._baseline * GROWTH_FOR_FULL:
                return None
            self._due_since = pending
        expected_s = self.watch.longest_full_s or FIRST_FULL_GUESS_S
        if slack_s >= SLACK_FACTOR * expected_s:
            outcome = "between steps"
            self.between_steps += 1
        elif pending - self._due_since >= MAX_DEFERRED:
            outcome = "forced"
            self.forced += 1
        else:
            return None
        gc.collect(2)
        self._rebase()
        return outcome

    def _rebase(self) -> None:
        """The oldest generation's size now, as after its last full collection."""
        self._baseline = len(gc.get_objects(2))
        self._baseline_fulls = self.watch.collections[2]
        self._checked_at = 0
        self._due_since = None
