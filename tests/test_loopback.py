"""tests/loopback.py: the UR tests' loopback addresses are their process's, and one whose UR
ports something else holds is skipped."""

from __future__ import annotations

import itertools
import os
import socket
import subprocess
import sys

import pytest

from tests import loopback
from tests.helpers import REPO_ROOT


def test_an_address_whose_ur_port_is_taken_is_skipped(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(loopback, "_counter", itertools.count(0))
    taken = loopback._address(os.getpid(), 0)
    with socket.socket() as other:  # another suite's emulator on that address
        other.bind((taken, loopback.UR_PORTS[1]))
        other.listen()
        host = loopback.loopback_host()
    assert host == loopback._address(os.getpid(), 1) != taken
    assert host.startswith("127.") and int(host.split(".")[1]) >= 128


def test_two_processes_get_addresses_of_their_own() -> None:
    script = "from tests.loopback import loopback_host; print(loopback_host())"
    other = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO_ROOT, capture_output=True, text=True, check=True
    ).stdout.strip()
    mine = {loopback.loopback_host() for _ in range(300)}  # the counter wraps past 254
    # another process's id: another 127.X.Y prefix, none of this process's addresses
    assert {host.rsplit(".", 1)[0] for host in mine} == {loopback._address(os.getpid(), 0)[:-2]}
    assert other.rsplit(".", 1)[0] != loopback._address(os.getpid(), 0)[:-2]
    assert other not in mine
