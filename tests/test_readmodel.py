"""The run's frozen view (daemon/run/readmodel.py): the progress the API and dashboard show."""

from __future__ import annotations

import pytest

from daemon.run.readmodel import RunView
from daemon.run.states import RunParameters, RunState


def view(state: RunState, end_s: float) -> RunView:
    parameters = RunParameters(duration_s=120.0, step_s=10.0)
    return RunView(
        id=1, state=state, reason=None, step=11, parameters=parameters, start_s=0.0, end_s=end_s
    )


def test_a_finished_run_is_complete_though_its_last_step_came_before_the_duration() -> None:
    # 12 steps of 10 s: the last is scheduled at 110 s and the run ends when it is recorded
    assert view(RunState.FINISHED, end_s=110.2).progress(clock_now=500.0) == (100.0, 0.0)


@pytest.mark.parametrize("state", [RunState.STOPPED, RunState.ABORTED, RunState.FAULT])
def test_a_run_ended_early_stays_where_it_ended(state: RunState) -> None:
    progress, remaining = view(state, end_s=60.0).progress(clock_now=500.0)
    assert progress == pytest.approx(50.0) and remaining == pytest.approx(60.0)


def test_a_running_run_counts_the_run_clock() -> None:
    progress, remaining = view(RunState.RUNNING, end_s=float("nan")).progress(clock_now=30.0)
    assert progress == pytest.approx(25.0) and remaining == pytest.approx(90.0)
