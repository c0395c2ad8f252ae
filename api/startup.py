"""``thermocomp serve``'s checks before anything is served: the binding is safe, the port is
free, the data directory and its database are usable, the devices are there, enough file
descriptors. Each failure is one line naming the thing and what to do, and an exit status of
its own (docs/reference/cli.md; deploy/thermocomp.service restarts on 3-5 with a back-off,
never on 2):

- 2 (``EXIT_USAGE``): invalid configuration, including an API reachable from the network
  without a control token;
- 3 (``EXIT_DEVICE``): a device is absent or cannot be opened (it may be plugged in later);
  uvicorn exits with 3 too when the daemon cannot open a device that is there (api/app.py);
- 4 (``EXIT_STORAGE``): the data directory or the run database cannot be used (unwritable,
  read-only, in use by another process);
- 5 (``EXIT_ADDRESS``): the address and port cannot be bound (in use, not on this machine).
"""

from __future__ import annotations

import errno
import logging
import os
import resource
import socket
import time
from collections.abc import Callable
from pathlib import Path

from api.connections import ACCEPT_MARGIN
from api.security import (
    CONTROL_TOKEN_FILE,
    TokenFileError,
    dashboard_url,
    is_loopback,
    local_control_token,
)
from config import Settings
from config.cli import EXIT_ADDRESS, EXIT_DEVICE, EXIT_STORAGE, EXIT_USAGE
from config.inputs import InputError, one_line
from daemon.storage.recorder import Recorder, RecorderError

logger = logging.getLogger(__name__)

#: Descriptors besides the connections: database and WAL (two connections), lock file,
#: serial port or pty pair, cameras, log, pipes, Python's own; generous.
RESERVED_FILES = 128


