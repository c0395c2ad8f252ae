"""``thermocomp serve``: run the daemon and its API under uvicorn until a signal stops it
(the command line is api/serve_cli.py, which imports this module only when it runs).

uvicorn is used through its public surface only (issue 27): ``Config`` (with the connection
guard as its ``http`` protocol class, api/connections.py), ``Server.serve()``, and the
``started`` / ``should_exit`` / ``force_exit`` attributes its documentation uses to run and
stop a server from code. Nothing of it is subclassed or overridden, so a uvicorn release
within the locked range cannot silently undo the shutdown order or the connection bounds.
What the old ``Server`` subclass did is done here, at the entry point:

- the daemon is opened before the server listens and closed after it has stopped, by this
  module (not by uvicorn's lifespan, which a forced exit skips): devices and database are
  closed on every exit;
- the signals, once the server is up, are this module's (:class:`SignalStop`): the first
  holds the robot at once, ends the run (``stopped``, "daemon shut down", committed), and only
  then lets uvicorn drain its connections; a second skips that drain (uvicorn's forced exit);
  a third leaves at once;
- the start-up heap is frozen once the daemon is open, before the first step (daemon/heap.py).
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from collections.abc import Callable, Coroutine
from contextlib import AsyncExitStack
from types import FrameType
from typing import Any

import uvicorn
from fastapi import FastAPI
from pydantic import ValidationError

from api.app import DaemonStartFailed, create_app, open_service, serving
from api.connections import LISTEN_BACKLOG, ConnectionGuard
from api.deps import ApiContext, grants_control, holds_robot
from api.startup import (
    StartupError,
    dashboard_banner,
    limit_repeated_logs,
    preflight,
    with_local_control_token,
)
from config import ConfigError, Settings, load_settings
from daemon.heap import freeze_startup_heap, lock_memory, log_memory_lock
from daemon.service import Daemon
from daemon.systemd import SystemdNotifier
from drivers.errors import DeviceError

logger = logging.getLogger(__name__)


def with_address(settings: Settings, host: str | None, port: int | None) -> Settings:
    """``settings`` with the command line's --host/--port applied over the file's."""
    update: dict[str, object] = {}
    if host is not None:
        update["host"] = host
    if port is not None:
        update["port"] = port
    if not update:
        return settings
    try:
        api = settings.api.model_validate({**settings.api.model_dump(), **update})
    except ValidationError as err:
        reasons = "; ".join(f"--{e['loc'][0]}: {e['msg']}" for e in err.errors())
        raise ConfigError(f"command line: {reasons}") from err
    return settings.model_copy(update={"api": api})


#: An idle keep-alive connection is closed after this long (s): a browser polling /state
#: every second keeps its connection, an abandoned one frees its descriptor.
KEEP_ALIVE_S = 5

#: How often the supervisor looks at the server and the daemon (startup, shutdown, STATUS).
SUPERVISOR_POLL_S = 0.1


def connection_guard(
    settings: Settings, context: ApiContext, http: str = "auto"
) -> ConnectionGuard:
    """The server's connection bounds (api/connections.py): at most ``api.max_connections``
    served, requests whole within ``api.request_timeout_s``, and beyond the cap only requests
    that hold the robot, with a control token of this application. ``http`` names uvicorn's
    HTTP implementation behind the guard ("auto": httptools, else h11)."""

    def admits_hold(method: str, path: str, authorization: str | None) -> bool:
        return holds_robot(method, path) and grants_control(context, authorization)

    return ConnectionGuard(
        settings.api.max_connections, settings.api.request_timeout_s, admits_hold, http=http
    )


def server_config(settings: Settings, app: FastAPI, guard: ConnectionGuard) -> uvicorn.Config:
    """The uvicorn configuration of the daemon's server. The daemon is not uvicorn's to open
    or close (``lifespan="off"``): :func:`serve` opens it before the server listens and
    closes it after the server has stopped."""
    return uvicorn.Config(
        app,
        host=settings.api.host,
        port=settings.api.port,
        log_config=None,  # logging is configured once, by the entry point
        access_log=False,  # step data goes to the recording, not the log
        lifespan="off",
        # the protocol layer refuses larger client messages before buffering them
        ws_max_size=settings.api.ws_max_message_bytes,
        # compressing every step message once per client costs the shared event loop more
        # than the lab network saves (50 clients: milliseconds per step)
        ws_per_message_deflate=False,
        timeout_graceful_shutdown=10,
        # bounded connections (issues 16, 26; api/connections.py): the guard wraps uvicorn's
        # own HTTP protocol, so uvicorn's limit_concurrency (whose 503 would meet the hold
        # too) is not used; an idle keep-alive connection closes after 5 s
        http=guard.protocol,
        backlog=LISTEN_BACKLOG,
        timeout_keep_alive=KEEP_ALIVE_S,
    )


def daemon_status(daemon: Daemon) -> str:
    """One line for ``systemctl status``: the run and its state (with its reason when paused
    or faulted), or idle. No step number: it would send systemd a message per poll."""
    run = daemon.run
    if run is None or not run.is_active:
        return "idle"
    status = f"run {run.id} {run.state.value}"
    reason = run.reason
    return f"{status}: {reason}" if reason and run.state.value in ("paused", "fault") else status


async def supervise(
    server: uvicorn.Server,
    context: ApiContext,
    notifier: SystemdNotifier,
    device_allowance_s: float = 0.0,
    stopping: Callable[[], bool] = lambda: False,
    *,
    banner: Callable[[int], str] | None = None,
) -> None:
    """Tell systemd what the service does (issue 10, deploy/thermocomp.service).

    READY=1 only once the daemon is open (devices, recording) AND the socket listens
    (``server.started``); WATCHDOG=1 only while the control loop makes progress
    (``Daemon.control_loop_alive``), so a hung loop -- or a blocked event loop, on which this
    task runs too -- gets the service restarted after WatchdogSec; STOPPING=1 as soon as a
    signal asks the service to stop (``stopping()``) or the server exits, before the daemon
    holds the robot and commits. ``device_allowance_s`` is how long one step may
    legitimately wait on a device before it fails (a timed-out move is a fault the run
    reports, not a hung loop).
    """
    while not server.started:
        if server.should_exit:
            return
        await asyncio.sleep(SUPERVISOR_POLL_S)
    if banner is not None:  # the dashboard's address, on stdout whatever the log level
        print(banner(_bound_port(server)), flush=True)
    daemon = context.service
    if daemon is None:  # cannot happen with a service factory; say so rather than lie
        notifier.status("started without a daemon")
        return
    notifier.ready(f"serving; {daemon_status(daemon)}")
    interval_s = notifier.watchdog_interval_s
    loop = asyncio.get_running_loop()
    next_keepalive = loop.time()
    status = ""
    while not (server.should_exit or stopping()):
        now = loop.time()
        if interval_s is not None and now >= next_keepalive:
            # half of WatchdogSec without a step beyond the device timeouts (and one step
            # period, added by control_loop_alive) is a hang: systemd restarts us WatchdogSec
            # after the last keep-alive
            if daemon.control_loop_alive(max_silence_s=interval_s + device_allowance_s):
                notifier.watchdog()
            else:
                logger.error(
                    "control loop silent for over %.1f s: no watchdog keep-alive",
                    interval_s + device_allowance_s,
                )
            next_keepalive = now + interval_s
        current = daemon_status(daemon)
        if current != status:
            notifier.status(current)
            status = current
        await asyncio.sleep(SUPERVISOR_POLL_S)
    notifier.stopping()


#: How often :func:`serve` looks whether uvicorn has started, to take the signals over.
SIGNAL_TAKEOVER_POLL_S = 0.01


class SignalStop:
    """SIGINT and SIGTERM while the server runs (issue 15, point 3: a machine that moves).

    uvicorn alone would keep the daemon driving the robot while HTTP connections drain (up to
    ``timeout_graceful_shutdown``). Here the first signal holds the robot at once and ends the
    run (``Daemon.shutdown``: hold first, then ``stopped``, committed), and only then asks
    uvicorn to exit, which drains the connections; a second signal makes that exit skip the
    drain (uvicorn's forced exit, like its second Ctrl-C) and holds again; a third exits now.

    Installed once uvicorn has started (:meth:`take_over`: uvicorn installs its own handlers
    when it begins to serve), again once it has stopped (it restores the ones it found),
    until the daemon is closed (:meth:`restore`).
    """

    def __init__(self, server: uvicorn.Server, daemon: Daemon) -> None:
        self._server = server
        self._daemon = daemon
        self._loop = asyncio.get_running_loop()
        self._signals = 0
        self._tasks: set[asyncio.Task[None]] = set()
        self._stopping: asyncio.Task[None] | None = None
        self._previous: dict[int, Any] = {}

    @property
    def requested(self) -> bool:
        return self._signals > 0

    async def take_over(self) -> None:
        """Replace uvicorn's signal handlers once it has installed them (it has, once it has
        started); return without doing so if it exits first."""
        while not self._server.started:
            if self._server.should_exit:
                return
            await asyncio.sleep(SIGNAL_TAKEOVER_POLL_S)
        self.install()

    def install(self) -> None:
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous = signal.signal(signum, self._on_signal)
            self._previous.setdefault(signum, previous)

    def restore(self) -> None:
        """Put back the handlers found at the first :meth:`install`."""
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)
        self._previous.clear()

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        # a signal handler runs between two bytecodes of whatever the loop was doing: it may
        # only schedule, thread-safely
        self._loop.call_soon_threadsafe(self.stop, signum)

    def stop(self, signum: int) -> None:
        self._signals += 1
        logger.info("%s: holding the robot and stopping", signal.Signals(signum).name)
        self._spawn(_hold(self._daemon), "hold-on-signal")
        if self._stopping is None:
            self._stopping = self._spawn(self._stop_daemon(), "daemon-stop")
        elif self._signals == 2:
            self._server.force_exit = True  # the exit, once the run has ended, skips the drain
        else:
            self._server.should_exit = True

    async def _stop_daemon(self) -> None:
        try:
            await self._daemon.shutdown()
        except Exception:  # the daemon is closed by serve() all the same
            logger.exception("stopping the daemon failed")
        finally:
            self._server.should_exit = True

    def _spawn(self, coroutine: Coroutine[Any, Any, None], name: str) -> asyncio.Task[None]:
        task = self._loop.create_task(coroutine, name=name)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    async def finished(self) -> None:
        """Wait for what the signals started (the hold, the run's end)."""
        while self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)


