"""daemon/run/gc_policy.py: full collections deferred while a run steps and done between
steps when there is slack for them, or past the bound whatever the slack; every collection
watched, with whether a step was under way; CPython's thresholds back afterwards."""

from __future__ import annotations

import gc
from collections.abc import Iterator

import pytest

from daemon.run.gc_policy import (
    DEFERRED_THRESHOLD2,
    FIRST_FULL_GUESS_S,
    MAX_DEFERRED,
    SLACK_FACTOR,
    GcPolicy,
)


@pytest.fixture
def policy() -> Iterator[GcPolicy]:
    """A policy, with the collector's automatic runs off meanwhile: the only collections are
    the test's own (in the whole suite's process, other tests' leftovers allocate too and
    would start full collections of their own between the test's steps)."""
    thresholds, enabled = gc.get_threshold(), gc.isenabled()
    gc.disable()
    policy = GcPolicy(enabled=True)
    policy.install()
    try:
        yield policy
    finally:
        policy.remove()
        gc.set_threshold(*thresholds)
        if enabled:
            gc.enable()
    assert gc.get_threshold() == thresholds


def _young_collections(count: int) -> None:
    """``count`` generation-1 collections: each adds one to the full collection's count."""
    for _ in range(count):
        gc.collect(1)


def test_full_collections_are_deferred_while_stepping_and_restored_after(
    policy: GcPolicy,
) -> None:
    before = gc.get_threshold()
    policy.defer_full()
    policy.defer_full()  # twice: still the thresholds of before to go back to
    assert gc.get_threshold() == (before[0], before[1], DEFERRED_THRESHOLD2)
    policy.resume_automatic()
    assert gc.get_threshold() == before


def _grow_oldest_generation() -> list[list[int]]:
    """Objects enough to grow the oldest generation by more than a quarter, moved into it
    (a generation-1 collection promotes what survives it); keep the result alive."""
    keep = [[] for _ in range(len(gc.get_objects(2)) // 3 + 1_000)]
    gc.collect(1)
    return keep


def test_a_due_full_collection_waits_for_the_slack_for_it(policy: GcPolicy) -> None:
    """Due is CPython's rule: enough generation-1 collections and the oldest generation grown
    by a quarter since the last full one; then it waits for a step with room for it."""
    every = gc.get_threshold()[2]  # generation-1 collections per full one (CPython's: 10)
    policy.defer_full()
    gc.collect()  # from a known state
    fulls = policy.watch.collections[2]
    assert policy.after_step(slack_s=1.0) is None  # sized from here
    _young_collections(every + 1)
    assert policy.after_step(slack_s=1.0) is None  # enough of them, but nothing grew
    keep = _grow_oldest_generation()
    _young_collections(every)  # the size is looked at once per `every` of them
    assert policy.after_step(slack_s=0.0) is None  # due, but no room before the deadline
    assert policy.watch.collections[2] == fulls
    # room: the slack for the longest full collection seen, the test's own first one included
    # (a worker's heap after hundreds of tests took over 0.5 s at load 5: 1 s was no room)
    room_s = SLACK_FACTOR * (policy.watch.longest_full_s or FIRST_FULL_GUESS_S) + 0.001
    assert policy.after_step(slack_s=room_s) == "between steps"  # the next step has room
    assert policy.watch.collections[2] == fulls + 1 and policy.between_steps == 1
    assert gc.get_count()[2] == 0 and policy.watch.longest_full_s > 0
    del keep


def test_past_the_bound_it_is_done_whatever_the_slack(policy: GcPolicy) -> None:
    every = gc.get_threshold()[2]
    policy.defer_full()
    gc.collect()
    policy.after_step(slack_s=0.0)  # sized
    keep = _grow_oldest_generation()
    _young_collections(every)
    assert policy.after_step(slack_s=0.0) is None  # due from here, no room
    _young_collections(MAX_DEFERRED - 1)
    assert policy.after_step(slack_s=0.0) is None
    _young_collections(1)
    assert policy.after_step(slack_s=0.0) == "forced" and policy.forced == 1
    assert gc.get_count()[2] == 0
    del keep


def test_a_large_heap_that_does_not_grow_is_not_walked_again(policy: GcPolicy) -> None:
    """CPython skips a full collection while the oldest generation has grown by less than a
    quarter: so does the deferral (else, ten times as many walks of a large heap)."""
    policy.defer_full()
    gc.collect()
    policy.after_step(slack_s=1.0)
    for _ in range(5):
        _young_collections(MAX_DEFERRED)
        assert policy.after_step(slack_s=1.0) is None
    assert policy.between_steps == policy.forced == 0


def test_nothing_is_done_outside_the_step_loop_or_when_off() -> None:
    thresholds = gc.get_threshold()
    off = GcPolicy(enabled=False)
    off.defer_full()
    assert gc.get_threshold() == thresholds
    _young_collections(MAX_DEFERRED)
    assert off.after_step(slack_s=1.0) is None  # CPython's own thresholds decide
    on = GcPolicy(enabled=True)
    assert on.after_step(slack_s=1.0) is None  # not stepping: nothing deferred


def test_the_watch_counts_collections_during_a_step(policy: GcPolicy) -> None:
    watch = policy.watch
    young, in_step = watch.collections[0], watch.in_step[0]
    policy.step(running=True)
    gc.collect(0)
    policy.step(running=False)
    gc.collect(0)
    assert watch.collections[0] == young + 2 and watch.in_step[0] == in_step + 1
    assert len(watch.pauses_s[0]) >= 2 and all(p >= 0 for p in watch.pauses_s[0])
