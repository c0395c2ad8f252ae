"""Loopback addresses for the tests that serve UR's fixed ports (issue 31).

ur-rtde's clients (RTDEReceiveInterface, RTDEIOInterface, DashboardClient) always dial UR's
fixed ports, 30004 and 29999: each test that serves them needs a loopback address of its own
(Linux routes all of 127.0.0.0/8 to the loopback interface). Fixed addresses per test collided
when two worktrees' suites (or two xdist workers running the same file) ran at once: "address
already in use". :func:`loopback_host` gives an address no other live process is given: it is
built from this process's id (distinct among live processes: xdist workers and other suites
alike) and a counter of this process, then probed on the UR ports (a bind to each): an address
some other process still listens on is skipped for the next.

The addresses are 127.128.0.1 to 127.255.255.254 (the upper half of 127/8: clear of 127.0.0.1,
where servers and the default UR emulator listen, and of the benchmarks' 127.0.34.x).
"""

from __future__ import annotations

import errno
import itertools
import os
import socket
from collections.abc import Iterable

#: UR's fixed RTDE and Dashboard Server ports (drivers/sim/ur/rtde_server.py, dashboard.py).
UR_PORTS = (30004, 29999)
#: Process ids are taken modulo this: Linux's default pid_max (2**15) keeps them unique among
#: live processes; beyond it two processes may share a prefix, and the probe tells them apart.
_PID_SPACE = 1 << 15
#: Addresses tried at most before giving up (each probe is two binds).
_TRIES = 254

_counter = itertools.count()


def _address(pid: int, n: int) -> str:
    prefix = pid % _PID_SPACE
    return f"127.{128 + (prefix >> 8)}.{prefix & 0xFF}.{1 + n % 254}"


def _free(host: str, ports: Iterable[int]) -> bool:
    """Nothing is bound on ``host`` at any of ``ports`` now (a listener, or a socket that
    lingers: both make the next bind fail)."""
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            try:
                probe.bind((host, port))
            except OSError as err:
                if err.errno == errno.EADDRINUSE:
                    return False
                raise
    return True


def loopback_host(ports: Iterable[int] = UR_PORTS) -> str:
    """A loopback address of this process whose ``ports`` are free now (module docstring)."""
    wanted = tuple(ports)
    pid = os.getpid()
    for _ in range(_TRIES):
        host = _address(pid, next(_counter))
        if _free(host, wanted):
            return host
    raise RuntimeError(f"no free loopback address for ports {wanted} in {_TRIES} tries")