async def _hold(daemon: Daemon) -> None:
    try:
        await daemon.hold_robot("daemon shutting down", pause=False)
    except DeviceError as err:  # e.g. the link is down: nothing can be sent anyway
        logger.warning("could not hold the robot on the signal: %s", err)


def _bound_port(server: uvicorn.Server) -> int:
    """The port the server listens on (api.port, or the one chosen for port 0). uvicorn keeps
    its listeners in ``Server.servers`` once started; should that ever go, api.port is the
    answer but for port 0 (tests), which then prints 0 rather than failing."""
    for listener in getattr(server, "servers", ()):
        for sock in listener.sockets:
            port: int = sock.getsockname()[1]
            return port
    return server.config.port


async def serve(
    settings: Settings, notifier: SystemdNotifier, generated_token: str | None = None
) -> bool:
    """Run the server until a signal stops it; True when it had started. Raises
    :class:`DaemonStartFailed` when the daemon cannot be opened (logged in one line). Once it
    serves, the dashboard's address is printed (with ``generated_token`` when the token was
    made for this loopback server, api/startup.py)."""
    app = create_app(settings)
    context: ApiContext = app.state.context
    guard = connection_guard(settings, context)
    server = uvicorn.Server(server_config(settings, app, guard))
    # the longest a step waits on the robot before it fails: a move, then the pose read
    allowance_s = settings.robot.move_timeout_s + settings.robot.command_timeout_s
    async with AsyncExitStack() as stack:  # closes the daemon last, whatever happened
        daemon = await open_service(stack, settings, Daemon)
        await stack.enter_async_context(serving(context, daemon))
        # Before any step: a full collection of the start-up heap stops the loop 10-15 ms,
        # the one cause of the fast path's overruns at a 20 ms step (daemon/heap.py).
        freeze_startup_heap()
        daemon.gc_policy.watch.reset()  # the collections from here on: the daemon's own
        if settings.scheduler.lock_memory:  # no step waits for a page from swap
            log_memory_lock(lock_memory())
        signals = SignalStop(server, daemon)
        takeover = asyncio.create_task(signals.take_over(), name="signals")
        supervisor = asyncio.create_task(
            supervise(
                server,
                context,
                notifier,
                allowance_s,
                lambda: signals.requested,
                banner=lambda port: dashboard_banner(settings, port, generated_token),
            ),
            name="systemd",
        )
        stack.callback(signals.restore)  # after the daemon has closed
        try:
            await server.serve()
        finally:
            signals.install()  # uvicorn has put back what it found: ours until the end
            server.should_exit = True  # lets the supervisor send STOPPING=1 if it has not yet
            takeover.cancel()
            await asyncio.gather(takeover, supervisor, return_exceptions=True)
            guard.close()  # connections still without a request: not uvicorn's to close
            await signals.finished()
    logger.info("daemon closed: robot held, recording committed, devices released")
    return server.started


