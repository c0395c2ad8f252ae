"""The daemon: devices, recorder, workers and the one current run, behind a small async API.

``async with Daemon(settings) as daemon:`` opens the run database (marking runs a crash left
live as ``interrupted``) and the devices; leaving holds the robot, stops any run (``stopped``,
"daemon shut down", committed) and closes everything. The REST/WebSocket API and ``thermocomp
run`` are thin layers over :meth:`Daemon.start_run`, :meth:`pause`, :meth:`resume`,
:meth:`stop`, :meth:`hold_robot`, :meth:`shutdown`, :meth:`snapshot` and :meth:`subscribe`.

Where things live (issue 15): a run's state changes only in daemon/run/session.py; one step is
daemon/run/two_link/step.py (model -> target check -> move -> measure -> record); the safety checks
of a target are daemon/model/compensation.py (limits) and the robot driver (hold, finite values,
right before the bytes are written). This façade only routes requests and keeps the read model
(daemon/run/readmodel.py) that the API reads; a run is built from its parameters in
daemon/run/start.py, and a run's end that could not be written is kept and written again by
daemon/run/unrecorded_end.py.

The devices and the run live on the control loop (daemon/run/control_loop.py: a thread with its
own event loop when the clock is a wall clock); the methods here run on the API's loop and hand
each request to it: a hold is taken on the permit here first, before anything is awaited.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from collections.abc import Callable
from contextlib import AbstractAsyncContextManager
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

from config import Settings
from daemon.run.arm.setup import ArmMeterFactory, ArmSetup, default_arm_meter, default_arm_setup
from daemon.run.control_loop import ControlLoop
from daemon.run.devices_check import DeviceCheck, Devices, check_devices
from daemon.run.events import (
    ERROR_HISTORY,
    EVENT_QUEUE_DEFAULT,
    ErrorEntry,
    ErrorLog,
    EventBus,
    Subscription,
)
from daemon.run.gc_policy import GcPolicy
from daemon.run.hold_requests import HoldRequests
from daemon.run.kinds import build_kind
from daemon.run.pending_summaries import PendingSummaries
from daemon.run.readmodel import RunReadModel, RunView
from daemon.run.scheduler import TimingStats
from daemon.run.sensors import Sensors
from daemon.run.services import SessionServices
from daemon.run.session import ResumeRefusedError, RunSession
from daemon.run.setup import RunParameterError
from daemon.run.start import RunBuilder
from daemon.run.states import RunParameters, RunState, RunStateError
from daemon.run.unrecorded_end import UnrecordedEnd
from daemon.run.workers import Workers
from daemon.storage.recorder import Recorder
from daemon.storage.report_queue import ReportQueue, ReportStatus
from drivers.clock import Clock, ScaledClock, make_clock
from drivers.factory import open_devices
from drivers.permit import MotionPermit, Ticket

__all__ = [
    "Daemon",
    "ResumeRefusedError",
    "RunConflictError",
    "RunParameterError",
]

logger = logging.getLogger(__name__)

_T = TypeVar("_T")

#: How often an end of run that could not be recorded (disk full, database read-only) is
#: written again, until it is (s; daemon/run/unrecorded_end.py).
UNRECORDED_END_RETRY_S = 2.0
SHUTDOWN_REASON = "daemon shut down"
#: At a shutdown, how long the summary of the run that ends may take beyond the step's grace
#: (s): the run's end is recorded before it, and systemd's TimeoutStopSec is 30 s
#: (deploy/thermocomp.service), so a long run's summary is given up rather than the end lost.
SHUTDOWN_SUMMARY_BUDGET_S = 15.0
HOLD_REASON = "robot held by request"


class RunConflictError(RunStateError):
    """A run is already active: one run at a time."""


DeviceOpener = Callable[[Settings, Clock], AbstractAsyncContextManager[Devices]]


class Daemon:
    """The service object (see the module docstring). One per process."""

    def __init__(
        self,
        settings: Settings,
        *,
        clock: Clock | None = None,
        open_devices: DeviceOpener | None = None,
        event_queue_size: int = EVENT_QUEUE_DEFAULT,
        arm_setup: ArmSetup = default_arm_setup,
        arm_meter: ArmMeterFactory = default_arm_meter,
    ) -> None:
        self.settings = settings
        self.clock: Clock = clock or make_clock(settings.bench.clock, settings.bench.time_factor)
        self._open_devices = open_devices
        self._arm_setup = arm_setup  # an arm run's model and poses (issue 20)
        self._arm_meter = arm_meter  # ... and its tool measurement
        self._exit_stack = contextlib.AsyncExitStack()
        self._devices: Devices | None = None
        self._sensors: Sensors | None = None
        self._workers: Workers | None = None
        self.recorder: Recorder | None = None
        self.reports = ReportQueue(settings.storage.data_dir)
        self.bus = EventBus(event_queue_size)
        self.error_log = ErrorLog(self.bus, ERROR_HISTORY)
        self.timing = TimingStats()
        self._session: RunSession | None = None
        #: the current or last run as the API sees it, and the control loop's liveness
        self.read_model = RunReadModel()
        self._requests = asyncio.Lock()  # serialises start/pause/resume/stop
        #: where the devices live and the run's steps run (daemon/run/control_loop.py): a
        #: thread of its own with a wall clock (real or accelerated), else this loop
        mode = settings.scheduler.control_thread
        wall_clock = isinstance(self.clock, ScaledClock)  # a virtual clock's sleepers share a loop
        self._control = ControlLoop(
            threaded=mode == "on" or (mode == "auto" and wall_clock),
            realtime_priority=settings.scheduler.realtime_priority,
        )
        #: full garbage collections kept between the steps (daemon/run/gc_policy.py)
        self.gc_policy = GcPolicy(enabled=settings.scheduler.gc_between_steps)
        self._unrecorded_end = UnrecordedEnd(self._storage, UNRECORDED_END_RETRY_S)
        #: summaries the last shutdown deferred (daemon/run/pending_summaries.py)
        self.pending_summaries: PendingSummaries | None = None
        #: holds asked here and not yet carried out on the control loop (see hold_pending)
        self._holds = HoldRequests()

    # --- lifecycle ---------------------------------------------------------------------

    async def __aenter__(self) -> Daemon:
        try:
            # first in, so last out: the devices are closed on it before it stops
            control = await self._exit_stack.enter_async_context(self._control)
            self.gc_policy.install()
            self._exit_stack.callback(self.gc_policy.remove)
            if control.threaded:
                self.bus.route(control.post_home)
                self._exit_stack.callback(self.bus.route, None)
            self._workers = Workers(control.critical_thread_setup())
            self._exit_stack.callback(self._workers.shutdown)
            self.recorder = await self._workers.db(Recorder, self.settings.storage.data_dir)
            self._exit_stack.callback(self.recorder.close)
            opener: DeviceOpener = self._open_devices or open_devices
            # opened on the control loop: their ports, readers and tasks belong to it
            device_stack = contextlib.AsyncExitStack()
            self._exit_stack.push_async_callback(control.call, device_stack.aclose)
            self._devices = await control.call(
                lambda: device_stack.enter_async_context(opener(self.settings, self.clock))
            )
            self._sensors = Sensors(
                self.settings,
                self._devices.camera,
                self._devices.ir,
                self.error_log,
                getattr(self._devices, "room", None),
            )
            self.reports.start()
            self._exit_stack.push_async_callback(self.reports.close)
            # summaries the last shutdown deferred: computed in the background, after
            # everything above is open; they never delay readiness, a hold or a run's steps
            self.pending_summaries = PendingSummaries(
                self._workers,
                self.recorder,
                self.reports,
                self.error_log,
                report_at_end=self.settings.storage.report_at_end,
            )
            self.pending_summaries.start()
            self._exit_stack.push_async_callback(self.pending_summaries.stop)
        except BaseException:
            await self._exit_stack.aclose()
            raise
        logger.info("daemon ready (data in %s)", self.settings.storage.data_dir)
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        try:
            await self.shutdown()
            await self._unrecorded_end.stop_retrying()
            await self._unrecorded_end.record()  # one last try before the database closes
        finally:
            await self._exit_stack.aclose()
            self._devices = None

    async def shutdown(self, reason: str = SHUTDOWN_REASON) -> None:
        """Hold the robot first, then stop the run (``stopped``, committed). Safe to call more
        than once (a second signal): each call holds again and waits for the same ending."""
        if self._devices is None:
            return
        with self._holds.asked():
            await self.hold_robot(reason, pause=False)  # first: nothing moves from here on
            if self.pending_summaries is not None:
                self.pending_summaries.give_up()  # deferred again: the stop's budget is the run's
            session = self._session
            if session is None or session.task is None:
                return
            if session.state.is_active:
                await self._control.run(lambda: session.request_stop(reason))
        await self._control.call(
            lambda: session.wait_ended(
                self.settings.scheduler.stop_grace_s, SHUTDOWN_SUMMARY_BUDGET_S
            )
        )

    @property
    def recorder_path(self) -> Path:
        return self._recorder().path

    @property
    def permit(self) -> MotionPermit:
        """The robot's permit (drivers/permit.py): the one owner of "may the robot move"."""
        return self.devices.robot.permit

    @property
    def devices(self) -> Devices:
        if self._devices is None:
            raise RuntimeError("the daemon is not started (use `async with Daemon(...)`)")
        return self._devices

    # --- commands ----------------------------------------------------------------------

    async def start_run(
        self, parameters: RunParameters, ticket: Ticket | None = None
    ) -> dict[str, Any]:
        """Start a run; return its info. RunConflictError when one is active,
        RunParameterError when the parameters are not admissible, RecorderError when the
        database cannot record it (e.g. the last run's end is still unrecorded).

        ``ticket``: the robot's permit when the request arrived (api/tickets.py), else now,
        before anything is awaited: the run may release a hold from before it, never one that
        comes while it is built (drivers/permit.py)."""
        ticket = ticket if ticket is not None else self.permit.ticket()
        async with self._requests:
            session = self._session
            if session is not None and session.state.is_active:
                raise RunConflictError(
                    f"run {session.id} is {session.state.value}: one run at a time"
                )
            await self._unrecorded_end.record(raise_on_failure=True)
            timing = TimingStats()
            services = SessionServices(
                settings=self.settings,
                robot=self.devices.robot,
                recorder=self._recorder(),
                workers=self._workers_(),
                bus=self.bus,
                errors=self.error_log,
                timing=timing,
                reports=self.reports,
                read_model=self.read_model,
                unrecorded_end=self._unrecorded_end,
                post_home=self._control.post_home,
                hold_pending=self.hold_pending,
                gc_policy=self.gc_policy,
            )
            # built and started on the control loop: the run's task, its devices' I/O and
            # its state live there (RunSession stays their one owner)
            return await self._control.call(
                lambda: self._start_session(parameters, services, ticket)
            )

    async def _start_session(
        self, parameters: RunParameters, services: SessionServices, ticket: Ticket
    ) -> dict[str, Any]:
        kind = await build_kind(self._run_builder(), parameters)
        self.timing = services.timing
        session = RunSession(kind, services, ticket)
        self._session = session
        session.start()
        logger.info("run %d (%s) started: %s", kind.run_id, kind.name, parameters.model_dump())
        return session.view().info(self.clock.now())

    async def pause(self, reason: str = "paused by request") -> None:
        """Hold the robot first (before anything is awaited), then pause the run: paused
        means held (docs/explanation/hold.md). A start still preparing is parked."""
        self._active_session()  # RunStateError (nothing held) when no run is active
        with self._holds.asked():
            await self.hold_robot(reason, pause=False)
            async with self._requests:
                await self._control.run(lambda: self._active_session().pause(reason))

    async def resume(self, ticket: Ticket | None = None) -> None:
        """Resume a paused or faulted run (ResumeRefusedError when it cannot continue).
        ``ticket``: the permit when the request arrived (else now): a hold that came after it
        wins."""
        ticket = ticket if ticket is not None else self.permit.ticket()
        async with self._requests:
            session = self._active_session()
            await self._control.call(lambda: session.resume(ticket))

    async def stop(
        self, reason: str = "stopped by request", final: RunState = RunState.STOPPED
    ) -> dict[str, Any]:
        """Stop the current run: the robot holds where it is, the recording is committed.
        Waits for the run to end; returns its info. ``final``: ``stopped`` (a request), or
        ``aborted`` for a caller that stops a run because it cannot go on."""
        with self._holds.asked():
            await self.hold_robot(reason, pause=False)  # first: nothing moves from here on
            async with self._requests:
                session = await self._control.run(self._active_session)
                await self._control.run(lambda: session.request_stop(reason, final))
        await self._control.call(lambda: session.wait_ended(self.settings.scheduler.stop_grace_s))
        return session.view().info(self.clock.now())

    async def hold_robot(self, reason: str = HOLD_REASON, *, pause: bool = True) -> None:
        """Hold the robot now, whatever the run state, behind nothing: the permit is held
        (its generation bumped) before this awaits anything, so the driver refuses motion and
        no request already in flight can release it (drivers/permit.py); then the driver's own
        hold (the fast path's HOLD frame), then a running run pauses and a starting one is
        cancelled."""
        robot = self.devices.robot
        with self._holds.asked():
            robot.permit.hold(reason)  # here, on the caller's thread: motion refused from now
            await self._control.call(lambda: self._hold_there(reason, pause))

    def hold_pending(self) -> bool:
        """A hold request has held the permit and has not yet reached the run (any thread)."""
        return self._holds.pending()

    async def _hold_there(self, reason: str, pause: bool) -> None:
        """On the control loop, where the driver lives: its HOLD, then the run's pause."""
        await self.devices.robot.stop()
        session = self._session
        if pause and session is not None:
            session.robot_held(reason)

    async def wait_run(self) -> dict[str, Any]:
        """Wait until the current run's task ends (finished, stopped, aborted or in fault)."""
        session = self._session
        if session is None:
            raise RunStateError("no run")
        task = session.task
        if task is not None:
            # asyncio.wait, not the task itself: a run task ended by cancellation (a step
            # abandoned to stop) must not raise CancelledError into a caller nobody cancelled
            await self._control.call(lambda: asyncio.wait({task}))
        return session.view().info(self.clock.now())

    async def wait_state(self, *states: RunState) -> RunState:
        """Wait until the current run is in one of ``states`` or has ended."""
        with self.subscribe(kinds=frozenset({"state"})) as subscription:
            while True:
                session = self._session
                if session is None:
                    raise RunStateError("no run")
                ended = session.state.is_terminal or (
                    session.task is not None and session.task.done()
                )
                if session.state in states or ended:
                    return session.state
                await subscription.get()

    async def check_devices(self) -> DeviceCheck:
        """The bring-up check of the daemon's own devices (issue 18: one frame, one IR image,
        the pose) while no run is active: RunConflictError during a run, and a start waits
        until the check is done (the same request lock), so the two never share a device."""
        async with self._requests:
            session = self._session
            if session is not None and session.state.is_active:
                raise RunConflictError(
                    f"run {session.id} is {session.state.value}: the devices are the run's"
                )
            return await self._control.call(lambda: check_devices(self.devices, self.settings))

    async def read(self, function: Callable[..., _T], *args: Any) -> _T:
        """Run an API read (database, files) on the bounded read pool, never on the control
        loop's workers (issue 15, point 6)."""
        return await self._workers_().read(function, *args)

    async def export(self, function: Callable[..., _T], *args: Any) -> _T:
        """Run an export's encoding (daemon/storage/exports.py) in an export process: it never holds
        this process's GIL, so it cannot delay a step (issue 15, point 6)."""
        return await self._workers_().export(function, *args)

    def report_status(self, run_id: int) -> ReportStatus | None:
        return self.reports.status(run_id)

    # --- observation -------------------------------------------------------------------

    @property
    def view_version(self) -> int:
        """Bumped at each new view: caches of the state key on it."""
        return self.read_model.version

    @property
    def last_progress_monotonic(self) -> float:
        return self.read_model.last_progress_monotonic

    @property
    def run(self) -> RunView | None:
        """The current or last run, as a frozen view (never the live run)."""
        return self.read_model.view

    @property
    def errors(self) -> deque[ErrorEntry]:
        return self.error_log.entries

    @property
    def sensor_states(self) -> dict[str, str]:
        return {} if self._sensors is None else dict(self._sensors.states)

    def subscribe(
        self, maxsize: int | None = None, kinds: frozenset[str] | None = None
    ) -> Subscription:
        return self.bus.subscribe(maxsize, kinds)

    def control_loop_alive(self, max_silence_s: float) -> bool:
        """For the systemd watchdog (issue 10): daemon/run/readmodel.py."""
        return self.read_model.control_loop_alive(max_silence_s)

    def recent_errors(self, limit: int = ERROR_HISTORY) -> list[dict[str, Any]]:
        """The latest device/storage/daemon errors, oldest first."""
        return self.error_log.recent(limit)

    def snapshot(self) -> dict[str, Any]:
        """Everything the daemon knows now: state, run, last step, devices, timing, errors."""
        return self.read_model.snapshot(
            self.clock.now(),
            robot=self.devices.robot.status() if self._devices is not None else None,
            timing=self.timing.summary(),
            errors=self.recent_errors(10),
        )

    # --- internals ---------------------------------------------------------------------

    def _run_builder(self) -> RunBuilder:
        return RunBuilder(
            settings=self.settings,
            clock=self.clock,
            devices=lambda: self.devices,
            sensors=self._sensors,
            workers=self._workers_(),
            recorder=self._recorder(),
            errors=self.error_log,
            arm_setup=self._arm_setup,
            arm_meter=self._arm_meter,
        )

    def _storage(self) -> tuple[Workers, Recorder] | None:
        if self._workers is None or self.recorder is None:
            return None
        return self._workers, self.recorder

    def _recorder(self) -> Recorder:
        if self.recorder is None:
            raise RuntimeError("the daemon is not started")
        return self.recorder

    def _workers_(self) -> Workers:
        if self._workers is None:
            raise RuntimeError("the daemon is not started")
        return self._workers

    def _active_session(self) -> RunSession:
        session = self._session
        if session is None or not session.state.is_active:
            raise RunStateError("no active run")
        return session
