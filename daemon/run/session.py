"""One run, from its start to its final state: the only code that changes a run's state.

prepare (teach, release the robot, warm-up, bench, references) -> loop (one step per
deadline) -> finish (hold, final state committed, summary). The same for every kind of run: what
a run does to its devices and data is its kind (daemon/run/kind.py, chosen only by
daemon/run/kinds.py). The robot may move only while no hold came after the request that last
allowed this run to (its grant: drivers/permit.py; docs/explanation/hold.md). Operator requests
(pause, resume, stop, a robot hold) and the steps' verdicts meet here, in :meth:`RunSession._go`,
against the state machine of daemon/run/states.py: a request is refused with RunStateError when the
state does not allow it; a verdict that arrives after a request (a step that ends in its own
pause while the operator paused or stopped during it) is already on the step's record (flag
and error) and changes nothing, so it never turns a run into ``aborted`` (issue 15, point 1).

Every state change happens synchronously (no await between check and change), is published at
once, and is persisted in order on the recorder's one thread (daemon/run/publish.py); the
run's frozen view (daemon/run/readmodel.py) is replaced at each change for the API to read. What
the daemon gives every run is daemon/run/services.py. The kind computes and does I/O; the state
changes only here.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
import threading
from collections.abc import Awaitable, Callable
from typing import Any

from daemon.run import ending
from daemon.run.gc_policy import GcPolicy
from daemon.run.grant import RunGrant
from daemon.run.kind import RunKind
from daemon.run.measuring import MEASURING_STEPS, StepsMeasuring
from daemon.run.publish import RunPublisher
from daemon.run.readmodel import RunView
from daemon.run.scheduler import FixedStepTimer, sleep_until_woken
from daemon.run.services import BenchControl, SessionServices
from daemon.run.states import RunState, RunStateError, StateMachine
from daemon.run.step import MeasuringStep, StepOutcome, Verdict
from daemon.run.summary import stored_basis
from daemon.storage.recorder import RecorderError
from drivers.errors import DeviceError, GoalLostError, MotionHeldError
from drivers.permit import MotionPermit, Ticket

__all__ = ["BenchControl", "ResumeRefusedError", "RunSession", "SessionServices"]

logger = logging.getLogger(__name__)


class ResumeRefusedError(RunStateError):
    """The run cannot continue (e.g. the controller lost the taught goal): a 409 with why."""


class RunSession:
    """``ticket``: the robot's permit (drivers/permit.py) as it was when the start request
    arrived: the start may release a hold that came before it, never one that came after."""

    def __init__(self, kind: RunKind, services: SessionServices, ticket: Ticket) -> None:
        self.kind = kind  # what this run does to its devices and data (daemon/run/kind.py)
        self.id = kind.run_id
        self._services = services
        self.machine = StateMachine()
        self.timer: FixedStepTimer | None = None
        self.step = -1
        self.last_record: dict[str, Any] | None = None
        self.summary: dict[str, Any] | None = None
        #: a shutdown gave the summary up and it is kept for the next start to compute
        self.summary_deferred = False
        self.ended_s = math.nan  # run clock at the end
        self.stop_requested = False
        self._stop_reason: str | None = None
        self._final_on_stop = RunState.STOPPED
        self.finishing = False  # holding the robot, writing the final state and the summary
        self._abandon_summary = threading.Event()  # a shutdown that cannot wait for it
        self._wake = asyncio.Event()
        #: the request that last allowed this run to move (its start, then each resume):
        #: motion goes on only while no hold came after it
        self._grant = RunGrant(self.id, services.robot, services.errors, ticket)
        self._prepared = False  # the start's teaching and references are done
        self._publisher = RunPublisher(self.id, services)
        self._measuring = StepsMeasuring(self._collect)  # overlapping later steps' moves
        #: the grant (start or resume request) each step still to be collected moved under
        self._step_grants: dict[int, Ticket] = {}
        self.task: asyncio.Task[None] | None = None

    @property
    def state(self) -> RunState:
        return self.machine.state

    @property
    def permit(self) -> MotionPermit:
        return self._grant.permit

    def start(self) -> None:
        self._go(RunState.STARTING, None)
        self.task = asyncio.get_running_loop().create_task(self._run(), name=f"run-{self.id}")

    # --- operator requests (the daemon serialises them) -----------------------------------

    def pause(self, reason: str) -> None:
        """Pause (the daemon has held the robot first). A start still preparing is parked:
        its teaching and references go on after the resume (docs/explanation/hold.md)."""
        if self.state not in (RunState.RUNNING, RunState.STARTING):
            raise RunStateError(f"run {self.id} is {self.state.value}, not running")
        self._go(RunState.PAUSED, reason)

    async def resume(self, ticket: Ticket) -> None:
        """Motion is allowed again only on this explicit request, made when ``ticket`` was
        taken; the actual pose is read back first. A hold or stop that came after the request
        wins; a controller that lost the taught goal refuses the resume (issue 15, point 9)
        instead of answering running and then faulting at the next step."""
        if self.state not in (RunState.PAUSED, RunState.FAULT):
            raise RunStateError(f"run {self.id} is {self.state.value}: nothing to resume")
        if not self.permit.is_current(ticket):
            raise RunStateError(f"run {self.id}: the robot was held after the resume was asked")
        robot = self._services.robot
        try:
            await robot.resume(ticket)  # a pause held it: released only if no hold came since
            await self.kind.resumed()
        except MotionHeldError as err:
            raise RunStateError(f"run {self.id}: a hold came during the resume") from err
        except GoalLostError as err:
            self._services.errors.note(err)
            await self._grant.hold()
            reason = (
                f"{err.message}: the run cannot continue (its offsets are from that goal); "
                "stop it and start a new run at the goal"
            )
            self._set_reason(reason)
            raise ResumeRefusedError(reason) from err
        except DeviceError as err:
            self._services.errors.note(err)
            if self.state is RunState.FAULT:
                self._set_reason(f"resume failed: {err}")
            elif self.state is RunState.PAUSED:
                self._go(RunState.FAULT, f"resume failed: {err}")
            raise
        if (
            self.stop_requested
            or self.state not in (RunState.PAUSED, RunState.FAULT)
            or not self.permit.is_current(ticket)
        ):
            await self._grant.hold()  # re-assert: the resume must not undo a later hold
            # and stop again what the resume started (a program the kind played again):
            # the loop stopped it for this pause already and will not again
            await self.kind.stop_playing(self._services.settings.scheduler.stop_grace_s, held=True)
            raise RunStateError(f"run {self.id}: a hold or stop came during the resume")
        self._grant.ticket = ticket
        self._go(RunState.RUNNING if self._prepared else RunState.STARTING, None)

    def request_stop(self, reason: str, final: RunState = RunState.STOPPED) -> None:
        """End the run at the next opportunity (the step in progress may finish)."""
        if self.stop_requested:
            return
        if self.state is RunState.FAULT:  # it could not go on: the fault ended it
            final = RunState.ABORTED
            reason = f"fault: {self.machine.reason}; {reason}"
        self.stop_requested = True  # before any await: the loop must see it first
        self._stop_reason = reason
        self._final_on_stop = final
        if self.state is not RunState.STOPPING:
            self._go(RunState.STOPPING, reason)
        self._wake.set()

    def robot_held(self, reason: str) -> None:
        """The robot has just been held by request: a running run pauses; a run still starting
        is cancelled (issue 15, point 2: a hold is never released by the start itself)."""
        if self.state is RunState.RUNNING:
            self._go(RunState.PAUSED, reason)
        elif self.state is RunState.STARTING:
            self.request_stop(f"start cancelled: {reason}")

    async def wait_ended(self, grace_s: float, summary_budget_s: float | None = None) -> None:
        """Wait for the run task; a step stuck on a device is abandoned after ``grace_s``.
        ``summary_budget_s`` (a shutdown): the summary of a long run is given up after that
        much more -- its end is recorded before the summary (see :meth:`_finish`) -- and
        deferred to the next start (daemon/run/pending_summaries.py)."""
        task = self.task
        if task is None:
            return
        _, pending = await asyncio.wait({task}, timeout=grace_s)
        if pending and not self.finishing:
            logger.warning("run %d: abandoning the step in progress to stop", self.id)
            task.cancel()
        if summary_budget_s is not None:
            _, pending = await asyncio.wait({task}, timeout=summary_budget_s)
            if pending:  # given up to shut down in time: deferred (logged in daemon/run/ending.py)
                self._abandon_summary.set()
        await asyncio.wait({task})

    # --- the run task ------------------------------------------------------------------------

    async def _run(self) -> None:
        final, reason = RunState.FINISHED, None
        try:
            if await self._prepare():
                await self._loop()
            if self.stop_requested:
                final, reason = self._final_on_stop, self._stop_reason
        except RecorderError as err:
            logger.error("run %d: recording failed: %s", self.id, err)
            self._services.errors.note(err, device="storage")
            final, reason = RunState.ABORTED, f"recording failed: {err}"
        except asyncio.CancelledError:
            if self.stop_requested:
                final = self._final_on_stop
                reason = f"{self._stop_reason}; the step in progress was abandoned"
            else:
                final, reason = RunState.ABORTED, "cancelled"
            raise
        except Exception as err:
            logger.exception("run %d failed", self.id)  # the traceback goes to the journal
            self._services.errors.note(err, device="daemon")
            final, reason = RunState.ABORTED, f"{type(err).__name__}: {err}"
        finally:
            self.finishing = True  # from here on the run is never cancelled: it is ending
            await self._finish(final, reason)

    async def _prepare(self) -> bool:
        """Teach the goal, release the robot for this start, teach the poses, wait for the
        camera, start the bench, take the references; False if stopped meanwhile.

        A pause or a fault while preparing holds the robot and parks the start; the phase it
        interrupted is done again after the resume, which comes back to ``starting``
        (docs/explanation/hold.md). Every move of a phase is refused by the driver after a hold
        (drivers/permit.py), so nothing of the start moves while it is parked."""
        services = self._services
        kind, parameters = self.kind, self.kind.parameters
        # 6.4.3: every offset is from the goal taught here. Taught first, while still held: a
        # resume checks the goal the controller holds, and after a controller restart the
        # previous run's goal is gone (docs/reference/c500c-console.md), which must not refuse a
        # new run.
        phases: list[tuple[str, Callable[[], Awaitable[None]]]] = [
            ("teach the operational goal", functools.partial(kind.teach, moving=False)),
            ("release the robot", self._release),
            ("teach the operational goal", functools.partial(kind.teach, moving=True)),
        ]
        for name, action in phases:
            if not await self._phase(name, action):
                return False
        if parameters.warmup_wait_s > 0:
            logger.info("run %d: camera warm-up wait %.0f s", self.id, parameters.warmup_wait_s)
            deadline_s = kind.clock.now() + parameters.warmup_wait_s
            while kind.clock.now() < deadline_s:
                if not await self._wait_while_held():
                    return False
                await sleep_until_woken(kind.clock, deadline_s, self._wake)
        if not await self._phase("start the bench", kind.start_bench):
            return False
        if not await self._phase("measure the references", kind.references):
            return False
        kind.start_s = kind.clock.now()
        self.timer = FixedStepTimer(
            kind.clock,
            parameters.step_s,
            kind.start_s,
            precise_wake_s=services.settings.scheduler.precise_wake_ms / 1000.0,
        )
        self._prepared = True
        if self.state is RunState.STARTING:
            self._go(RunState.RUNNING, None)
        return not self.stop_requested

    async def _phase(self, name: str, action: Callable[[], Awaitable[None]]) -> bool:
        """One phase of the start, done again after a pause or a fault that interrupts it;
        False when the run was stopped instead."""
        while True:
            if not await self._wait_while_held():
                return False
            try:
                await action()
            except MotionHeldError as err:
                if self.stop_requested:
                    return False
                if self.state not in (RunState.PAUSED, RunState.FAULT):
                    await self._fault(f"cannot {name}: {err}")
                continue  # done again after the resume
            except DeviceError as err:
                self._services.errors.note(err)
                await self._fault(f"cannot {name}: {err}")
                continue
            return not self.stop_requested

    async def _release(self) -> None:
        """Motion for this run (daemon/run/grant.py): a hold that came after the start request
        cancels the start."""
        try:
            await self._grant.release()
        except MotionHeldError:
            if self.state is RunState.STARTING and not self._grant.current:
                self.request_stop(
                    "start cancelled: the robot was held after the start was requested"
                )
            raise

    async def _loop(self) -> None:
        """The steps, with full garbage collections between them (daemon/run/gc_policy.py)
        while it steps; CPython's own thresholds while it is held and after it."""
        collector = self._services.gc_policy
        try:
            await self._steps(collector)
            await self._measuring.settle()  # the steps still measuring, before the run ends
        finally:
            collector.step(running=False)
            collector.resume_automatic()

    async def _steps(self, collector: GcPolicy) -> None:
        timer = self.timer
        assert timer is not None
        end_s = self.kind.start_s + self.kind.parameters.duration_s
        # run seconds per wall second (an accelerated bench clock); a virtual clock's as is
        factor = float(getattr(timer.clock, "factor", 1.0))
        collector.defer_full()
        while True:
            if self.stop_requested or self.state is RunState.STOPPING:
                return
            if self.state in (RunState.PAUSED, RunState.FAULT):
                await self._measuring.settle()  # the last step's record and verdict before the wait
                collector.resume_automatic()
                await self.kind.stop_playing(
                    self._services.settings.scheduler.stop_grace_s, held=True
                )
                if not await self._wait_while_held():
                    return
                timer.resync()
                collector.defer_full()
                continue
            if timer.next_deadline_s >= end_s - 1e-9:
                return
            self.kind.play(self._grant.ticket)  # what moves between the steps, for this grant
            await sleep_until_woken(self.kind.clock, timer.next_wake_s, self._wake)
            if self.stop_requested or self.state is not RunState.RUNNING:
                continue  # woken by a request: handled at the top
            # a request that lands during the last yield before the deadline finds this step
            # under way (it completes): skipping it would leave a gap in the step numbers
            tick = await timer.wait()
            collector.step(running=True)
            self._step_grants[tick.step] = self._grant.ticket
            try:
                outcome = await self.kind.step(tick)
            finally:
                collector.step(running=False)
            # the steps before overlapped this step's move: those done are collected now
            # (published and judged in step order); the oldest is waited for when too many are
            # under way, and this one at once when it is done or the next step needs it
            measuring = MeasuringStep.of(tick.step, outcome)
            self._measuring.add(measuring)
            await self._measuring.settle(keep=measuring.may_overlap * (MEASURING_STEPS - 1))
            timer.step_done()
            self._services.read_model.progress()
            collector.after_step((timer.next_wake_s - timer.clock.now()) / factor)

    async def _collect(self, step: int, outcome: StepOutcome) -> None:
        """A committed step, in step order: published, then its verdict acted on."""
        self._recorded(outcome)
        await self._judge(step, outcome.verdict, self._step_grants.pop(step, self._grant.ticket))

    def _recorded(self, outcome: StepOutcome) -> None:
        """A committed step: the session's last step, then its publication (the budget in wall
        seconds, as the stages are timed: ``factor`` run seconds a wall second)."""
        factor = 1.0 if self.timer is None else float(getattr(self.timer.clock, "factor", 1.0))
        self.step = outcome.record.step
        self.last_record = outcome.record.as_dict()
        self._publisher.step(
            outcome, self.last_record, self.view(), self.kind.parameters.step_s, factor
        )

    async def _judge(self, step: int, verdict: Verdict, grant: Ticket) -> None:
        """A step's verdict meets the operator's requests here. ``grant``: the request (start
        or resume) the step moved for."""
        if verdict.kind == "ok":
            return
        stale = self.state is not RunState.RUNNING or grant != self._grant.ticket
        if stale or self._services.hold_pending():
            # a hold request from the API's thread held the permit and its pause or stop is on
            # its way here (that request came first); or the run was paused, faulted or stopped
            # after this step moved, by a request or a verdict that held the robot then, and
            # may have been resumed since by a later request: this verdict (often the hold's
            # own refusal of the step's move) stays on its record; holding again now would
            # refuse or undo that resume
            since = f"the run was {self.state.value} since it moved" if stale else "a hold came"
            logger.info(
                "run %d step %d: %s is on its record; %s", self.id, step, verdict.reason, since
            )
            return
        if verdict.kind == "fault":
            await self._fault(verdict.reason or "device fault")
            return
        logger.warning("run %d step %d: %s", self.id, step, verdict.reason)
        await self._grant.hold(f"run {self.id} paused: {verdict.reason}")  # paused: held
        self._go(RunState.PAUSED, verdict.reason)

    async def _fault(self, reason: str) -> None:
        """A device fault: hold motion first, then park the run in ``fault`` until an explicit
        resume -- unless a request (pause, stop) came first: then the fault is on the step."""
        await self._grant.hold(f"run {self.id} fault: {reason}")
        if self.state in (RunState.RUNNING, RunState.STARTING):
            self._go(RunState.FAULT, reason)
        else:
            logger.warning("run %d: %s (the run is already %s)", self.id, reason, self.state.value)

    async def _wait_while_held(self) -> bool:
        """Wait while paused or faulted; False when a stop came instead of a resume."""
        while self.state in (RunState.PAUSED, RunState.FAULT) and not self.stop_requested:
            self._wake.clear()
            await self._wake.wait()
        return not self.stop_requested

    async def _finish(self, final: RunState, reason: str | None) -> None:
        """Hold the robot, record the final state, then the summary. Never raises: whatever
        fails here, the run still ends in ``final`` with the daemon idle (issue 15, point 5).
        The end is written before the summary: a day at a 20 ms step is 4.32 M steps to read
        back, and a shutdown must end within systemd's TimeoutStopSec (issue 26): a summary the
        shutdown gives up is deferred to the next start (daemon/run/pending_summaries.py)."""
        services = self._services
        try:
            # the hold says why when nothing asked for it first (issue 26: not "stopped by
            # request" after a recording failure aborted the run)
            await self._grant.hold(
                f"run {self.id} {final.value}" + (f": {reason}" if reason else "")
            )
            # after the hold: a robot that plays its own program is paused then, unless the
            # run simply reached its end (daemon/run/followed/program_pause.py)
            await self.kind.stop_playing(
                services.settings.scheduler.stop_grace_s, held=final is not RunState.FINISHED
            )
            await self._measuring.settle_at_end(self.id, services.errors)
            if self.state is not RunState.STOPPING and self.machine.can(RunState.STOPPING):
                self._go(RunState.STOPPING, reason)
            recorded = await ending.record_end(services, self.id, final, reason)
            # as the database keeps it: the summary now and a deferred one are the same
            basis = stored_basis(
                self.kind.summary_basis(
                    overruns=0 if self.timer is None else self.timer.overruns,
                    skipped=0 if self.timer is None else self.timer.skipped,
                    timing=services.timing.summary(fresh=True),
                )
            )
            self.summary = await ending.summarize(services, self.kind, basis, self._abandon_summary)
            if self.summary is None and self._abandon_summary.is_set():  # a shutdown gave it up
                self.summary_deferred = await ending.defer_summary(services, self.id, basis)
            elif self.summary is not None:
                await ending.store_summary(
                    services, self.id, self.summary, recorded=recorded, final=final, reason=reason
                )
        except Exception as err:  # a bug in the ending itself: still end (traceback logged)
            logger.exception("run %d: error while ending", self.id)
            services.errors.note(err, device="daemon")
        finally:
            self.ended_s = self.kind.clock.now()
            self.machine.state, self.machine.reason = final, reason
            self._publisher.state(self.view())
            # a deferred summary's report comes with it, at the next start
            report = services.settings.storage.report_at_end and not self.summary_deferred
            if report and self.step >= 0:
                run_id = self.id
                services.post_home(lambda: services.reports.submit(run_id))
            logger.info("run %d %s%s", self.id, final.value, f" ({reason})" if reason else "")

    # --- the one place a state changes ----------------------------------------------------

    def _go(self, state: RunState, reason: str | None) -> None:
        """Change state now (no await between the caller's check and this), publish it and
        the new view, and persist it in order on the recorder's thread."""
        self.machine.go(state, reason)
        if state is RunState.RUNNING:
            self._services.read_model.progress()  # a pause is not a hung loop
        self._wake.set()
        logger.info("run %d: %s%s", self.id, state.value, f" ({reason})" if reason else "")
        self._announce(state, reason)

    def _set_reason(self, reason: str) -> None:
        self.machine.reason = reason
        self._announce(self.state, reason)

    def _announce(self, state: RunState, reason: str | None) -> None:
        self._publisher.state(self.view())
        self._publisher.persist_state(state, reason)

    def view(self) -> RunView:
        return RunView(
            id=self.id,
            state=self.state,
            reason=self.machine.reason,
            step=self.step,
            parameters=self.kind.parameters,
            start_s=self.kind.start_s,
            end_s=self.ended_s,
            summary=self.summary,
            overruns=0 if self.timer is None else self.timer.overruns,
            skipped=0 if self.timer is None else self.timer.skipped,
            last_record=self.last_record,
            kind=self.kind.name,
        )
