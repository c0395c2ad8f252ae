"""systemd's notification protocol (sd_notify), without a C library.

Under ``Type=notify`` systemd waits for ``READY=1`` before it calls the service started, and
with ``WatchdogSec=`` it restarts a service that stops sending ``WATCHDOG=1``. Keep-alives must
come from the control loop's own health, so that a hung loop stops them (issue 10).
Outside systemd (no ``NOTIFY_SOCKET``) every call is a no-op.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

logger = logging.getLogger(__name__)

#: Send keep-alives at this fraction of WatchdogSec, as sd_watchdog_enabled(3) advises.
WATCHDOG_KEEPALIVE_FRACTION = 0.5
MICROSECONDS_PER_SECOND = 1_000_000


class SystemdNotifier:
    """Sends state changes to systemd over the datagram socket it named in the environment."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        environ = os.environ if environ is None else environ
        address = environ.get("NOTIFY_SOCKET", "")
        # '@' marks a socket in the abstract namespace, written with a leading NUL byte.
        self._address = "\0" + address[1:] if address.startswith("@") else address
        self._watchdog_usec = self._watchdog_for_us(environ)

    @staticmethod
    def _watchdog_for_us(environ: Mapping[str, str]) -> int | None:
        raw = environ.get("WATCHDOG_USEC")
        if raw is None:
            return None
        pid = environ.get("WATCHDOG_PID")
        if pid is not None and pid != str(os.getpid()):
            return None  # the watchdog is meant for another process
        try:
            usec = int(raw)
        except ValueError:
            logger.warning("ignoring WATCHDOG_USEC=%r: not a number", raw)
            return None
        return usec if usec > 0 else None

    @property
    def enabled(self) -> bool:
        return bool(self._address)

    @property
    def watchdog_interval_s(self) -> float | None:
        """How often to send WATCHDOG=1, or None when systemd set no watchdog."""
        if self._watchdog_usec is None:
            return None
        return self._watchdog_usec / MICROSECONDS_PER_SECOND * WATCHDOG_KEEPALIVE_FRACTION

    def notify(self, *assignments: str) -> bool:
        """Send ``KEY=value`` lines; True when sent. Never raises: systemd's absence or a
        transient socket error must not stop the daemon."""
        if not self._address:
            return False
        message = "\n".join(assignments).encode()
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
                sock.sendto(message, self._address)
        except OSError as err:
            logger.warning("sd_notify %r failed: %s", assignments, err)
            return False
        return True

    def ready(self, status: str = "ready") -> bool:
        return self.notify("READY=1", f"STATUS={status}")

    def stopping(self) -> bool:
        return self.notify("STOPPING=1", "STATUS=stopping")

    def status(self, text: str) -> bool:
        return self.notify(f"STATUS={text}")

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")