class StartupError(Exception):
    """A check failed: ``str()`` is the one line for the user, ``status`` the exit status."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def check_binding(settings: Settings) -> None:
    """An API reachable from other machines needs a control token, or an explicit choice of
    anonymous reads: otherwise every request but /health would be a 401 nobody explained."""
    api = settings.api
    if is_loopback(api.host) or api.control_token or api.anonymous_read is True:
        return
    raise StartupError(
        EXIT_USAGE,
        f"api.host {api.host} is reachable from other machines but no api.control_token is "
        "set: set one (THERMOCOMP_API__CONTROL_TOKEN=<long random secret>, e.g. in "
        "/etc/thermocomp/env), or set api.anonymous_read = true to serve anonymous reads "
        "without control, or bind to 127.0.0.1",
    )


def with_local_control_token(settings: Settings) -> tuple[Settings, str | None]:
    """``settings`` with the data directory's control token when bound to loopback without a
    configured one (api/security.py says why), and that token; else unchanged and None. A
    configured token always wins; a server reachable from other machines never gets one made
    (check_binding refuses it, or it serves anonymous reads only)."""
    api = settings.api
    if api.control_token or not is_loopback(api.host):
        return settings, None
    data_dir = settings.storage.data_dir
    try:
        token = local_control_token(data_dir)
    except TokenFileError as err:
        raise StartupError(EXIT_STORAGE, str(err)) from err
    updated = api.model_copy(update={"control_token": token})
    return settings.model_copy(update={"api": updated}), token


def dashboard_banner(settings: Settings, port: int, generated_token: str | None) -> str:
    """What ``thermocomp serve`` prints once it serves: where the dashboard is and how it
    gets control. The generated token is printed in the address (its file is 0600 and only
    this user's, like the terminal); a configured one never is (it may be a shared secret)."""
    api = settings.api
    if generated_token is not None:
        token_file = settings.storage.data_dir / CONTROL_TOKEN_FILE
        return (
            f"dashboard (control): {dashboard_url(api.host, port, generated_token)}\n"
            f"  the control token is kept in {token_file}; open this address (it keeps the "
            "token), or send it as `Authorization: Bearer <token>`"
        )
    url = dashboard_url(api.host, port)
    if api.control_token:
        return f"dashboard: {url} (control with the configured api.control_token)"
    return f"dashboard: {url} (read-only: no api.control_token is set)"


def check_address(host: str, port: int) -> None:
    """Bind the address once (as uvicorn will, SO_REUSEADDR) and let it go."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise StartupError(
            EXIT_USAGE, f"api.host {host}: not an address of this machine ({err.strerror})"
        ) from err
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind(address)
        except OSError as err:
            where = f"{host}:{port}"
            if err.errno == errno.EADDRINUSE:
                message = (
                    f"port {port} on {host} is in use by another process: stop it "
                    f"(ss -ltnp 'sport = :{port}' shows it) or choose another port with "
                    "--port or api.port"
                )
            elif err.errno == errno.EACCES:
                message = f"{where}: permission denied: use a port above 1023 (--port)"
            elif err.errno == errno.EADDRNOTAVAIL:
                message = (
                    f"api.host {host} is not an address of this machine: use 127.0.0.1, "
                    "0.0.0.0 or one of its addresses (--host)"
                )
            else:
                message = f"cannot listen on {where}: {err.strerror}"
            raise StartupError(EXIT_ADDRESS, message) from err


def check_storage(data_dir: Path) -> None:
    """Open the run database once (created if new; migrations and the claim on the folder
    included), then close it for the daemon to open."""
    try:
        Recorder(data_dir).close()
    except RecorderError as err:
        raise StartupError(EXIT_STORAGE, storage_message(err, data_dir)) from err


def storage_message(err: RecorderError, data_dir: Path) -> str:
    text = str(err)
    if "in use by" in text:
        return text
    return (
        f"{text}: make {data_dir} and its database writable by user {_user()}, or choose "
        "another folder (storage.data_dir, THERMOCOMP_STORAGE__DATA_DIR)"
    )


def _user() -> str:
    try:
        import pwd

        return pwd.getpwuid(os.getuid()).pw_name
    except (ImportError, KeyError):
        return str(os.getuid())


def _video_path(device: int | str) -> Path | None:
    """The V4L2 node an OpenCV device names, when it names one (an index or a /dev path);
    None for a URL or a pattern, which only opening can check."""
    if isinstance(device, int) or (isinstance(device, str) and device.isdigit()):
        return Path(f"/dev/video{int(device)}")
    if isinstance(device, str) and device.startswith("/dev/"):
        return Path(device)
    return None


def _check_device_node(path: Path, what: str, fix: str) -> None:
    if not path.exists():
        raise StartupError(EXIT_DEVICE, f"{what} {path}: no such device: {fix}")
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except PermissionError as err:
        raise StartupError(
            EXIT_DEVICE,
            f"{what} {path}: permission denied for user {_user()}: add it to the group "
            f"owning {path} (dialout for serial ports, video for cameras)",
        ) from err
    except OSError as err:
        raise StartupError(
            EXIT_DEVICE, f"{what} {path}: cannot open ({err.strerror}): {fix}"
        ) from err
    os.close(fd)


def check_devices(settings: Settings) -> None:
    """What can be checked without talking to the devices: they exist and can be opened."""
    simulated = [
        f"{name}.driver"
        for name, driver in (
            ("camera", settings.camera.driver),
            ("ir", settings.ir.driver),
            ("robot", settings.robot.driver),
        )
        if driver == "sim"
    ]
    if simulated and not settings.bench.enabled:
        raise StartupError(
            EXIT_USAGE,
            f"bench.enabled is false but {', '.join(simulated)} is 'sim': choose real "
            "drivers or enable the bench",
        )
    robot = settings.robot
    if robot.driver == "c500c" and "://" not in robot.port:
        _check_device_node(
            Path(robot.port),
            "robot.port",
            "connect the controller's serial adapter or set robot.port "
            "(e.g. /dev/ttyUSB0, socket://host:port)",
        )
    for name, section in (("camera", settings.camera), ("ir", settings.ir)):
        if section.driver == "opencv":
            node = _video_path(section.device)
            if node is not None:
                _check_device_node(
                    node,
                    f"{name}.device",
                    f"plug the {'camera' if name == 'camera' else 'IR camera'} in or set "
                    f"{name}.device (v4l2-ctl --list-devices lists them)",
                )
        elif section.driver == "replay":
            folder = section.replay_dir
            if folder is None or not folder.is_dir():
                raise StartupError(
                    EXIT_USAGE,
                    f"{name}.replay_dir {folder}: no such folder: set it to the folder of "
                    "recorded frames",
                )


def check_open_files(settings: Settings) -> None:
    """Enough descriptors for every connection the server accepts (api.max_connections plus
    the margin) and the rest: raise the soft limit up to the hard one if needed, so accept()
    never fails with EMFILE (which floods the journal)."""
    needed = settings.api.max_connections + ACCEPT_MARGIN + RESERVED_FILES
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY or soft >= needed:
        return
    if hard != resource.RLIM_INFINITY and hard < needed:
        raise StartupError(
            EXIT_USAGE,
            f"api.max_connections {settings.api.max_connections} needs {needed} open files "
            f"but the limit is {hard}: lower api.max_connections or raise the limit "
            "(LimitNOFILE= in the unit, ulimit -n)",
        )
    resource.setrlimit(resource.RLIMIT_NOFILE, (needed, hard))


def check_files(settings: Settings) -> None:
    """Every file and name the settings give loads (network, arm, duty cycle, cameras): a
    mistake there is a configuration error, exit 2 -- never 3, which systemd retries forever
    (issues 26 and 28); the daemon's start would otherwise meet it deep inside."""
    from daemon.run.inputs import check_inputs  # lazy: the model stack, only to check files

    try:
        check_inputs(settings)
    except InputError as err:
        raise StartupError(EXIT_USAGE, one_line(err)) from err


def preflight(settings: Settings) -> None:
    """Every check, configuration first, then the cheapest; raises :class:`StartupError`."""
    check_binding(settings)
    check_files(settings)
    check_open_files(settings)
    check_devices(settings)
    check_address(settings.api.host, settings.api.port)
    check_storage(settings.storage.data_dir)


class RepeatFilter(logging.Filter):
    """Lets one record per message template through every ``interval_s``, then says how many
    it held back: a storm of identical errors (accept() failures, 503s beyond the concurrency
    limit) costs the journal one line per interval, not megabytes."""

    def __init__(
        self, interval_s: float = 10.0, clock: Callable[[], float] = time.monotonic
    ) -> None:
        super().__init__()
        self.interval_s = interval_s
        self._clock = clock
        self._seen: dict[str, tuple[float, int]] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        key = str(record.msg)
        now = self._clock()
        last, held = self._seen.get(key, (-self.interval_s, 0))
        if now - last < self.interval_s:
            self._seen[key] = (last, held + 1)
            return False
        if held:
            record.msg = f"{record.msg} (and {held} more like it in {self.interval_s:g} s)"
        self._seen[key] = (now, 0)
        if len(self._seen) > 1000:
            self._seen.clear()
        return True


class ReportedStartFailure(logging.Filter):
    """Drops uvicorn's traceback of a daemon start failure api/app.py already logged in one
    line (uvicorn logs the lifespan's traceback text whatever the application does)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "DaemonStartFailed" not in record.getMessage()


def limit_repeated_logs() -> None:
    """Install :class:`RepeatFilter` on the loggers a connection storm writes to, and
    :class:`ReportedStartFailure` on uvicorn's."""
    for name in ("asyncio", "uvicorn.error", "api.connections"):
        logging.getLogger(name).addFilter(RepeatFilter())
    logging.getLogger("uvicorn.error").addFilter(ReportedStartFailure())