def _stopped_by_signal(signum: int, frame: FrameType | None) -> None:
    """Replaces the default SIGTERM action while serving: a signal that reaches uvicorn's
    handler (during its start-up, before :class:`SignalStop` takes over) is re-raised by
    uvicorn once it has shut down, which would kill the process AFTER the clean shutdown and
    turn systemd's ordinary stop into a failure (status -15 instead of 0)."""
    logger.info("stopped by %s", signal.Signals(signum).name)


#: The GIL switch interval while serving (s); see run().
GIL_SWITCH_INTERVAL_S = 0.0005


def run(args: argparse.Namespace) -> int:
    settings = with_address(load_settings(args.config), args.host, args.port)
    if getattr(args, "data_dir", None) is not None:  # --data-dir (issue 28)
        storage = settings.storage.model_copy(update={"data_dir": args.data_dir})
        settings = settings.model_copy(update={"storage": storage})
    notifier = SystemdNotifier()
    try:
        preflight(settings)  # binding, descriptors, devices, port, database: one line each
        # on loopback without a configured token: the data directory's (made on first start)
        settings, generated_token = with_local_control_token(settings)
    except StartupError as err:
        print(f"thermocomp serve: {err}", file=sys.stderr)
        notifier.status(f"failed to start: {err}")
        return err.status
    limit_repeated_logs()  # "serving on ..." is logged once the daemon is up (api/app.py)
    # the control loop runs on this process's event loop: a worker thread holding the GIL
    # (an API read, the export pool's result reader) must hand it back within this, not
    # CPython's default 5 ms, for the next step to begin on time (issue 15)
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    previous = signal.signal(signal.SIGTERM, _stopped_by_signal)
    try:
        started = asyncio.run(serve(settings, notifier, generated_token))
    except DaemonStartFailed as err:  # logged in one line by api/app.py
        # 3 for a device, 2 for a file or name of the settings (never retried by systemd)
        notifier.status(f"failed to start: {err}")
        return err.status
    finally:
        signal.signal(signal.SIGTERM, previous)
    if not started:  # the daemon or the socket could not be opened (logged above)
        notifier.status("failed to start")
        return 1
    return 0
