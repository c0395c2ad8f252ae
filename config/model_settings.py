"""The sections of the model and the control loop: ``[model]``, ``[observer]``,
``[compensation]``, ``[scheduler]``."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, StrictBool

from config.section import (
    MAX_DURATION_S,
    MAX_HEAT_W,
    MAX_TIMEOUT_S,
    NonNegativeFloat,
    PositiveFloat,
    Section,
)


class ModelSettings(Section):
    """The controller's thermal model (thesis 5.4)."""

    network: str = Field(
        "thesis-two-link",
        description="Preset name in config/networks, an identified network saved in "
        "storage.data_dir/networks (identify --save NAME), or a TOML file path.",
    )
    stepper: Literal["exact", "explicit", "implicit"] = Field(
        "exact", description="exact: zero-order hold (any dt); explicit: Eq. 5.1; implicit: sparse."
    )
    ambient_c: Annotated[float, Field(ge=-60, le=150)] = Field(
        22.0,
        description="Ambient temperature the controller's model assumes (degC); an arm run "
        "with a room thermometer (room.driver) follows its readings instead. The two-link "
        "bench's real room is bench.ambient_c (none: this), the arm bench's its truth file's.",
    )
    heat_w: dict[str, Annotated[float, Field(ge=0, le=MAX_HEAT_W)]] = Field(
        default_factory=dict,
        description="Heat input per node NAME (W) for a network that carries no heat of its "
        "own; a key naming no node of the run's network refuses the run. Precedence: the "
        "run's heat_w (--heat) > the network file's heat > this > heater_power_w.",
    )
    heater_power_w: Annotated[float, Field(ge=0, le=MAX_HEAT_W)] = Field(
        0.5,
        description="The controller's belief of each heater pad's power (W): the heat of "
        "every heater node of a network with no heat of its own when heat_w is empty.",
    )
    reference_nodes: tuple[str, str] | None = Field(
        None, description="Deformation between these nodes; none: the network's default."
    )
    direction: tuple[float, float, float] = Field(
        (1.0, 0.0, 0.0),
        description="Unit vector of the link's axis in world coordinates, as the controller "
        "believes it (the sim truth's: bench.direction).",
    )
    prediction: Literal["model", "model+ir"] = Field(
        "model",
        description="model: open loop (the thesis); model+ir: a Kalman filter corrects the "
        "model each step from the IR regions tied to its nodes (issue 9).",
    )


class ObserverSettings(Section):
    """The IR observer of prediction model+ir (daemon.model.observer) and its online
    adaptation (issue 19, daemon.model.adaptation)."""

    adapt: StrictBool = Field(
        False,
        description="model+ir: also estimate the adapt_parameters scale factors online with the "
        "temperatures (augmented-state EKF), so a wrong model converges without a calibration "
        "run; an identified network's values and errors are the priors.",
    )
    adapt_parameters: tuple[str, ...] = Field(
        ("heat", "convection", "alpha"),
        description="What adaptation estimates: heat (every heat input x one factor), "
        "heat:NODE (that node's), convection (every node's conductance to ambient), from the IR "
        "regions; alpha (the predicted deformation x one factor), from the measured spot drift "
        "alone.",
    )
    stand_drift_tau_s: PositiveFloat | None = Field(
        600.0,
        description="alpha: the measured drift also carries the camera stand's warm-up, "
        "A (1 - exp(-t / tau)) of unknown A, estimated beside alpha and never compensated "
        "(thesis 4.8: the camera warmed up within ~25 min); none: no stand drift state.",
    )
    deformation_noise_um: Annotated[float, Field(gt=0, le=1000)] = Field(
        1.0,
        description="1-sigma of one measured residual (um, scaled) as adaptation of alpha "
        "weighs it: the robot's repeatability and the centroid (thesis Table 6.1: S_x 0.92).",
    )
    prior_sigma: Annotated[float, Field(gt=0, le=3)] = Field(
        0.5,
        description="1-sigma of the log of an adapted factor that no identification gave "
        "(0.5: a factor 1.65 either way).",
    )
    random_walk_per_hour: Annotated[float, Field(ge=0, le=1)] = Field(
        0.05,
        description="How far an adapted factor's log may wander per hour (1-sigma): the "
        "factors of a coarse model are effective values, nearly constant.",
    )


