"""Runs: their parameters, their state machine, and the procedures they follow.

State machine (issue 6, issue 15)::

    idle -> starting -> running <-> paused -> stopping -> finished | stopped | aborted
                           \\-> fault -> (explicit resume) -> running

A start that is paused or faults while it prepares (teaching, references) goes back to
``starting`` on its resume: the state says the truth while the start's motion is redone
(issue 26: a pause while preparing holds the robot and parks the start; docs/explanation/hold.md).

Final states say what happened: ``finished`` (ran to its end), ``stopped`` (by request: the
reason says who asked and why), ``aborted`` (an error), ``fault`` (a device fault the run was
parked in when it ended), ``interrupted`` (only ever written by the recorder at start-up, for
a run a crash left live). Only :class:`daemon.run.session.RunSession` changes a run's state.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from config import Settings
from drivers.base import Vector3

#: Upper bounds of the run parameters (issue 15: every parameter has a finite, documented range,
#: so nothing a request sends can reach the run clock as an infinity or a NaN). A week of run
#: and a day of camera warm-up are far beyond any warm-up study (the thesis ran 4,800 s, 6.5).
MAX_DURATION_S = 7 * 24 * 3600.0
MAX_WARMUP_WAIT_S = 24 * 3600.0
#: Procedure periods (moving arc, capture interval): an hour at most.
MAX_PROCEDURE_PERIOD_S = 3600.0
#: Deformation and time scales (thesis 6.3 used x28 for the deformation).
MAX_SCALE = 1000.0
MAX_HEAT_W = 1000.0  # per node (the bench's pads are 0.5 W)
MAX_HEAT_INPUTS = 256
MAX_OFFSET_MM = 1000.0  # procedure offsets from the goal (arc radius, repeatability poses)
MAX_POSES = 100

Duration = Annotated[float, Field(gt=0, le=MAX_DURATION_S, allow_inf_nan=False)]
ProcedurePeriod = Annotated[float, Field(gt=0, le=MAX_PROCEDURE_PERIOD_S, allow_inf_nan=False)]
Scale = Annotated[float, Field(gt=0, le=MAX_SCALE, allow_inf_nan=False)]
HeatW = Annotated[float, Field(ge=0, le=MAX_HEAT_W, allow_inf_nan=False)]
OffsetMm = Annotated[float, Field(ge=-MAX_OFFSET_MM, le=MAX_OFFSET_MM, allow_inf_nan=False)]


class RunState(enum.Enum):
    IDLE = "idle"
    STARTING = "starting"
    RUNNING = "running"
    PAUSED = "paused"
    STOPPING = "stopping"
    FINISHED = "finished"
    STOPPED = "stopped"
    ABORTED = "aborted"
    FAULT = "fault"
    INTERRUPTED = "interrupted"

    @property
    def is_terminal(self) -> bool:
        return self in _TERMINAL

    @property
    def is_active(self) -> bool:
        """A run in this state holds the daemon: no other run may start."""
        return self not in _TERMINAL and self is not RunState.IDLE


_TERMINAL = frozenset({RunState.FINISHED, RunState.STOPPED, RunState.ABORTED, RunState.INTERRUPTED})

#: Allowed transitions. ``fault`` is where a device fault parks the run until an explicit
#: resume (or stop); a run still in ``fault`` when the daemon shuts down ends there.
TRANSITIONS: dict[RunState, frozenset[RunState]] = {
    RunState.IDLE: frozenset({RunState.STARTING}),
    RunState.STARTING: frozenset(
        {RunState.RUNNING, RunState.PAUSED, RunState.STOPPING, RunState.ABORTED, RunState.FAULT}
    ),
    RunState.RUNNING: frozenset({RunState.PAUSED, RunState.STOPPING, RunState.FAULT}),
    RunState.PAUSED: frozenset(
        {RunState.RUNNING, RunState.STARTING, RunState.STOPPING, RunState.FAULT}
    ),
    RunState.FAULT: frozenset({RunState.RUNNING, RunState.STARTING, RunState.STOPPING}),
    RunState.STOPPING: frozenset(
        {RunState.FINISHED, RunState.STOPPED, RunState.ABORTED, RunState.FAULT}
    ),
    RunState.FINISHED: frozenset(),
    RunState.STOPPED: frozenset(),
    RunState.ABORTED: frozenset(),
    RunState.INTERRUPTED: frozenset(),
}


#: What each state means, as the API, the CLI and the documentation say it.
RUN_STATE_MEANINGS: dict[RunState, str] = {
    RunState.IDLE: "no run yet: the daemon waits for a start",
    RunState.STARTING: "the run is being prepared: devices checked, goal taught, reference "
    "frame taken; a hold now cancels the start",
    RunState.RUNNING: "steps are taken on their deadlines",
    RunState.PAUSED: "no steps are taken; the robot stays where it is until a resume or stop",
    RunState.STOPPING: "the run is ending: the robot is held, the step in progress finishes "
    "or is abandoned after scheduler.stop_grace_s, the end is committed",
    RunState.FAULT: "a device fault parked the run: an explicit resume continues it, a stop "
    "ends it (aborted); a run still in fault when the daemon shuts down ends there",
    RunState.FINISHED: "it ran to its end",
    RunState.STOPPED: "someone stopped it (a stop request, a signal, the daemon shutting "
    "down, a hold while starting): the reason says which",
    RunState.ABORTED: "an error ended it: the recording failed, an unexpected error (its "
    "traceback is in the log), or a stop while parked in fault",
    RunState.INTERRUPTED: "the process died under it; marked at the next start, its steps kept",
}


class RunStateError(Exception):
    """A request that the run's current state does not allow (e.g. resume while running)."""


