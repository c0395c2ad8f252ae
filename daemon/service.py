"""The daemon: devices, recorder and the one current run, behind a small async API.

``async with Daemon(settings) as daemon:`` opens the run database (marking runs a crash left
live as ``interrupted``) and the devices; leaving stops any run (robot held, recording
committed) and closes everything. The REST/WebSocket API (issue 7) and ``thermocomp run``
are thin layers over :meth:`Daemon.start_run`, :meth:`pause`, :meth:`resume`, :meth:`stop`,
:meth:`hold_robot`, :meth:`snapshot` and :meth:`subscribe`.

One step (issue 6, thesis 6.4), in this fixed order, each stage timed:
model -> compensation target -> move -> frame -> centroid -> IR -> record (committed before
the next step begins) -> publish.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import AbstractAsyncContextManager
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from config import Settings
from daemon import __version__
from daemon.analysis import NUMERIC_COLUMNS, RunSteps, summarize_run
from daemon.model import ThermalModel, ThermalNetwork, load_network
from daemon.model.compensation import (
    CompensationLimits,
    UnsafeTargetError,
    check_offset,
    check_scale,
    compensation_offset_mm,
)
from daemon.model.model import EXACT_NODE_LIMIT
from daemon.model.observer import IrObserver, regions_to_nodes
from daemon.recorder import Recorder, RecorderError, StepRecord
from daemon.reports import write_run_report
from daemon.runs import (
    ProcedurePoint,
    RunParameters,
    RunState,
    RunStateError,
    StateMachine,
    heat_at,
    procedure_point,
)
from daemon.scheduler import FixedStepTimer, TimingStats, percentiles
from daemon.vision import CentroidError, measure_with_camera_settings
from drivers.base import Camera, Frame, IrReader, IrReading, MoveResult, Pose, Robot
from drivers.clock import Clock, make_clock
from drivers.errors import DeviceError, DeviceTimeoutError

logger = logging.getLogger(__name__)

_T = TypeVar("_T")

#: Model steps above this many node-substeps of work go to a worker thread (numpy releases
#: the GIL); a 17-node exact step is a few microseconds and stays on the loop.
MODEL_WORK_OFF_LOOP = 200_000
EVENT_QUEUE_DEFAULT = 256
ERROR_HISTORY = 200
#: A step that begins more than this fraction of a period after its deadline is flagged late.
LATE_FRACTION = 0.1
#: What the end-of-run summary reads of the steps: no JSON columns (temperatures, IR, stage
#: timings), which cost most of the time to read back.
SUMMARY_COLUMNS = (*NUMERIC_COLUMNS, "run_id", "flags", "error")
#: Flags that the scheduler.sensor_error_policy acts on (issue 10: camera and IR faults). A
#: stale frame or reading counts: it is recorded but never used, so the step has no
#: measurement, as with no frame at all (a normal bench run on its virtual clock has none).
SENSOR_ERROR_FLAGS = frozenset(
    {"camera-error", "ir-error", "centroid-error", "stale-frame", "stale-ir"}
)


class RunConflictError(RunStateError):
    """A run is already active: one run at a time."""


class RunParameterError(ValueError):
    """The run's parameters are not admissible (e.g. scale pushes the spot off the chip)."""


class Devices(Protocol):
    """What the daemon needs of ``drivers.factory.open_devices``'s result."""

    @property
    def camera(self) -> Camera: ...

    @property
    def ir(self) -> IrReader: ...

    @property
    def robot(self) -> Robot: ...


class BenchControl(Protocol):
    """What the daemon tells the simulated bench (drivers.sim.bench.Bench) when a run starts."""

    def start_run(
        self,
        t_s: float,
        *,
        deformation_scale: float | None = None,
        procedure: str | None = None,
        heater_off_s: float | None = None,
    ) -> None: ...


DeviceOpener = Callable[[Settings, Clock], AbstractAsyncContextManager[Devices]]


@dataclass(frozen=True, slots=True)
class Event:
    """What subscribers receive: ``kind`` is "step", "state", "error" or "frame" (the frame's
    image as an array: subscribe to it only where it is consumed in process)."""

    kind: str
    data: dict[str, Any]


class Subscription:
    """A bounded event queue: when full, the oldest event is dropped and counted, so a slow
    reader never slows the control loop (issue 7)."""

    def __init__(self, owner: Daemon, maxsize: int, kinds: frozenset[str] | None) -> None:
        self._owner = owner
        self._queue: asyncio.Queue[Event] = asyncio.Queue(maxsize)
        self.kinds = kinds
        self.dropped = 0

    def put(self, event: Event) -> None:
        if self.kinds is not None and event.kind not in self.kinds:
            return
        if self._queue.full():
            self._queue.get_nowait()
            self.dropped += 1
        self._queue.put_nowait(event)

    async def get(self) -> Event:
        return await self._queue.get()

    def get_nowait(self) -> Event | None:
        try:
            return self._queue.get_nowait()
        except asyncio.QueueEmpty:
            return None

    def close(self) -> None:
        self._owner._subscriptions.discard(self)

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


@dataclass(frozen=True, slots=True)
class ErrorEntry:
    time_unix: float
    device: str
    kind: str
    message: str

    def as_dict(self) -> dict[str, Any]:
        return {
            "time": self.time_unix,
            "device": self.device,
            "kind": self.kind,
            "message": self.message,
        }