class CompensationSettings(Section):
    """How a predicted deformation becomes a robot move (thesis 6.3, 6.4.4)."""

    mode: Literal["off", "absolute", "incremental"] = Field(
        "absolute", description="absolute: goal + offset (6.4.4); incremental: thesis comparison."
    )
    deformation_scale: PositiveFloat = Field(
        1.0, description="Scale factor on the deformation (thesis 6.3); checked against the chip."
    )
    time_scale: PositiveFloat = Field(1.0, description="Time scale of the procedure (thesis 6.3).")
    max_step_change_mm: PositiveFloat = Field(
        0.5, description="Largest change of the offset between two steps (mm)."
    )
    max_total_offset_mm: PositiveFloat = Field(
        5.0, description="Largest offset from the operational goal (mm)."
    )
    latency_s: NonNegativeFloat = Field(
        0.0, description="Predict this far ahead: when the move is expected to execute (s)."
    )
    spot_size_um: NonNegativeFloat = Field(
        200.0,
        description="Laser spot size on the chip (um), for the admissible-scale check (6.3).",
    )
    target_um: Annotated[float, Field(gt=0, le=10000)] = Field(
        5.0,
        description="The error the compensation must stay within (um): what `thermocomp "
        "budget` checks the measurement can resolve (thesis 4.11 trusted its improved "
        "measurement to +-5 um).",
    )


class SchedulerSettings(Section):
    """The fixed-step control loop (thesis chapter 6)."""

    procedure: Literal["stationary", "moving", "repeatability"] = Field(
        "stationary", description="What the robot does during the run (thesis 3.2.4, 2.2.2)."
    )
    step_s: Annotated[float, Field(ge=0.01, le=600)] = Field(
        1.0, description="Step period (s), 10 ms to 10 min."
    )
    duration_s: Annotated[float, Field(gt=0, le=MAX_DURATION_S)] = Field(
        3600.0, description="Run length (s of run clock)."
    )
    warmup_wait_s: Annotated[float, Field(ge=0, le=MAX_TIMEOUT_S)] = Field(
        0.0, description="Camera warm-up wait before the first step (s)."
    )
    precise_wake_ms: Annotated[float, Field(ge=0, le=10)] = Field(
        1.5,
        description="Wall clocks: wake this long before a deadline and yield until it "
        "(asyncio sleeps end up to 1 ms late); 0 = plain sleep.",
    )
    control_thread: Literal["auto", "on", "off"] = Field(
        "auto",
        description="Run the devices and the run's steps on a thread with its own event loop, "
        "apart from the API (auto: with a wall clock, real or accelerated; a virtual clock's "
        "sleepers share one loop).",
    )
    realtime_priority: Annotated[int, Field(ge=0, le=99)] = Field(
        10,
        description="SCHED_FIFO priority asked for the control thread (0 = do not ask); "
        "not permitted: niceness -10 is tried, then normal scheduling, with one log line.",
    )
    gc_between_steps: bool = Field(
        True,
        description="While a run steps, defer the garbage collector's full collections and do "
        "them between steps when one is due and the time to the next deadline allows (a due "
        "one waits at most ten times CPython's usual interval); false = CPython's own "
        "thresholds throughout.",
    )
    lock_memory: bool = Field(
        True,
        description="Lock the daemon's memory in RAM (mlockall, current and future pages) so "
        "a step never waits for a page to come back from swap; not permitted (no "
        "CAP_IPC_LOCK nor LimitMEMLOCK=infinity): one log line, the daemon runs unlocked.",
    )
    stop_grace_s: Annotated[float, Field(gt=0, le=60)] = Field(
        5.0,
        description="On stop, wait this long for the step in progress, then abandon it (s).",
    )
    sensor_error_policy: Literal["continue", "pause"] = Field(
        "continue",
        description="On a sensor error (flags camera-error, ir-error, centroid-error, and "
        "stale-frame/stale-ir: a late measurement is a missing one): flag the step and go on, "
        "or pause the run with the reason (the step's compensating move was already made).",
    )
