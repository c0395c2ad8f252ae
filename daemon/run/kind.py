"""One shape for every run kind (issue 27): what a run does to its devices and its data beside
the state machine of daemon/run/session.py.

A kind is built by the one factory that chooses it (daemon/run/kinds.py) and is all the session
knows of it: the session calls these at the points of its prepare -> loop -> finish and decides
what their errors do; no code outside the factory and the kind's own package asks which kind a
run is. Today's kinds: the two-link bench (daemon/run/two_link/), an arm run moved to its poses
or playing its duty cycle (daemon/run/arm/), and a robot that plays its own program while the
daemon follows and offsets it (daemon/run/followed/). Adding a kind touches the factory and the
kind's own files only (docs/explanation/architecture.md "Run kinds").

The hold rules are the session's and the driver's, not the kind's: every motion a kind makes
goes through the robot's driver, which refuses it after a hold (drivers/permit.py); a kind that
moves between steps (a played cycle) starts only with the grant the session gives it.
"""

from __future__ import annotations

import abc
import threading
from collections.abc import Mapping
from typing import Any, ClassVar, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field

from daemon.run.scheduler import Tick
from daemon.run.states import RunParameters
from daemon.run.step import MeasuringStep, StepOutcome
from daemon.run.summary import SummaryBasis, SummaryRow
from daemon.storage.recorder import Recorder
from drivers.clock import Clock
from drivers.permit import Ticket

#: The dashboard's plot slots (api/static/index.html ``slot-*``): which a kind shows is its view's.
PlotSlotName = Literal["residual", "drift3d", "rotation", "predicted", "offset", "temperature"]