class StateMachine:
    """The current state and the reason of the last change; refuses illegal transitions."""

    def __init__(self) -> None:
        self.state = RunState.IDLE
        self.reason: str | None = None

    def can(self, target: RunState) -> bool:
        return target in TRANSITIONS[self.state]

    def go(self, target: RunState, reason: str | None = None) -> None:
        if not self.can(target):
            raise RunStateError(f"cannot go from {self.state.value} to {target.value}")
        self.state = target
        self.reason = reason


Procedure = Literal["stationary", "moving", "repeatability"]
CompensationMode = Literal["off", "absolute", "incremental"]
#: model: the thesis's open loop; model+ir: a Kalman filter fuses the IR regions into the
#: model's node temperatures every step (issue 9), so the prediction follows the real link.
PredictionMode = Literal["model", "model+ir"]


#: The largest run number: SQLite's INTEGER PRIMARY KEY is a signed 64-bit integer; a larger
#: number given as a reference run overflowed in the database driver (a 500, issue 26).
MAX_RUN_ID = 2**63 - 1


class RunParameters(BaseModel):
    """What a run is started with (issue 6 "Runs and procedures"). Defaults come from the
    settings (:meth:`from_settings`); the API validates requests against this model."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    procedure: Procedure = "stationary"
    compensation: CompensationMode = "absolute"
    duration_s: Duration = Field(3600.0, description="Run length (s), at most a week.")
    step_s: Annotated[float, Field(ge=0.01, le=600, allow_inf_nan=False)] = 1.0
    deformation_scale: Scale = 1.0
    time_scale: Scale = Field(
        1.0, description="Model seconds per run-clock second (thesis 6.3: time may be scaled)."
    )
    network: Annotated[str, Field(min_length=1, max_length=4096)] = "thesis-two-link"
    prediction: PredictionMode = Field(
        "model",
        description="model: open loop (the thesis); model+ir: corrected each step from the "
        "IR regions tied to model nodes (Kalman filter).",
    )
    warmup_wait_s: Annotated[float, Field(ge=0, le=MAX_WARMUP_WAIT_S, allow_inf_nan=False)] = Field(
        0.0, description="Camera warm-up wait before the first step (s), at most a day."
    )
    heat_w: Annotated[dict[str, HeatW], Field(max_length=MAX_HEAT_INPUTS)] | None = Field(
        None,
        description="Heater power per model node NAME while the heaters are on (W, 0 to 1000), "
        "overriding the network's own heat; none: the network's heat, else model.heat_w, else "
        "model.heater_power_w on each heater node. A recorded run holds the heat it used.",
    )
    heater_off_s: Annotated[float, Field(ge=0, le=MAX_DURATION_S, allow_inf_nan=False)] | None = (
        Field(None, description="Run time at which the heaters switch off; none: stay on.")
    )
    reference_run: Annotated[int, Field(ge=1, le=MAX_RUN_ID)] | None = Field(
        None,
        description="An uncompensated (compensation off) run of the same bench and scale whose "
        "measured drift the summary's reduction is computed against; none: the reduction is "
        "only stated against the model's prediction.",
    )
    duty_cycle: Annotated[str, Field(min_length=1, max_length=4096)] | None = Field(
        None,
        description="An arm run (issue 20, needs arm.enabled): the duty cycle file it follows; "
        "its measured poses are corrected in 6-DOF (compensation off or absolute).",
    )
    arm_model: Annotated[str, Field(min_length=1, max_length=64)] | None = Field(
        None,
        description="An arm run: the identified arm model saved in the data directory by "
        "`thermocomp identify RUN --save NAME`, by name; none: the preset arm's model.",
    )
    # moving procedure (thesis 3.2.4): a wiper arc about the goal, back home to capture
    arc_amplitude_deg: Annotated[float, Field(ge=0, le=90, allow_inf_nan=False)] = 15.0
    arc_radius_mm: Annotated[float, Field(ge=0, le=MAX_OFFSET_MM, allow_inf_nan=False)] = 10.0
    arc_period_s: ProcedurePeriod = 60.0
    capture_every_s: ProcedurePeriod = 30.0
    # repeatability procedure (thesis 2.2.2): offsets from the goal of the taught poses (mm)
    poses_mm: Annotated[
        tuple[tuple[OffsetMm, OffsetMm, OffsetMm], ...], Field(max_length=MAX_POSES)
    ] = ((0.0, 0.0, 0.0), (0.2, 0.2, 0.0))

    @model_validator(mode="after")
    def _consistent(self) -> RunParameters:
        if self.step_s > self.duration_s:
            raise ValueError("step_s must not exceed duration_s")
        # an arm run's IR reads the arm on the run clock times time_scale, as its model runs
        if self.prediction == "model+ir" and self.time_scale != 1.0 and self.duty_cycle is None:
            raise ValueError("prediction model+ir needs time_scale 1: the IR sees real time")
        if self.duty_cycle is not None and self.compensation == "incremental":
            raise ValueError("an arm run corrects absolutely: compensation off or absolute")
        if self.arm_model is not None and self.duty_cycle is None:
            raise ValueError("arm_model is for an arm run: name a duty cycle")
        if self.duty_cycle is not None and self.procedure != "stationary":
            raise ValueError("an arm run follows its duty cycle: procedure must be stationary")
        if self.procedure == "repeatability" and len(self.poses_mm) < 2:
            raise ValueError("the repeatability procedure needs at least two poses")
        return self

    @classmethod
    def from_settings(cls, settings: Settings, **overrides: Any) -> RunParameters:
        """Parameters from the configuration, with ``overrides`` (None values ignored)."""
        values: dict[str, Any] = {
            "procedure": settings.scheduler.procedure,
            "compensation": settings.compensation.mode,
            "duration_s": settings.scheduler.duration_s,
            "step_s": settings.scheduler.step_s,
            "deformation_scale": settings.compensation.deformation_scale,
            "time_scale": settings.compensation.time_scale,
            "network": settings.model.network,
            "prediction": settings.model.prediction,
            "warmup_wait_s": settings.scheduler.warmup_wait_s,
            "heater_off_s": settings.bench.heater_off_s,
            "duty_cycle": settings.arm.duty_cycle if settings.arm.enabled else None,
        }
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls.model_validate(values)

    @property
    def step_count(self) -> int:
        """Steps in a run that misses no deadline: at 0, step, 2 step ... < duration."""
        return math.ceil(self.duration_s / self.step_s - 1e-9)


@dataclass(frozen=True, slots=True)
class ProcedurePoint:
    """What the procedure asks for at one step."""

    pose_offset_mm: Vector3  # offset of the operational pose from the taught goal
    capture: bool  # take a frame and measure at this step
    pose_index: int  # which taught pose (repeatability), 0 otherwise


def procedure_point(parameters: RunParameters, step: int, run_time_s: float) -> ProcedurePoint:
    """The procedure's pose and whether to capture, at a step.

    stationary: stay at the goal, capture every step (thesis 6.2). moving: a wiper arc of
    ``arc_amplitude_deg`` about the goal on a circle of ``arc_radius_mm`` (thesis 3.2.4),
    home for a capture every ``capture_every_s``. repeatability: cycle through the taught
    poses and capture at each (thesis 2.2.2).
    """
    if parameters.procedure == "repeatability":
        index = step % len(parameters.poses_mm)
        return ProcedurePoint(parameters.poses_mm[index], True, index)
    if parameters.procedure == "moving":
        half_step = parameters.step_s / 2
        phase = math.fmod(run_time_s + half_step, parameters.capture_every_s)
        if phase < parameters.step_s:  # the step nearest each capture instant
            return ProcedurePoint((0.0, 0.0, 0.0), True, 0)
        angle = math.radians(parameters.arc_amplitude_deg) * math.sin(
            2 * math.pi * run_time_s / parameters.arc_period_s
        )
        radius = parameters.arc_radius_mm
        return ProcedurePoint(
            (radius * math.sin(angle), radius * (1 - math.cos(angle)), 0.0), False, 0
        )
    return ProcedurePoint((0.0, 0.0, 0.0), True, 0)


def heat_at(parameters: RunParameters, run_time_s: float) -> dict[str, float]:
    """The heater inputs of the procedure at ``run_time_s`` (heaters on, then off)."""
    heat = parameters.heat_w or {}  # resolved at the run's start (daemon.run.setup)
    if parameters.heater_off_s is not None and run_time_s >= parameters.heater_off_s:
        return dict.fromkeys(heat, 0.0)
    return dict(heat)