@dataclass(eq=False)
class ActiveRun:
    """The daemon's current run and its working state."""

    id: int
    parameters: RunParameters
    machine: StateMachine
    model: ThermalModel
    direction: NDArray[np.float64]  # unit vector of the link axis, world coordinates
    timer: FixedStepTimer | None = None
    start_s: float = math.nan  # run clock at step 0
    goal: Pose | None = None  # taught operational goal
    step: int = -1  # last recorded step
    last_offset_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    last_target_mm: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    reference_um: dict[int, tuple[float, float]] = field(default_factory=dict)
    last_record: StepRecord | None = None
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    stop_requested: bool = False
    stop_reason: str | None = None
    task: asyncio.Task[None] | None = None
    summary: dict[str, Any] | None = None
    model_heat: dict[str, float] = field(default_factory=dict)
    final_on_stop: RunState = RunState.FINISHED
    finishing: bool = False  # holding the robot, writing the summary and the final state
    reference_source: str = "first step"  # where the drift's zero was measured
    report_path: Path | None = None  # the end-of-run report, once written
    observer: IrObserver | None = None  # prediction "model+ir": the IR Kalman filter

    @property
    def state(self) -> RunState:
        return self.machine.state

    def info(self, clock_now: float) -> dict[str, Any]:
        elapsed = 0.0 if math.isnan(self.start_s) else max(clock_now - self.start_s, 0.0)
        duration = self.parameters.duration_s
        progress = min(100.0, 100.0 * elapsed / duration)
        return {
            "id": self.id,
            "state": self.state.value,
            "reason": self.machine.reason,
            "step": self.step,
            "parameters": self.parameters.model_dump(mode="json"),
            "progress_percent": progress,
            "remaining_s": max(duration - elapsed, 0.0),
            "summary": self.summary,
            "report": None if self.report_path is None else str(self.report_path),
        }


