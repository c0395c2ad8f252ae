"""``thermocomp serve``: run the daemon and its API under uvicorn until a signal stops it
(the command line is api/serve_cli.py, which imports this module only when it runs)."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import socket
import sys
from collections.abc import Callable
from types import FrameType

import uvicorn
from fastapi import FastAPI
from pydantic import ValidationError

from api.app import create_app
from api.connections import guarded_protocol
from api.deps import ApiContext
from api.startup import (
    StartupError,
    dashboard_banner,
    limit_repeated_logs,
    preflight,
    with_local_control_token,
)
from config import ConfigError, Settings, load_settings
from daemon.heap import freeze_startup_heap
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


def server_config(settings: Settings, app: FastAPI | None = None) -> uvicorn.Config:
    """The uvicorn configuration of the daemon's server: the application's lifespan opens the
    daemon (devices, recording) at startup and closes it at shutdown (robot held, recording
    committed), so the server is "up" only with the daemon."""
    return uvicorn.Config(
        create_app(settings, service_factory=Daemon) if app is None else app,
        host=settings.api.host,
        port=settings.api.port,
        log_config=None,  # logging is configured once, by the entry point
        access_log=False,  # step data goes to the recording, not the log
        lifespan="on",  # a daemon that cannot start fails the server's startup
        # the protocol layer refuses larger client messages before buffering them
        ws_max_size=settings.api.ws_max_message_bytes,
        # compressing every step message once per client costs the shared event loop more
        # than the lab network saves (50 clients: milliseconds per step)
        ws_per_message_deflate=False,
        timeout_graceful_shutdown=10,
        # bounded connections (issue 16; api/connections.py says what uvicorn lacks): 503
        # beyond max_connections, closed on accept a little beyond, a request must arrive
        # whole within request_timeout_s, an idle keep-alive connection closes after 5 s
        http=guarded_protocol(settings.api.max_connections, settings.api.request_timeout_s),
        limit_concurrency=settings.api.max_connections,
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
    banner: Callable[[int], str] | None = None,
) -> None:
    """Tell systemd what the service does (issue 10, deploy/thermocomp.service).

    READY=1 only once uvicorn's lifespan has opened the daemon (devices, recording) AND the
    socket listens (``server.started``); WATCHDOG=1 only while the control loop makes
    progress (``Daemon.control_loop_alive``), so a hung loop -- or a blocked event loop, on
    which this task runs too -- gets the service restarted after WatchdogSec; STOPPING=1 as
    soon as a signal asks the server to exit, before the daemon holds the robot and commits.
    ``device_allowance_s`` is how long one step may legitimately wait on a device before it
    fails (a timed-out move is a fault the run reports, not a hung loop).
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
    while not server.should_exit:
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


def _bound_port(server: uvicorn.Server) -> int:
    """The port the server listens on (api.port, or the one chosen for port 0)."""
    for listener in getattr(server, "servers", ()):
        for sock in listener.sockets:
            port: int = sock.getsockname()[1]
            return port
    return server.config.port


class DaemonServer(uvicorn.Server):
    """uvicorn's server with the shutdown order of a machine that moves (issue 15, point 3).

    uvicorn alone would keep the daemon driving the robot while HTTP connections drain (up to
    ``timeout_graceful_shutdown``) and stop it only in the application's lifespan shutdown,
    which a second Ctrl-C (a forced exit) skips. Here every signal holds the robot at once,
    the first also ends the run (``stopped``, "daemon shut down", committed), and the
    connections drain only after that; on a forced exit the lifespan shutdown (devices and
    database closed) still runs. Signals stay uvicorn's: this only adds to its handler.
    """

    def __init__(self, config: uvicorn.Config, context: ApiContext) -> None:
        super().__init__(config)
        self._context = context
        self._loop: asyncio.AbstractEventLoop | None = None
        self._daemon_stopping: asyncio.Task[None] | None = None

    async def serve(self, sockets: list[socket.socket] | None = None) -> None:
        self._loop = asyncio.get_running_loop()
        await super().serve(sockets)

    async def startup(self, sockets: list[socket.socket] | None = None) -> None:
        try:
            await super().startup(sockets)  # the lifespan: the daemon and its devices are open
        except SystemExit:  # uvicorn's 3 for any failed start; a bad file asks for 2
            status = self._context.start_failure_status
            if status is None:
                raise
            raise SystemExit(status) from None
        # Before any step: a full collection of the start-up heap stops the loop 10-15 ms,
        # the one cause of the fast path's overruns at a 20 ms step (daemon/heap.py).
        freeze_startup_heap()

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        super().handle_exit(sig, frame)
        if self._loop is not None:  # a signal handler may only schedule, thread-safely
            self._loop.call_soon_threadsafe(self._stop_daemon)

    def _stop_daemon(self) -> None:
        daemon = self._context.service
        if daemon is None or self._loop is None:
            return
        self._loop.create_task(_hold(daemon), name="hold-on-signal")
        if self._daemon_stopping is None:
            self._daemon_stopping = self._loop.create_task(daemon.shutdown(), name="daemon-stop")

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        self._stop_daemon()  # also when the exit was not a signal
        if self._daemon_stopping is not None:
            try:
                await self._daemon_stopping
            except Exception:  # the lifespan shutdown below still closes everything
                logger.exception("stopping the daemon failed")
        await super().shutdown(sockets)
        if self.force_exit:  # uvicorn skips the lifespan shutdown on a forced exit
            await self.lifespan.shutdown()


async def _hold(daemon: Daemon) -> None:
    try:
        await daemon.hold_robot("daemon shutting down", pause=False)
    except DeviceError as err:  # e.g. the link is down: nothing can be sent anyway
        logger.warning("could not hold the robot on the signal: %s", err)


async def serve(
    settings: Settings, notifier: SystemdNotifier, generated_token: str | None = None
) -> bool:
    """Run the server until a signal stops it; True when it had started. Once it serves, the
    dashboard's address is printed (with ``generated_token`` when the token was made for
    this loopback server, api/startup.py)."""
    app = create_app(settings, service_factory=Daemon)
    context: ApiContext = app.state.context
    server = DaemonServer(server_config(settings, app), context)
    # the longest a step waits on the robot before it fails: a move, then the pose read
    allowance_s = settings.robot.move_timeout_s + settings.robot.command_timeout_s
    supervisor = asyncio.create_task(
        supervise(
            server,
            context,
            notifier,
            allowance_s,
            banner=lambda port: dashboard_banner(settings, port, generated_token),
        ),
        name="systemd",
    )
    try:
        await server.serve()  # uvicorn handles SIGINT/SIGTERM and shuts down cleanly
    finally:
        server.should_exit = True  # lets the supervisor send STOPPING=1 if it has not yet
        await supervisor
    return server.started


def _stopped_by_signal(signum: int, frame: FrameType | None) -> None:
    """Replaces the default SIGTERM action while serving: uvicorn re-raises the signal that
    stopped it once it has shut down, which would kill the process AFTER the clean shutdown
    and turn systemd's ordinary stop into a failure (status -15 instead of 0)."""
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
    finally:
        signal.signal(signal.SIGTERM, previous)
    if not started:  # the daemon or the socket could not be opened (logged above)
        notifier.status("failed to start")
        return 1
    return 0
