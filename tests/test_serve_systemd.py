"""``thermocomp serve`` under a stand-in for systemd (issue 10, deploy/thermocomp.service):
a real datagram socket as NOTIFY_SOCKET, the real server as a subprocess, SIGTERM to stop it."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import httpx
import pytest

from api.serve import SUPERVISOR_POLL_S, supervise
from daemon.storage.recorder import Recorder
from daemon.systemd import SystemdNotifier
from tests.helpers import REPO_ROOT, cli_command, free_port

SIM = str(REPO_ROOT / "config" / "sim.toml")
CONTROL = "control-token-0123456789"
WATCHDOG_USEC = 400_000  # keep-alives every 0.2 s (half of it, sd_watchdog_enabled(3))


@pytest.fixture
def notify_socket() -> Iterator[tuple[socket.socket, str]]:
    """What systemd listens on: a datagram socket whose path the service gets in its
    environment (short path under /tmp: AF_UNIX paths are limited to 108 bytes)."""
    with tempfile.TemporaryDirectory(prefix="tc-notify-") as folder:
        path = os.path.join(folder, "notify")
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock.bind(path)
        try:
            yield sock, path
        finally:
            sock.close()


def receive(sock: socket.socket, timeout_s: float) -> dict[str, str] | None:
    sock.settimeout(timeout_s)
    try:
        message = sock.recv(4096).decode()
    except TimeoutError:
        return None
    return dict(line.split("=", 1) for line in message.splitlines())


def wait_for(
    sock: socket.socket, key: str, process: subprocess.Popen[bytes], timeout_s: float
) -> tuple[dict[str, str], list[dict[str, str]]]:
    """The first message carrying ``key``, and the messages before it."""
    before: list[dict[str, str]] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        message = receive(sock, 0.5)
        if message is None:
            assert process.poll() is None, f"the server exited with {process.returncode}"
            continue
        if key in message:
            return message, before
        before.append(message)
    raise AssertionError(f"no {key} within {timeout_s} s; got {before}")


@pytest.mark.slow
def test_serve_notifies_systemd_and_stops_safely_on_sigterm(
    tmp_path: Path, notify_socket: tuple[socket.socket, str]
) -> None:
    sock, path = notify_socket
    port = free_port()
    base_url = f"http://127.0.0.1:{port}"
    env = {
        **os.environ,
        "NOTIFY_SOCKET": path,
        "WATCHDOG_USEC": str(WATCHDOG_USEC),
        "THERMOCOMP_STORAGE__DATA_DIR": str(tmp_path),
        "THERMOCOMP_API__CONTROL_TOKEN": CONTROL,
    }
    process = subprocess.Popen(
        cli_command(
            "--log-level",
            "WARNING",
            "serve",
            "--config",
            SIM,
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
        ),
        cwd=REPO_ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        ready, before = wait_for(sock, "READY", process, timeout_s=60.0)
        # READY=1 means the daemon is open and the socket listens: /health answers at once
        health = httpx.get(f"{base_url}/api/v1/health", timeout=5.0)
        assert health.status_code == 200
        assert before == [] and ready["READY"] == "1" and "STATUS" in ready

        started = httpx.post(
            f"{base_url}/api/v1/runs",
            json={"duration_s": 36000, "step_s": 1},
            headers={"Authorization": f"Bearer {CONTROL}"},
            timeout=10.0,
        )
        assert started.status_code == 201, started.text
        run_id = started.json()["id"]
        keepalives = 0
        statuses: list[str] = []
        running = f"run {run_id} running"
        while keepalives < 3 or not any(status.startswith(running) for status in statuses):
            # the control loop runs: keep-alives keep coming, STATUS follows the run
            message, others = wait_for(sock, "WATCHDOG", process, timeout_s=10.0)
            statuses += [m["STATUS"] for m in [*others, message] if "STATUS" in m]
            keepalives += 1
            assert keepalives < 50, statuses
        state = httpx.get(f"{base_url}/api/v1/state", timeout=5.0).json()
        assert state["run"]["id"] == run_id and state["run"]["step"] >= 0

        process.send_signal(signal.SIGTERM)
        stopping, _ = wait_for(sock, "STOPPING", process, timeout_s=10.0)
        assert stopping["STOPPING"] == "1"
        assert process.wait(timeout=30) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()

    with Recorder(tmp_path) as recorder:  # what a restart finds: nothing to mark interrupted
        assert recorder.interrupted_runs == []
        run = recorder.run(run_id)
        assert run is not None
        assert run.state == "stopped" and run.reason == "daemon shut down"
        steps = recorder.steps(run_id)
    assert run.step_count == len(steps) > 0
    assert [s.step for s in steps] == list(range(len(steps)))  # every step readable, no gap


class RecordingNotifier(SystemdNotifier):
    def __init__(self) -> None:
        super().__init__({"NOTIFY_SOCKET": "/unused", "WATCHDOG_USEC": "20000"})
        self.sent: list[tuple[str, ...]] = []
        self.keepalive = asyncio.Event()

    def notify(self, *assignments: str) -> bool:
        self.sent.append(assignments)
        if "WATCHDOG=1" in assignments:
            self.keepalive.set()
        return True

    async def next_keepalive(self) -> None:
        self.keepalive.clear()
        await asyncio.wait_for(self.keepalive.wait(), timeout=10.0)


class HangingDaemon:
    """The two things supervise() reads of the daemon; the loop "hangs" when told to."""

    def __init__(self) -> None:
        self.run = None
        self.alive = True

    def control_loop_alive(self, max_silence_s: float) -> bool:
        return self.alive


async def test_a_hung_control_loop_stops_the_watchdog_keepalives() -> None:
    notifier = RecordingNotifier()  # keep-alives every 10 ms
    daemon = HangingDaemon()
    server = SimpleNamespace(started=True, should_exit=False)
    context = SimpleNamespace(service=daemon)
    task = asyncio.create_task(supervise(cast(Any, server), cast(Any, context), notifier))

    def keepalives() -> int:
        return sum(1 for message in notifier.sent if message == ("WATCHDOG=1",))

    for _ in range(3):
        await notifier.next_keepalive()
    daemon.alive = False
    await asyncio.sleep(SUPERVISOR_POLL_S)  # let a keep-alive already due go out
    hung_at = keepalives()
    await asyncio.sleep(5 * SUPERVISOR_POLL_S)  # many intervals, all while the loop hangs
    assert keepalives() == hung_at
    daemon.alive = True
    await notifier.next_keepalive()  # progress again: keep-alives resume
    server.should_exit = True
    await task
    assert notifier.sent[0][0] == "READY=1" and notifier.sent[-1][0] == "STOPPING=1"