class Daemon:
    """The service object (see the module docstring). One per process."""

    def __init__(
        self,
        settings: Settings,
        *,
        clock: Clock | None = None,
        open_devices: DeviceOpener | None = None,
        event_queue_size: int = EVENT_QUEUE_DEFAULT,
    ) -> None:
        self.settings = settings
        self.clock: Clock = clock or make_clock(settings.bench.clock, settings.bench.time_factor)
        self._open_devices = open_devices
        self._event_queue_size = event_queue_size
        self._exit_stack = contextlib.AsyncExitStack()
        self._devices: Devices | None = None
        self.recorder: Recorder | None = None
        self.run: ActiveRun | None = None
        self.timing = TimingStats()
        self.errors: deque[ErrorEntry] = deque(maxlen=ERROR_HISTORY)
        self._subscriptions: set[Subscription] = set()
        #: the latest frame and its centroid (kind "frame"), for a live view
        self.last_frame_event: Event | None = None
        self._db_executor: ThreadPoolExecutor | None = None
        self._lock = asyncio.Lock()  # serialises start/pause/resume/stop requests
        #: monotonic time of the control loop's last sign of life (systemd watchdog, issue 10)
        self.last_progress_monotonic = time.monotonic()
        #: how each sensor's last grab/read went (GET /health): "open" before the first,
        #: then "ok", "stale" or "<error kind> error" (e.g. "timeout error")
        self.sensor_states: dict[str, str] = {}

    # --- lifecycle ---------------------------------------------------------------------

    async def __aenter__(self) -> Daemon:
        try:
            self._db_executor = ThreadPoolExecutor(1, thread_name_prefix="recorder")
            self._exit_stack.callback(self._db_executor.shutdown)
            self.recorder = await self._db(Recorder, self.settings.storage.data_dir)
            self._exit_stack.callback(self.recorder.close)
            opener = self._open_devices or _default_opener
            self._devices = await self._exit_stack.enter_async_context(
                opener(self.settings, self.clock)
            )
            self.sensor_states = {"camera": "open", "ir": "open"}
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
            run = self.run
            if run is not None and run.state.is_active:
                await self.stop(reason="the daemon shut down", final=RunState.ABORTED)
            elif run is not None and run.task is not None:
                await asyncio.wait({run.task})  # a run that is just ending: let it end
        finally:
            await self._exit_stack.aclose()
            self._devices = None

    @property
    def recorder_path(self) -> Path:
        return self._recorder().path

    @property
    def devices(self) -> Devices:
        if self._devices is None:
            raise RuntimeError("the daemon is not started (use `async with Daemon(...)`)")
        return self._devices

    # --- runs --------------------------------------------------------------------------

    async def start_run(self, parameters: RunParameters) -> dict[str, Any]:
        """Start a run; return its info. RunConflictError when one is active,
        RunParameterError when the parameters are not admissible."""
        async with self._lock:
            if self.run is not None and self.run.state.is_active:
                raise RunConflictError(
                    f"run {self.run.id} is {self.run.state.value}: one run at a time"
                )
            network, model = await asyncio.to_thread(self._build_model, parameters)
            direction = _unit(self.settings.model.direction)
            await asyncio.to_thread(self._check_scale, parameters, network, direction)
            observer = self._build_observer(model) if parameters.prediction == "model+ir" else None
            recorder = self._recorder()
            run_id = await self._db(
                recorder.create_run,
                parameters.model_dump(mode="json"),
                self.settings.model_dump(mode="json"),
                _network_snapshot(network),
                __version__,
            )
            machine = StateMachine()
            machine.go(RunState.STARTING)
            run = ActiveRun(run_id, parameters, machine, model, direction, observer=observer)
            self.run = run
            self.timing = TimingStats()
            self._publish_state(run)
            run.task = asyncio.create_task(self._run_task(run), name=f"run-{run_id}")
            logger.info("run %d started: %s", run_id, parameters.model_dump())
            return run.info(self.clock.now())

    async def pause(self, reason: str = "paused by request") -> None:
        async with self._lock:
            run = self._active_run()
            if run.state is not RunState.RUNNING:
                raise RunStateError(f"run {run.id} is {run.state.value}, not running")
            await self._set_state(run, RunState.PAUSED, reason)
            run.wake.set()

    async def resume(self) -> None:
        """Resume a paused or faulted run: motion is allowed again and the actual pose is read
        back first (issue 6: only on explicit request)."""
        async with self._lock:
            run = self._active_run()
            if run.state not in (RunState.PAUSED, RunState.FAULT):
                raise RunStateError(f"run {run.id} is {run.state.value}: nothing to resume")
            robot = self.devices.robot
            try:
                if run.state is RunState.FAULT or robot.status().motion_held:
                    await robot.resume()
                pose = await robot.actual_pose()
            except DeviceError as err:
                self._note_error(err)
                if run.state is RunState.FAULT:
                    run.machine.reason = f"resume failed: {err}"
                    self._publish_state(run)
                else:
                    await self._set_state(run, RunState.FAULT, f"resume failed: {err}")
                raise
            if run.goal is not None:
                actual = np.subtract(pose.position, run.goal.position)
                # the incremental mode continues from where the robot really is
                run.last_target_mm = actual
            await self._set_state(run, RunState.RUNNING, None)
            run.wake.set()

    async def stop(
        self, reason: str = "stopped by request", final: RunState = RunState.FINISHED
    ) -> dict[str, Any]:
        """Stop the current run: the robot holds where it is, the recording is committed.
        Waits for the run to end; returns its info."""
        async with self._lock:
            run = self._active_run()
            if run.state is RunState.FAULT:
                final = RunState.ABORTED  # ended because of the fault, not completed
            run.stop_requested = True  # before any await: the loop must see it first
            run.stop_reason = reason
            run.final_on_stop = final
            run.wake.set()
            if run.state is not RunState.STOPPING:
                await self._set_state(run, RunState.STOPPING, reason)
        if run.task is not None:
            # the step in progress may finish; one stuck on a device is abandoned after the
            # grace period (issue 10: SIGTERM ends within a bounded time)
            grace_s = self.settings.scheduler.stop_grace_s
            _, pending = await asyncio.wait({run.task}, timeout=grace_s)
            if pending and not run.finishing:
                logger.warning("run %d: abandoning the step in progress to stop", run.id)
                run.task.cancel()
            await asyncio.wait({run.task})
        return run.info(self.clock.now())

    async def hold_robot(self) -> None:
        """Hold the robot now, whatever the run state; a running run pauses."""
        async with self._lock:
            run = self.run
            if run is not None and run.state is RunState.RUNNING:
                await self._set_state(run, RunState.PAUSED, "robot held by request")
        await self.devices.robot.stop()

    async def wait_run(self) -> dict[str, Any]:
        """Wait until the current run's task ends (finished, aborted or left in fault)."""
        run = self.run
        if run is None:
            raise RunStateError("no run")
        if run.task is not None:
            await asyncio.shield(run.task)
        return run.info(self.clock.now())

    async def wait_state(self, *states: RunState) -> RunState:
        """Wait until the current run is in one of ``states`` or has ended."""
        with self.subscribe(kinds=frozenset({"state"})) as subscription:
            while True:
                run = self.run
                if run is None:
                    raise RunStateError("no run")
                ended = run.state.is_terminal or (run.task is not None and run.task.done())
                if run.state in states or ended:
                    return run.state
                await subscription.get()

    # --- observation -------------------------------------------------------------------

    def subscribe(
        self, maxsize: int | None = None, kinds: frozenset[str] | None = None
    ) -> Subscription:
        subscription = Subscription(self, maxsize or self._event_queue_size, kinds)
        self._subscriptions.add(subscription)
        return subscription

    def control_loop_alive(self, max_silence_s: float) -> bool:
        """For the systemd watchdog (issue 10): False when a running run has recorded no step
        for ``max_silence_s`` beyond its step period, i.e. the control loop hangs."""
        run = self.run
        if run is None or run.state is not RunState.RUNNING:
            return True
        silence_s = time.monotonic() - self.last_progress_monotonic
        return silence_s <= max_silence_s + run.parameters.step_s

    def recent_errors(self, limit: int = ERROR_HISTORY) -> list[dict[str, Any]]:
        """The latest device/storage/daemon errors, oldest first."""
        return [entry.as_dict() for entry in list(self.errors)[-limit:]]

    def snapshot(self) -> dict[str, Any]:
        """Everything the daemon knows now: state, run, last step, devices, timing, errors."""
        run = self.run
        robot_status = self.devices.robot.status() if self._devices is not None else None
        timer = run.timer if run is not None else None
        return {
            "state": RunState.IDLE.value
            if run is None or not run.state.is_active
            else run.state.value,
            "run": None if run is None else run.info(self.clock.now()),
            "last_step": None
            if run is None or run.last_record is None
            else run.last_record.as_dict(),
            "robot": None
            if robot_status is None
            else {
                "link": robot_status.link.value,
                "motion_held": robot_status.motion_held,
                "last_error": robot_status.last_error,
            },
            "timing": {
                **self.timing.summary(),
                "overruns": 0 if timer is None else timer.overruns,
                "skipped": 0 if timer is None else timer.skipped,
            },
            "errors": self.recent_errors(10),
        }

    # --- the run task ------------------------------------------------------------------

    async def _run_task(self, run: ActiveRun) -> None:
        final = RunState.FINISHED
        reason: str | None = None
        try:
            await self._prepare(run)
            await self._loop(run)
            if run.stop_requested:
                final, reason = run.final_on_stop, run.stop_reason
        except RecorderError as err:
            logger.error("run %d: recording failed: %s", run.id, err)
            self._note_error(err, device="storage")
            final, reason = RunState.ABORTED, f"recording failed: {err}"
        except asyncio.CancelledError:
            final, reason = RunState.ABORTED, "cancelled"
            if run.stop_requested:
                reason = f"{run.stop_reason}; the step in progress was abandoned"
            raise
        except Exception as err:
            logger.exception("run %d failed", run.id)
            self._note_error(err, device="daemon")
            final, reason = RunState.ABORTED, f"{type(err).__name__}: {err}"
        finally:
            run.finishing = True  # from here on the run is never cancelled: it is ending
            await self._finish(run, final, reason)

    async def _prepare(self, run: ActiveRun) -> None:
        robot = self.devices.robot
        parameters = run.parameters
        try:
            if robot.status().motion_held:
                # the previous run ended with the robot held; starting a run is an explicit
                # request to move again
                await robot.resume()
            run.goal = await robot.teach_goal()  # the operational goal (6.4.3): offsets are from it
        except DeviceError as err:
            self._note_error(err)
            await self._fault(run, f"cannot teach the operational goal: {err}")
            if not await self._wait_while_held(run):
                return
            run.goal = await robot.teach_goal()
        if parameters.warmup_wait_s > 0:
            logger.info("run %d: camera warm-up wait %.0f s", run.id, parameters.warmup_wait_s)
            await self._sleep_until(run, self.clock.now() + parameters.warmup_wait_s)
        bench: BenchControl | None = getattr(self.devices, "bench", None)
        if bench is not None:
            # the simulated links start cold with this run, at its scale and procedure
            bench.start_run(
                self.clock.now(),
                deformation_scale=parameters.deformation_scale,
                procedure=parameters.procedure,
                heater_off_s=parameters.heater_off_s,
            )
        await self._capture_reference(run)
        run.start_s = self.clock.now()
        run.timer = FixedStepTimer(
            self.clock,
            parameters.step_s,
            run.start_s,
            precise_wake_s=self.settings.scheduler.precise_wake_ms / 1000.0,
        )
        if run.state is RunState.STARTING:
            await self._set_state(run, RunState.RUNNING, None)

    async def _capture_reference(self, run: ActiveRun) -> None:
        """The spot at the operational goal before the first move: the zero of every drift.

        Thesis 6.2 sets the centroid "at the start at the operational goal". Taken here, the
        robot has not moved since the goal was taught, so the reference carries no positioning
        error; taken at step 0 instead, that move's error (the robot's repeatability) would
        offset every residual of the run. If no frame can be had, step 0's centroid is used.
        """
        try:
            frame = await self._grab()
            result = await asyncio.to_thread(
                measure_with_camera_settings, frame.image, self.settings.camera
            )
        except (DeviceError, CentroidError) as err:
            if isinstance(err, DeviceError):
                self._note_error(err)
            logger.warning("run %d: no reference frame (%s): step 0 is the reference", run.id, err)
            return
        run.reference_um[0] = (result.x_um, result.y_um)
        run.reference_source = "goal before the first move"

    async def _loop(self, run: ActiveRun) -> None:
        timer = run.timer
        assert timer is not None
        end_s = run.start_s + run.parameters.duration_s
        while True:
            if run.stop_requested or run.state is RunState.STOPPING:
                return
            if run.state in (RunState.PAUSED, RunState.FAULT):
                if not await self._wait_while_held(run):
                    return
                timer.resync()
                continue
            if timer.next_deadline_s >= end_s - 1e-9:
                return
            await self._sleep_until(run, timer.next_wake_s)
            if run.stop_requested or run.state is not RunState.RUNNING:
                continue  # woken by a request: handled at the top
            tick = await timer.wait()
            await self._step(run, tick.step, tick.scheduled_s, tick.actual_s)
            timer.step_done()
            self.last_progress_monotonic = time.monotonic()

    async def _wait_while_held(self, run: ActiveRun) -> bool:
        """Wait while paused or faulted; False when a stop came instead of a resume."""
        while run.state in (RunState.PAUSED, RunState.FAULT) and not run.stop_requested:
            run.wake.clear()
            await run.wake.wait()
        return not run.stop_requested

    async def _sleep_until(self, run: ActiveRun, deadline_s: float) -> None:
        """Sleep on the run clock, waking early for a stop/pause request."""
        if self.clock.now() >= deadline_s:
            return
        run.wake.clear()
        sleeper = asyncio.ensure_future(self.clock.sleep_until(deadline_s))
        waker = asyncio.ensure_future(run.wake.wait())
        try:
            await asyncio.wait({sleeper, waker}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in (sleeper, waker):
                if not task.done():
                    task.cancel()
            await asyncio.gather(sleeper, waker, return_exceptions=True)

    async def _step(self, run: ActiveRun, step: int, scheduled_s: float, actual_s: float) -> None:
        parameters = run.parameters
        run_time_s = scheduled_s - run.start_s
        record = StepRecord(
            run_id=run.id,
            step=step,
            scheduled_s=run_time_s,
            actual_s=actual_s - run.start_s,
            lateness_s=actual_s - scheduled_s,
            deformation_scale=parameters.deformation_scale,
        )
        flags: list[str] = []
        errors: list[str] = []
        stages: dict[str, float] = {}
        if record.lateness_s > LATE_FRACTION * parameters.step_s:
            flags.append("late")
        point = procedure_point(parameters, step, run_time_s)

        # 1. the model, to the time the move is expected to execute (latency-compensated)
        started = time.perf_counter()
        predicted_um = await self._advance_model(run, run_time_s)
        record.model_time_s = run.model.time_s
        record.predicted_x_um, record.predicted_y_um, record.predicted_z_um = map(
            float, predicted_um
        )
        record.model_temperatures_json = json.dumps(
            dict(
                zip(
                    run.model.network.node_names,
                    np.round(run.model.temperatures_c, 4).tolist(),
                    strict=True,
                )
            )
        )
        if run.observer is not None:
            record.deformation_sigma_um = run.observer.corrected_deformation_um()[1]
        stages["model"] = time.perf_counter() - started

        # 2. the compensation target, checked before anything reaches the robot
        started = time.perf_counter()
        unsafe: str | None = None
        offset = np.zeros(3)
        target = np.asarray(point.pose_offset_mm, dtype=np.float64)
        if parameters.compensation != "off":
            limits = CompensationLimits(
                self.settings.compensation.max_step_change_mm,
                self.settings.compensation.max_total_offset_mm,
            )
            try:
                offset = check_offset(
                    compensation_offset_mm(predicted_um, parameters.deformation_scale),
                    run.last_offset_mm,
                    limits,
                )
            except UnsafeTargetError as err:
                unsafe = f"compensation target refused: {err}"
            target = target + offset
        if unsafe is None and not np.all(np.isfinite(target)):
            unsafe = f"motion target is not finite: {target.tolist()}"
        record.offset_x_mm, record.offset_y_mm, record.offset_z_mm = map(float, offset)

        # 3. the move (absolute from the goal, incremental, or none), then the actual pose
        device_fault: str | None = None
        round_trips_s: tuple[float, ...] = ()
        if unsafe is not None:
            flags.append("unsafe-target")
            errors.append(unsafe)
        else:
            try:
                pose, round_trips_s = await self._move(run, target)
                run.last_offset_mm = offset
                run.last_target_mm = target
                record.pose_x_mm, record.pose_y_mm, record.pose_z_mm = pose.position
            except DeviceError as err:
                self._note_error(err)
                flags.append("robot-error")
                errors.append(str(err))
                device_fault = str(err)
        stages["move"] = time.perf_counter() - started

        # 4. frame -> centroid, and the IR regions
        frame: Frame | None = None
        if point.capture and device_fault is None and unsafe is None:
            frame = await self._measure(
                run, point=point, record=record, flags=flags, errors=errors, stages=stages
            )

        # 5. record (committed before the next step), then publish
        record.flags = ",".join(flags)
        record.error = "; ".join(errors)
        # the record's own stage cannot be in it: it is in the timing statistics only
        record.stage_ms_json = json.dumps({k: round(v * 1e3, 3) for k, v in stages.items()})
        started = time.perf_counter()
        archive_every = self.settings.storage.archive_every
        if frame is not None and archive_every and step % archive_every == 0:
            record.frame_path = await asyncio.to_thread(
                self._recorder().archive_frame, run.id, step, frame.image
            )
        await self._db(self._recorder().write_step, record)
        stages["record"] = time.perf_counter() - started
        run.step = step
        run.last_record = record
        self.timing.add(record.lateness_s, stages)
        # the step message is the record plus the serial timings (Prometheus histogram)
        self._publish(Event("step", {**record.as_dict(), "serial_round_trips_s": round_trips_s}))
        if frame is not None:  # for live views (issue 7 thumbnails); a reference, no copy
            self.last_frame_event = Event(
                "frame",
                {
                    "run_id": run.id,
                    "step": step,
                    "image": frame.image,
                    "bit_depth": frame.bit_depth,
                    "timestamp_s": frame.timestamp_s,
                    "centroid_x_px": record.centroid_x_px,
                    "centroid_y_px": record.centroid_y_px,
                },
            )
            self._publish(self.last_frame_event)

        if unsafe is not None:
            logger.warning("run %d step %d: %s", run.id, step, unsafe)
            await self._set_state(run, RunState.PAUSED, unsafe)
        elif device_fault is not None:
            await self._fault(run, device_fault)
        elif self.settings.scheduler.sensor_error_policy == "pause" and (
            set(flags) & SENSOR_ERROR_FLAGS
        ):
            await self._set_state(run, RunState.PAUSED, f"sensor error: {record.error}")

    async def _advance_model(self, run: ActiveRun, run_time_s: float) -> NDArray[np.float64]:
        """Advance the model to the expected execution time, switching the heaters at the
        procedure's switching time exactly; return the predicted deformation vector (um)."""
        parameters = run.parameters
        scale = parameters.time_scale
        target_model_s = (run_time_s + self.settings.compensation.latency_s) * scale
        model = run.model
        if parameters.heater_off_s is not None:
            switch_s = parameters.heater_off_s * scale
            if model.time_s < switch_s <= target_model_s:
                await self._advance_to(run, switch_s)
        if target_model_s > model.time_s:
            await self._advance_to(run, target_model_s)
        if run.observer is not None:
            run.observer.predict(model.time_s)  # the covariance follows the model's mean
        return model.deformation_um()

    async def _advance_to(self, run: ActiveRun, model_s: float) -> None:
        model = run.model
        # the heat over the interval is the procedure's at its start (a step input)
        heat = heat_at(run.parameters, model.time_s / run.parameters.time_scale + 1e-9)
        if heat != run.model_heat:
            model.set_heat(heat)
            run.model_heat = heat
        nodes = len(model.network.node_names)
        work = nodes * nodes * max(1.0, (model_s - model.time_s) / max(model.dt_s, 1e-9))
        if work > MODEL_WORK_OFF_LOOP:
            await asyncio.to_thread(model.advance_to, model_s)
        else:
            model.advance_to(model_s)

    async def _move(
        self, run: ActiveRun, target_mm: NDArray[np.float64]
    ) -> tuple[Pose, tuple[float, ...]]:
        """The move of this step, if any: the actual pose after it, and the round trip of each
        console command it took."""
        robot = self.devices.robot
        mode = run.parameters.compensation
        moving_procedure = run.parameters.procedure != "stationary"
        result: MoveResult | None = None
        if mode == "absolute" or (mode == "off" and moving_procedure):
            result = await robot.move_absolute(_vector3(target_mm))
        elif mode == "incremental":
            # thesis 6.4.3: each move is relative to where the previous one should have ended
            result = await robot.move_incremental(_vector3(target_mm - run.last_target_mm))
        if result is not None:
            return result.actual, result.round_trips_s
        return await robot.actual_pose(), ()

    async def _grab(self) -> Frame:
        timeout_s = self.settings.camera.grab_timeout_s
        return await self._sensor(self.devices.camera.grab(), "camera", "frame", timeout_s)

    async def _read_ir(self) -> IrReading:
        timeout_s = self.settings.ir.read_timeout_s
        return await self._sensor(self.devices.ir.read(), "ir", "reading", timeout_s)

    async def _sensor(
        self, operation: Awaitable[_T], device: str, what: str, timeout_s: float
    ) -> _T:
        """Await a sensor's grab/read for at most ``timeout_s`` of wall time, else
        DeviceTimeoutError, and remember how it went (``sensor_states``): the daemon never
        waits forever on a sensor (issue 10). Wall time, as the robot's command timeout: a hung
        device or thread does not run on the bench's clock, and a virtual clock would jump a
        run-clock timeout forward at once."""
        try:
            try:
                async with asyncio.timeout(timeout_s) as scope:
                    result = await operation
            except TimeoutError as err:
                if not scope.expired():
                    raise  # the device's own timeout (a DeviceTimeoutError): as it is
                raise DeviceTimeoutError(device, f"no {what} within {timeout_s:g} s") from err
        except DeviceError as err:
            self.sensor_states[device] = f"{err.kind} error"
            raise
        self.sensor_states[device] = "ok"
        return result

    def _note_stale(self, device: str, what: str, age_s: float, errors: list[str]) -> None:
        """A stale frame/reading is a sensor error (SENSOR_ERROR_FLAGS): say how old it was."""
        err = DeviceError(device, f"stale {what}: {age_s:.3g} s old (limit {device}.max_age_s)")
        self.sensor_states[device] = "stale"
        self._note_error(err)
        errors.append(str(err))

    async def _measure(
        self,
        run: ActiveRun,
        *,
        point: ProcedurePoint,
        record: StepRecord,
        flags: list[str],
        errors: list[str],
        stages: dict[str, float],
    ) -> Frame | None:
        camera_settings = self.settings.camera
        started = time.perf_counter()
        frame: Frame | None = None
        try:
            frame = await self._grab()
        except DeviceError as err:
            self._note_error(err)
            flags.append("camera-error")
            errors.append(str(err))
        stages["frame"] = time.perf_counter() - started
        started = time.perf_counter()
        if frame is not None:
            age_s = self.clock.now() - frame.timestamp_s
            stale = age_s > camera_settings.max_age_s
            if stale:
                flags.append("stale-frame")
                self._note_stale("camera", "frame", age_s, errors)
            try:
                result = await asyncio.to_thread(
                    measure_with_camera_settings, frame.image, camera_settings
                )
            except CentroidError as err:
                flags.append("centroid-error")
                errors.append(f"centroid: {err}")
            else:
                record.centroid_x_px, record.centroid_y_px = result.x_px, result.y_px
                record.centroid_x_um, record.centroid_y_um = result.x_um, result.y_um
                if not stale:  # a stale frame is recorded and flagged, never used
                    reference = run.reference_um.setdefault(
                        point.pose_index, (result.x_um, result.y_um)
                    )
                    record.drift_x_um = result.x_um - reference[0]
                    record.drift_y_um = result.y_um - reference[1]
                    residual = (
                        record.drift_x_um * run.direction[0] + record.drift_y_um * run.direction[1]
                    )
                    record.residual_um = float(residual)
        stages["centroid"] = time.perf_counter() - started

        started = time.perf_counter()
        try:
            reading = await self._read_ir()
        except DeviceError as err:
            self._note_error(err)
            flags.append("ir-error")
            errors.append(str(err))
        else:
            age_s = self.clock.now() - reading.timestamp_s
            stale_ir = age_s > self.settings.ir.max_age_s
            if stale_ir:
                flags.append("stale-ir")
                self._note_stale("ir", "reading", age_s, errors)
            elif run.observer is not None:  # a stale reading is recorded, never fused
                innovation = run.observer.update(
                    {name: region.mean_c for name, region in reading.regions.items()}
                )
                if innovation is not None:
                    record.innovation_nis = innovation.nis
                if run.observer.drifting:
                    flags.append("model-drifting")
            record.ir_json = json.dumps(
                {
                    name: {"mean_c": region.mean_c, "max_c": region.max_c}
                    for name, region in reading.regions.items()
                }
            )
        stages["ir"] = time.perf_counter() - started
        return frame

    async def _finish(self, run: ActiveRun, final: RunState, reason: str | None) -> None:
        """Hold the robot, write the summary and the final state, publish it."""
        robot = self.devices.robot
        try:
            await robot.stop()  # stop holds the robot where it is (issue 6)
        except DeviceError as err:
            self._note_error(err)
            logger.warning("run %d: could not hold the robot at the end: %s", run.id, err)
        if run.state is not RunState.STOPPING and run.machine.can(RunState.STOPPING):
            await self._set_state(run, RunState.STOPPING, reason)
        try:
            run.summary = await self._db(self._summary, run)
        except RecorderError as err:
            self._note_error(err, device="storage")
        try:
            await self._db(self._recorder().finish_run, run.id, final.value, run.summary, reason)
        except RecorderError as err:
            self._note_error(err, device="storage")
            logger.error("run %d: cannot record its end: %s", run.id, err)
        if self.settings.storage.report_at_end and run.step >= 0:
            await self._write_report(run)  # part of stopping: the run ends with its report
        if run.machine.can(final):
            run.machine.go(final, reason)
        else:  # e.g. an error while starting: the state machine goes starting -> aborted
            run.machine.state, run.machine.reason = final, reason
        # the last thing the run task does: whoever sees the final state sees it ended
        self._publish_state(run)
        logger.info("run %d %s%s", run.id, final.value, f" ({reason})" if reason else "")

    async def _write_report(self, run: ActiveRun) -> None:
        """The run's report (issue 8) beside the database, where the API serves it from."""
        try:
            files = await asyncio.to_thread(
                write_run_report, self.settings.storage.data_dir, run.id
            )
        except Exception as err:  # a report is a convenience: its failure never fails a run
            logger.warning("run %d: no report: %s: %s", run.id, type(err).__name__, err)
            return
        run.report_path = files.html
        logger.info("run %d: report %s", run.id, files.html)

    def _summary(self, run: ActiveRun) -> dict[str, Any]:
        # the steps as series streamed from the database, never as one record object per
        # step: an hour at a 20 ms step is 180,000 steps (benchmarks/bench_run_end.py)
        steps = self._recorder().run_steps(run.id, SUMMARY_COLUMNS)
        summary: dict[str, Any] = dict(summarize_run(steps))
        timer = run.timer
        summary.update(
            {
                "steps": steps.n_steps,
                "deformation_scale": run.parameters.deformation_scale,
                "compensation": run.parameters.compensation,
                "step_s": run.parameters.step_s,
                "overruns": 0 if timer is None else timer.overruns,
                "skipped_deadlines": 0 if timer is None else timer.skipped,
                "reference": {
                    "source": run.reference_source,
                    "x_um": run.reference_um.get(0, (None, None))[0],
                    "y_um": run.reference_um.get(0, (None, None))[1],
                },
                "uncompensated_measured_max_um": self._measured_uncompensated_max_um(run, steps),
                "timing": {
                    **self.timing.summary(fresh=True),
                    # over every step of the run, not only the recent window
                    "lateness_s": percentiles(steps.numeric.get("lateness_s", ())),
                },
            }
        )
        return summary

    @staticmethod
    def _measured_uncompensated_max_um(run: ActiveRun, steps: RunSteps) -> float | None:
        """The largest drift the spot would have shown without the compensating moves: the
        measured residual less the robot's actual displacement from the goal along the link
        (issue 6 summary; stationary runs only, where the goal is the only pose)."""
        goal = run.goal
        if goal is None or run.parameters.procedure != "stationary" or steps.n_steps == 0:
            return None
        poses_mm = np.column_stack([steps.column(f"pose_{axis}_mm") for axis in "xyz"])
        displacement_um = 1000.0 * (poses_mm - np.asarray(goal.position)) @ run.direction
        values = steps.residual_um - displacement_um
        values = values[np.isfinite(values)]  # steps with no residual or no pose read back
        return float(np.abs(values).max()) if values.size else None

    # --- helpers -----------------------------------------------------------------------

    def _recorder(self) -> Recorder:
        if self.recorder is None:
            raise RuntimeError("the daemon is not started")
        return self.recorder

    def _active_run(self) -> ActiveRun:
        if self.run is None or not self.run.state.is_active:
            raise RunStateError("no active run")
        return self.run

    def _build_model(self, parameters: RunParameters) -> tuple[ThermalNetwork, ThermalModel]:
        try:
            network = load_network(parameters.network)
        except (ValueError, OSError) as err:
            raise RunParameterError(f"network {parameters.network!r}: {err}") from err
        model_settings = self.settings.model
        try:
            model = ThermalModel(
                network,
                stepper=model_settings.stepper,
                dt_s=parameters.step_s * parameters.time_scale,
                ambient_c=model_settings.ambient_c,
                reference_nodes=model_settings.reference_nodes,
                direction=model_settings.direction,
                allow_substeps=True,
            )
        except ValueError as err:
            raise RunParameterError(f"network {parameters.network!r}: {err}") from err
        return network, model

    def _build_observer(self, model: ThermalModel) -> IrObserver:
        """The IR Kalman filter of a model+ir run (issue 9): the regions tied to model nodes
        (configured, else the reader's own), each with the noise of its mean."""
        ir_settings = self.settings.ir
        regions = tuple(getattr(self.devices.ir, "regions", ()) or ir_settings.regions)
        tied = [region for region in regions if region.node]
        if not tied:
            raise RunParameterError("prediction model+ir needs IR regions tied to model nodes")
        noise = {r.name: ir_settings.noise_c / math.sqrt(r.width * r.height) for r in tied}
        return IrObserver(model, regions_to_nodes(tied), noise)

    def _check_scale(
        self, parameters: RunParameters, network: ThermalNetwork, direction: NDArray[np.float64]
    ) -> None:
        """DESIGN.md Scaling: the scaled deformation must stay on the camera chip."""
        largest = largest_predicted_deformation_um(self.settings, parameters, network)
        camera = self.settings.camera
        extent = (camera.width_px * camera.um_per_px[0], camera.height_px * camera.um_per_px[1])
        try:
            check_scale(
                parameters.deformation_scale,
                largest,
                direction.tolist(),
                extent,
                self.settings.compensation.spot_size_um,
            )
        except ValueError as err:
            raise RunParameterError(str(err)) from err

    async def _set_state(self, run: ActiveRun, state: RunState, reason: str | None) -> None:
        """Change state now (before any await, so no request can slip in between), publish
        it, then persist it; the single database thread keeps the writes in order."""
        run.machine.go(state, reason)
        if state is RunState.RUNNING:
            self.last_progress_monotonic = time.monotonic()  # a pause is not a hung loop
        self._publish_state(run)
        logger.info("run %d: %s%s", run.id, state.value, f" ({reason})" if reason else "")
        try:
            await self._db(self._recorder().set_run_state, run.id, state.value, reason)
        except RecorderError as err:
            self._note_error(err, device="storage")

    def _db(self, function: Callable[..., _T], *args: Any) -> asyncio.Future[_T]:
        """Run a recorder call on the one database thread: off the event loop, in order."""
        if self._db_executor is None:
            raise RuntimeError("the daemon is not started")
        return asyncio.get_running_loop().run_in_executor(self._db_executor, function, *args)

    async def _fault(self, run: ActiveRun, reason: str) -> None:
        """A device fault: hold motion, park the run in ``fault`` until an explicit resume."""
        with contextlib.suppress(DeviceError):
            await self.devices.robot.stop()
        if run.machine.can(RunState.FAULT):
            await self._set_state(run, RunState.FAULT, reason)

    def _note_error(self, err: BaseException, device: str | None = None) -> None:
        entry = ErrorEntry(
            time.time(),
            str(device or getattr(err, "device", "daemon")),
            getattr(err, "kind", type(err).__name__),
            str(err),
        )
        self.errors.append(entry)
        self._publish(Event("error", entry.as_dict()))

    def _publish_state(self, run: ActiveRun) -> None:
        self._publish(
            Event(
                "state", {"run_id": run.id, "state": run.state.value, "reason": run.machine.reason}
            )
        )

    def _publish(self, event: Event) -> None:
        for subscription in list(self._subscriptions):
            subscription.put(event)


def largest_predicted_deformation_um(
    settings: Settings, parameters: RunParameters, network: ThermalNetwork, samples: int = 400
) -> float:
    """The largest |deformation| the model predicts over the run (for the scale check)."""
    model = ThermalModel(
        network,
        stepper="exact" if network.node_count <= EXACT_NODE_LIMIT else "implicit",
        dt_s=parameters.duration_s * parameters.time_scale / samples,
        ambient_c=settings.model.ambient_c,
        reference_nodes=settings.model.reference_nodes,
    )
    largest = 0.0
    for k in range(1, samples + 1):
        run_time = parameters.duration_s * k / samples
        model.set_heat(heat_at(parameters, run_time - parameters.duration_s / samples))
        model.advance_to(run_time * parameters.time_scale)
        largest = max(largest, abs(float(model.deformation_um_scalar())))
    return largest


def _network_snapshot(network: ThermalNetwork) -> dict[str, Any]:
    return {
        "name": network.name,
        "node_names": list(network.node_names),
        "positions_mm": network.positions_mm.tolist(),
        "capacitance_j_per_c": network.capacitance_j_per_c.tolist(),
        "alpha_per_c": network.alpha_per_c.tolist(),
        "r_ambient_c_per_w": [_finite_or_none(v) for v in network.r_ambient_c_per_w.tolist()],
        "r_end_c_per_w": [_finite_or_none(v) for v in network.r_end_c_per_w.tolist()],
        "resistances": [[r.a, r.b, r.r_c_per_w] for r in network.resistances],
        "reference_nodes": list(network.reference_nodes),
        "heater_nodes": list(network.heater_nodes),
        "direction": network.direction.tolist(),
    }


def _finite_or_none(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _unit(vector: tuple[float, float, float]) -> NDArray[np.float64]:
    array = np.asarray(vector, dtype=np.float64)
    norm = float(np.linalg.norm(array))
    if not math.isfinite(norm) or norm == 0:
        raise RunParameterError(f"model.direction must be a non-zero vector, not {vector}")
    return array / norm


def _vector3(array: NDArray[np.float64]) -> tuple[float, float, float]:
    return (float(array[0]), float(array[1]), float(array[2]))


@contextlib.asynccontextmanager
async def _default_opener(settings: Settings, clock: Clock) -> AsyncIterator[Devices]:
    from drivers.factory import open_devices

    async with open_devices(settings, clock) as devices:
        yield devices
