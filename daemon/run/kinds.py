"""The one factory of run kinds (issue 27): the only code that chooses what kind a run is, and
the only one that knows every kind (KINDS).

- a robot that plays its own program (drivers/base.py OffsetRobot, ``robot.driver =
  "ur-rtde"``): a followed run (daemon/run/followed/), whose duty cycle is the program's;
- parameters that set a kind's own parameters (KindBase.own_parameters: the arm's duty
  cycle): that kind's run (daemon/run/arm/);
- otherwise the two-link bench's run (daemon/run/two_link/).

A recorded run's kind is read the same way from its parameters: a run's reference must be of
its own kind (:func:`check_reference_run`, which asks the kinds what else they require).

Each kind builds itself (its package's ``build.py``) and carries its summary (daemon/run/
kind.py KindBase ``summary_from_basis``): a summary a shutdown deferred is found here by the
basis's kind name. Adding a kind: its package under daemon/run/, its class in KINDS and one
branch in :func:`build_kind` (docs/explanation/architecture.md "Run kinds"). Nothing here
changes a run's state or starts it.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from typing import Any

from daemon.run.arm.build import build_arm
from daemon.run.arm.kind import ArmKind
from daemon.run.followed.build import build_followed
from daemon.run.followed.kind import FollowedKind
from daemon.run.kind import KindBase, KindView, RunKind
from daemon.run.setup import RunParameterError, check_comparable, reference_row
from daemon.run.start import RunBuilder
from daemon.run.states import RunParameters
from daemon.run.summary import SummaryBasis, SummaryRow, fixed_summary
from daemon.run.two_link.build import build_two_link
from daemon.run.two_link.kind import TwoLinkKind
from daemon.storage.recorder import Recorder
from drivers.base import OffsetRobot, Robot

#: Every run kind, by the name its runs' summary bases carry.
KINDS: tuple[type[KindBase], ...] = (TwoLinkKind, ArmKind, FollowedKind)
_BY_NAME: dict[str, type[KindBase]] = {kind.name: kind for kind in KINDS}


def chosen_kind(robot: Robot, parameters: RunParameters) -> type[KindBase]:
    """The kind a run of ``parameters`` on ``robot`` is: what :func:`build_kind` builds, and
    what the dashboard's start form asks for (``GET /kinds`` ``default``)."""
    if isinstance(robot, OffsetRobot):  # plays its own program: even with a duty cycle
        return FollowedKind
    return kind_of_parameters(parameters.model_dump())


async def build_kind(builder: RunBuilder, parameters: RunParameters) -> RunKind:
    """The run's kind, built (its row created in the run database); RunParameterError when the
    run is not admissible."""
    robot = builder.devices().robot
    kind = chosen_kind(robot, parameters)
    if kind is FollowedKind and isinstance(robot, OffsetRobot):  # the check narrows the type
        return await build_followed(builder, parameters, robot)
    if kind is ArmKind:
        return await build_arm(builder, parameters, check_reference_run)
    return await build_two_link(builder, parameters, check_reference_run)


def kind_of_parameters(parameters: Mapping[str, Any]) -> type[KindBase]:
    """The kind a run's parameters choose (a started run's, or a recorded run's): the first
    kind whose own parameters they all set (KindBase.own_parameters), else the two-link
    bench's. A robot that plays its own program is the robot's choice, not the parameters'
    (:func:`build_kind`): its runs are recorded with an arm or a two-link run's parameters."""
    for kind in KINDS:
        own = kind.own_parameters
        if own and all(parameters.get(name) is not None for name in own):
            return kind
    return TwoLinkKind


def check_reference_run(recorder: Recorder, parameters: RunParameters) -> None:
    """The run named by ``reference_run`` must be an ended, uncompensated run of the same kind
    at the same deformation scale (and what the kind asks besides: KindBase.reference_refusal):
    its measured drift is what the summary's reduction compares with (issue 19). Blocking (the
    database): the kind's build calls it on the database worker."""
    reference_id = parameters.reference_run
    if reference_id is None:
        return
    row = reference_row(recorder, reference_id)
    ours, theirs = kind_of_parameters(parameters.model_dump()), kind_of_parameters(row.parameters)
    if theirs is not ours:
        # an arm run's summary compares tool drifts, a two-link run's the spot's: a reference
        # of the other kind has none of the figures (issue 28: it gave a null reduction)
        raise RunParameterError(
            f"reference_run {reference_id} is {theirs.title}, this run is {ours.title}: a "
            f"reference must be {ours.title} too ({ours.reference_hint(parameters)})"
        )
    refusal = ours.reference_refusal(parameters, row.parameters)
    if refusal is not None:
        raise RunParameterError(f"reference_run {reference_id} {refusal}")
    check_comparable(reference_id, row.parameters, parameters)


def kind_views() -> tuple[KindView, ...]:
    """How the dashboard shows each kind (daemon/run/kind.py KindView), in KINDS's order."""
    return tuple(kind.view for kind in KINDS)


def summary_from_basis(
    recorder: Recorder, basis: SummaryBasis, abandon: threading.Event | None = None
) -> dict[str, Any]:
    """A run's summary from its basis and the database, computed by the kind the basis names
    (at the next start for a summary a shutdown deferred: the same values, so the summary the
    end would have written). A basis of a kind this daemon does not know (a later version's)
    gives what it holds: its figures known without the steps."""
    kind = _BY_NAME.get(str(basis.get("kind", "")))
    compute = fixed_summary if kind is None else kind.summary_from_basis
    return compute(recorder, basis, abandon)


def summary_rows(summary: dict[str, Any]) -> list[SummaryRow]:
    """A run's summary as ``thermocomp run`` prints it, by the kind the summary names; of a kind
    this daemon does not know (a later version's), what every run has."""
    kind = _BY_NAME.get(str(summary.get("kind", "")))
    if kind is None:
        return [("overruns", summary.get("overruns"), "")]
    return kind.summary_rows(summary)