class _Frozen(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class PlotSlot(_Frozen):
    """One plot a run of the kind draws, in the page's order."""

    slot: PlotSlotName
    title: str
    title_uncompensated: str | None = Field(
        None, description="The title instead when the run's compensation is off."
    )


class KindView(_Frozen):
    """How the dashboard shows a kind (the kind owns its view, so adding a kind never edits the
    page): everything the page used to decide by a kind's name, as data. Served by
    ``GET /api/v1/kinds`` (docs/reference/api.md); the page renders from it and names no kind
    (tests/test_kind_isolation.py).

    Texts named ``*_text`` are templates: ``{name}`` is the run's parameter ``name``; a
    template naming a parameter the run left unset gives nothing."""

    name: str = Field(description="The kind's name, as each run record's ``kind`` gives it.")
    form_title: str = Field(description="The start form's heading on a daemon of this kind.")
    form_fields: tuple[str, ...] = Field(
        description="The start form's fields (RunRequest names) only this kind asks for; the "
        "fields every kind has (compensation, duration, step, time scale, reference) are shown "
        "always."
    )
    plots: tuple[PlotSlot, ...] = Field(description="The plots a run of this kind draws.")
    series: Literal["axes", "poses"] = Field(
        description="``axes``: the spot's error, prediction and offset per axis (x, y, z); "
        "``poses``: the tool's 3-D drift, rotation, prediction and correction, one series per "
        "measured pose."
    )
    time_axis: Literal["run", "model-hours"] = Field(
        description="The plots' x: the run clock in s, or the model's time in h (a scaled run)."
    )
    x_label: str
    temperature_x_label: str
    group_temperatures: bool = Field(
        description="Temperatures averaged per link and joint (node names link.segment)."
    )
    rotation_measured: bool = Field(
        description="Whether a run measures the tool's rotation error; when not, the rotation "
        "plot says so rather than stay empty."
    )
    adaptation: bool = Field(description="Whether its steps carry the model's adapted factors.")
    reference_runs: bool = Field(
        description="Whether a run may name an uncompensated ended run as its reference; the "
        "runs offered are those of ``reference_kinds`` with compensation off."
    )
    reference_kinds: tuple[str, ...] = Field(
        description="The kinds whose runs may be its reference (daemon/run/kinds.py "
        "check_reference_run)."
    )
    what_text: str = Field(description="What a run did, in the runs table (e.g. its procedure).")
    model_text: str = Field(description="The model it used, after ``what_text``.")
    doing_text: str = Field(description="What the robot does, in the headline.")
    reference_text: str = Field(description="A reference run, in the form's list.")
    scaled_time_text: str | None = Field(
        description="After a run's duration when its time scale is not 1: the model time it "
        "covered, e.g. 'of arm' ('2 h of arm')."
    )


class RunKind(Protocol):
    """A run's kind. ``run_id``, ``parameters`` and ``start_s`` (run clock at step 0, set by
    the session when its steps begin) are the kind's work's."""

    @property
    def name(self) -> str:
        """The kind's name, as the run's info and the dashboard show it."""
        ...

    @property
    def run_id(self) -> int: ...

    @property
    def parameters(self) -> RunParameters: ...

    @property
    def clock(self) -> Clock:
        """The run's clock (a played duty cycle paces a virtual clock its steps follow)."""
        ...

    start_s: float  # run clock at step 0, set by the session when its steps begin

    async def teach(self, *, moving: bool) -> None:
        """Teach the run's goals: what moves nothing (``moving=False``, before the start's
        release), then what moves (after it). Raises DeviceError."""
        ...

    async def start_bench(self) -> None:
        """The simulated bench, when there is one, starts cold with this run."""
        ...

    async def references(self) -> None:
        """The zero of every drift, measured before the first correction. Raises DeviceError
        when the robot cannot go on (the session faults, and does it again after a resume)."""
        ...

    async def step(self, tick: Tick) -> StepOutcome | MeasuringStep:
        """One step: model -> check -> move -> measure -> record (committed) -> verdict; or,
        once its frame is taken, the step still measuring (daemon/run/step.py MeasuringStep:
        its record is committed after the previous step's and before the next one's)."""
        ...

    async def resumed(self) -> None:
        """The robot was released for this run again: read back what the kind carries over
        (the two-link bench's incremental mode: where the robot really is). Raises
        DeviceError (a GoalLostError: the run cannot continue)."""
        ...

    def play(self, grant: Ticket) -> None:
        """Start what moves between the steps (a played duty cycle), on behalf of the request
        that holds ``grant``; nothing for a kind whose steps make every move."""
        ...

    async def stop_playing(self, grace_s: float, *, held: bool) -> None:
        """Stop it: the run pauses, faults or ends, within ``grace_s``. Called after the
        session's hold. ``held``: the run was held (a pause, a fault, a stop, an abort, a
        shutdown), not ended at its duration: a robot that plays its own program is paused
        then (daemon/run/followed/program_pause.py)."""
        ...

    def summary_basis(self, *, overruns: int, skipped: int, timing: dict[str, Any]) -> SummaryBasis:
        """What the run's summary needs beyond its steps (daemon/run/summary.py SummaryBasis):
        what only this daemon's memory holds, JSON-able, cheap (called on the event loop). A
        shutdown that gives the summary up keeps it in the database, and the next start
        computes the summary from it (docs/reference/run-states.md)."""
        ...

    def summary(
        self, recorder: Recorder, basis: SummaryBasis, *, abandon: threading.Event | None
    ) -> dict[str, Any]:
        """The run's summary (thesis Table 6.1 and its timing) from ``basis`` and the steps
        read back from the database on a worker thread; ``abandon`` gives the read up
        (daemon/storage/series.py). The same as the kind's ``summary_from_basis`` (KindBase),
        which computes a deferred one at the next start (daemon/run/kinds.py)."""
        ...


class KindWork(Protocol):
    """What every kind's work carries from one step to the next, whatever else it holds."""

    @property
    def run_id(self) -> int: ...

    @property
    def parameters(self) -> RunParameters: ...

    start_s: float


class KindBase(abc.ABC):
    """What every run kind shares: ``run_id``, ``parameters`` and ``start_s`` are its work's,
    and its summary is its class's: ``summary_from_basis`` computes it from a basis alone (the
    run's end, and a summary a shutdown deferred, found by the basis's ``kind``: the class's
    ``name``, in daemon/run/kinds.py). A subclass is a dataclass with a ``work`` field."""

    #: the kind's name: the run's info and the dashboard show it, a summary's basis carries it
    name: ClassVar[str]
    #: how a message names one of its runs ("an arm run")
    title: ClassVar[str]
    #: the run parameters that are this kind's own: a run that sets them all is this kind's
    #: (daemon/run/kinds.py kind_of_parameters). Nothing outside the factory and the kinds'
    #: packages tests them to tell the kinds apart (tests/test_kind_isolation.py).
    own_parameters: ClassVar[frozenset[str]] = frozenset()
    #: how the dashboard shows its runs and its start form (the kind's ``view.py``)
    view: ClassVar[KindView]
    work: KindWork

    @staticmethod
    def reference_hint(parameters: RunParameters) -> str:
        """What the reference of this kind's run with ``parameters`` must be, for a refusal."""
        return "an uncompensated run of the same kind"

    @staticmethod
    def reference_refusal(parameters: RunParameters, reference: Mapping[str, Any]) -> str | None:
        """Why a recorded run of this kind (its parameters: ``reference``) cannot be the
        reference of this kind's run with ``parameters``, beyond what every reference needs
        (daemon/run/kinds.py check_reference_run); None when it can."""
        return None

    @staticmethod
    @abc.abstractmethod
    def summary_from_basis(
        recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
    ) -> dict[str, Any]:
        """The kind's summary from ``basis`` (KindBase.summary_basis) and the recorded steps:
        blocking (a worker thread); ``abandon`` gives the read up at its next chunk."""

    @staticmethod
    @abc.abstractmethod
    def summary_rows(summary: dict[str, Any]) -> list[SummaryRow]:
        """The kind's summary as ``thermocomp run`` prints it (found by the summary's
        ``kind``, daemon/run/kinds.py summary_rows)."""

    @property
    def run_id(self) -> int:
        return self.work.run_id

    @property
    def parameters(self) -> RunParameters:
        return self.work.parameters

    @property
    def start_s(self) -> float:
        return self.work.start_s

    @start_s.setter
    def start_s(self, value: float) -> None:
        self.work.start_s = value

    def summary(
        self, recorder: Recorder, basis: SummaryBasis, *, abandon: threading.Event | None
    ) -> dict[str, Any]:
        return type(self).summary_from_basis(recorder, basis, abandon)
