"""The fixed-step timer: absolute deadlines, overruns skip ahead without a burst."""

import math

import pytest

from daemon.run.scheduler import FixedStepTimer, TimingStats
from drivers.clock import ScaledClock, VirtualClock


async def test_ticks_fall_on_absolute_deadlines() -> None:
    clock = VirtualClock(start_s=10.0)
    timer = FixedStepTimer(clock, period_s=0.5, start_s=10.0)
    ticks = []
    for _ in range(4):
        tick = await timer.wait()
        await clock.sleep_until(clock.now() + 0.2)  # work shorter than a period
        timer.step_done()
        ticks.append(tick)
    assert [t.scheduled_s for t in ticks] == [10.0, 10.5, 11.0, 11.5]
    assert [t.lateness_s for t in ticks] == [0.0] * 4
    assert (timer.overruns, timer.skipped) == (0, 0)


async def test_an_overrun_moves_to_the_next_deadline_without_catch_up() -> None:
    clock = VirtualClock()
    timer = FixedStepTimer(clock, period_s=1.0, start_s=0.0)
    await timer.wait()
    await clock.sleep_until(2.5)  # step 0 ran 2.5 periods: deadlines 1 and 2 are lost
    timer.step_done()
    assert (timer.overruns, timer.skipped) == (1, 2)
    tick = await timer.wait()
    assert (tick.step, tick.slot, tick.scheduled_s) == (1, 3, 3.0)
    timer.step_done()
    tick = await timer.wait()
    assert (tick.step, tick.slot) == (2, 4)
    assert timer.overruns == 1


async def test_a_step_ending_exactly_on_the_next_deadline_is_not_an_overrun() -> None:
    clock = VirtualClock()
    timer = FixedStepTimer(clock, period_s=1.0, start_s=0.0)
    await timer.wait()
    await clock.sleep_until(1.0)
    timer.step_done()
    assert timer.overruns == 0 and timer.next_deadline_s == 1.0


async def test_resync_after_a_pause_is_not_an_overrun() -> None:
    clock = VirtualClock()
    timer = FixedStepTimer(clock, period_s=2.0, start_s=0.0)
    await timer.wait()
    timer.step_done()
    await clock.sleep_until(9.0)  # paused for a while
    timer.resync()
    assert timer.next_deadline_s == 10.0 and timer.overruns == 0


@pytest.mark.parametrize("period", [0.001, 0.0099, 600.1, math.inf])
def test_period_outside_10_ms_to_10_min_is_refused(period: float) -> None:
    with pytest.raises(ValueError, match="10 ms to 10 min"):
        FixedStepTimer(VirtualClock(), period_s=period, start_s=0.0)


def test_timing_stats_percentiles() -> None:
    stats = TimingStats(window=1000)
    for k in range(101):
        stats.add(k * 1e-3, {"model": 2e-3, "move": k * 1e-4})
    summary = stats.summary()
    lateness = summary["lateness_s"]
    assert isinstance(lateness, dict)
    assert lateness["p50"] == pytest.approx(0.050)
    assert lateness["p99"] == pytest.approx(0.099)
    assert lateness["max"] == pytest.approx(0.100)
    stages = summary["stages_s"]
    assert isinstance(stages, dict)
    assert stages["model"]["max"] == pytest.approx(2e-3)
    assert "centroid" not in stages  # no sample, no figure


def test_precise_wake_is_in_wall_time_and_only_for_wall_clocks() -> None:
    virtual = FixedStepTimer(VirtualClock(), 1.0, 0.0, precise_wake_s=0.0015)
    assert virtual.next_wake_s == virtual.next_deadline_s  # a virtual clock jumps exactly
    accelerated = FixedStepTimer(ScaledClock(100.0), 1.0, 0.0, precise_wake_s=0.0015)
    assert accelerated.next_deadline_s - accelerated.next_wake_s == pytest.approx(0.15)


async def test_precise_wake_still_returns_the_deadline_tick() -> None:
    clock = ScaledClock(1000.0)  # 20 run-ms = 20 wall-us: quick, and a real wall clock
    timer = FixedStepTimer(clock, period_s=0.02, start_s=clock.now(), precise_wake_s=0.001)
    ticks = [await timer.wait() for _ in range(3)]
    assert [t.slot for t in ticks] == [0, 1, 2]
    assert all(t.actual_s >= t.scheduled_s for t in ticks)  # never early
