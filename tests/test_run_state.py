"""Run parameters, the run state machine and the procedures (issue 6 "Runs and procedures")."""

import math

import pytest
from pydantic import ValidationError

from config import Settings
from daemon.run.states import (
    TRANSITIONS,
    RunParameters,
    RunState,
    RunStateError,
    StateMachine,
    heat_at,
    procedure_point,
)


def test_the_documented_path_is_allowed() -> None:
    machine = StateMachine()
    for state in ("starting", "running", "paused", "running", "fault", "running", "stopping"):
        machine.go(RunState(state))
    machine.go(RunState.FINISHED, "done")
    assert machine.state.is_terminal and machine.reason == "done"


@pytest.mark.parametrize(
    ("start", "target"),
    [
        (RunState.IDLE, RunState.RUNNING),
        (RunState.FINISHED, RunState.RUNNING),
        (RunState.PAUSED, RunState.FINISHED),
        (RunState.RUNNING, RunState.IDLE),
        (RunState.INTERRUPTED, RunState.RUNNING),
    ],
)
def test_illegal_transitions_are_refused(start: RunState, target: RunState) -> None:
    machine = StateMachine()
    machine.state = start
    with pytest.raises(RunStateError, match=f"from {start.value} to {target.value}"):
        machine.go(target)


def test_terminal_states_lead_nowhere_and_only_live_states_hold_the_daemon() -> None:
    for state, targets in TRANSITIONS.items():
        assert (not targets) == state.is_terminal
    live = {s for s in RunState if s.is_active}
    assert live == {
        RunState.STARTING,
        RunState.RUNNING,
        RunState.PAUSED,
        RunState.STOPPING,
        RunState.FAULT,
    }


def test_parameters_default_to_the_settings_and_take_overrides() -> None:
    settings = Settings.model_validate(
        {"scheduler": {"step_s": 2.0}, "compensation": {"mode": "incremental"}}
    )
    parameters = RunParameters.from_settings(settings, duration_s=60.0, procedure=None)
    assert (parameters.step_s, parameters.compensation, parameters.duration_s) == (
        2.0,
        "incremental",
        60.0,
    )
    assert parameters.procedure == "stationary" and parameters.step_count == 30


@pytest.mark.parametrize(
    "bad",
    [
        {"step_s": 0.005},
        {"step_s": 601.0},
        {"duration_s": 0.0},
        {"step_s": 10.0, "duration_s": 5.0},
        {"compensation": "relative"},
        {"procedure": "repeatability", "poses_mm": [[0.0, 0.0, 0.0]]},
        {"deformation_scale": -1.0},
        {"unknown": 1},
    ],
)
def test_bad_parameters_are_refused(bad: dict[str, object]) -> None:
    with pytest.raises(ValidationError):
        RunParameters.model_validate(bad)


def test_stationary_captures_every_step_at_the_goal() -> None:
    parameters = RunParameters()
    point = procedure_point(parameters, 7, 7.0)
    assert point.pose_offset_mm == (0.0, 0.0, 0.0) and point.capture


def test_moving_sweeps_an_arc_and_comes_home_to_capture() -> None:
    parameters = RunParameters(
        procedure="moving",
        step_s=1.0,
        arc_amplitude_deg=30.0,
        arc_radius_mm=10.0,
        arc_period_s=40.0,
        capture_every_s=20.0,
    )
    captures = [t for t in range(100) if procedure_point(parameters, t, float(t)).capture]
    assert captures == [0, 20, 40, 60, 80]
    peak = procedure_point(parameters, 10, 10.0)  # a quarter period: the full amplitude
    angle = math.radians(30.0)
    assert peak.pose_offset_mm[0] == pytest.approx(10.0 * math.sin(angle))
    assert peak.pose_offset_mm[1] == pytest.approx(10.0 * (1 - math.cos(angle)))
    # every pose lies on the arc's circle about the pivot (0, radius)
    for t in range(1, 20):
        x, y, _ = procedure_point(parameters, t, float(t)).pose_offset_mm
        assert math.hypot(x, y - 10.0) == pytest.approx(10.0)


def test_repeatability_cycles_through_the_taught_poses() -> None:
    poses = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    parameters = RunParameters(procedure="repeatability", poses_mm=poses)
    points = [procedure_point(parameters, k, float(k)) for k in range(6)]
    assert [p.pose_index for p in points] == [0, 1, 2, 0, 1, 2]
    assert [p.pose_offset_mm for p in points[:3]] == list(poses)
    assert all(p.capture for p in points)


def test_heaters_switch_off_at_the_scheduled_time() -> None:
    parameters = RunParameters(heat_w={"2": 0.5, "9": 0.5}, heater_off_s=100.0)
    assert heat_at(parameters, 99.9) == {"2": 0.5, "9": 0.5}
    assert heat_at(parameters, 100.0) == {"2": 0.0, "9": 0.0}
    # no heat given: none until the run's start resolves it (daemon.run.setup.resolve_heat)
    assert heat_at(RunParameters(), 1e6) == {}
