"""Small utilities the tests share: free ports, running the real CLI, waiting for a server."""

from __future__ import annotations

import argparse
import io
import logging
import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from pathlib import Path
from unittest import mock

import httpx
import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent
#: Bound on a `thermocomp serve` start (imports, bench, first answer): ~4 s idle, 30 s was
#: exceeded at load 19 with the suite on both cores. A hang bound, not a speed check.
SERVER_START_S = 60.0


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def cli_command(*args: str) -> list[str]:
    """The real ``thermocomp`` command, run with this interpreter."""
    return [sys.executable, "-m", "api", *args]


def run_cli(
    args: Sequence[str], env: dict[str, str] | None = None, timeout: float = 120.0
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        cli_command(*args),
        cwd=REPO_ROOT,
        env={**os.environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def run_main(
    args: Sequence[str], env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """What ``run_cli`` returns, from the ``thermocomp`` entry point (``api.cli.main``, which
    ``python -m api`` passes to ``sys.exit``) called in this process: the command's logic
    without the ~4 s of CPU a fresh interpreter spends importing the stack (issue 27). For
    what only a process shows (exit by signal, what ``--help`` imports, the interpreter's
    own stderr) use ``run_cli``.

    As in the subprocess: the working directory is the checkout, ``env`` is added to the
    environment, stdout and stderr are captured, and the root logger is the one ``main``
    configures (its handler writes to the captured stderr); all of it is put back after."""
    from api.cli import main  # lazy: the stack loads for the tests that run a command

    root = logging.getLogger()
    saved_handlers, saved_level = root.handlers[:], root.level
    out, err = io.StringIO(), io.StringIO()
    previous_cwd = os.getcwd()
    root.handlers = []  # pytest's capture handlers: main's basicConfig would add none
    try:
        os.chdir(REPO_ROOT)
        with (
            mock.patch.dict(os.environ, env or {}),
            redirect_stdout(out),
            redirect_stderr(err),
        ):
            try:
                status = main(list(args))
            except SystemExit as exit_:  # argparse's usage errors, --help, --version
                code = exit_.code
                status = code if isinstance(code, int) else (0 if code is None else 1)
                if isinstance(code, str):
                    print(code, file=sys.stderr)
    finally:
        for handler in root.handlers:
            handler.close()
        root.handlers = saved_handlers
        root.setLevel(saved_level)
        os.chdir(previous_cwd)
    return subprocess.CompletedProcess(
        ["thermocomp", *args], status, stdout=out.getvalue(), stderr=err.getvalue()
    )


def run_in_process(
    register: Callable[[argparse._SubParsersAction[argparse.ArgumentParser]], None],
    argv: Sequence[str],
    capsys: pytest.CaptureFixture[str],
) -> tuple[int, str, str]:
    """The subcommands one ``register`` adds, parsed and run in-process: (status, out, err)."""
    parser = argparse.ArgumentParser(prog="thermocomp")
    register(parser.add_subparsers(dest="command", required=True))
    try:
        args = parser.parse_args(argv)
        status = int(args.handler(args))
    except SystemExit as exit_:
        status = int(exit_.code or 0)
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@contextmanager
def running_server(
    args: Sequence[str], env: dict[str, str] | None = None, timeout_s: float = SERVER_START_S
) -> Iterator[str]:
    """Start ``thermocomp serve`` on a free loopback port; yield its base URL; stop it. Its
    data directory is a temporary one unless ``env`` names one (never the checkout's data/:
    the user's run database, and a `make run` beside the suite holds it)."""
    with tempfile.TemporaryDirectory(prefix="thermocomp-serve-") as data_dir:
        environment = {**os.environ, "THERMOCOMP_STORAGE__DATA_DIR": data_dir, **(env or {})}
        with _serving(args, environment, timeout_s) as base_url:
            yield base_url


@contextmanager
def _serving(args: Sequence[str], env: dict[str, str], timeout_s: float) -> Iterator[str]:
    port = free_port()
    process = subprocess.Popen(
        cli_command("serve", "--host", "127.0.0.1", "--port", str(port), *args),
        cwd=REPO_ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    base_url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            if process.poll() is not None:
                output = process.stdout.read() if process.stdout else ""
                raise AssertionError(f"server exited with {process.returncode}:\n{output}")
            try:
                httpx.get(f"{base_url}/api/v1/health", timeout=1.0)
                break
            except httpx.TransportError:
                if time.monotonic() > deadline:
                    raise AssertionError("server did not answer in time") from None
                time.sleep(0.1)
        yield base_url
    finally:
        process.terminate()
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        if process.stdout:
            process.stdout.close()
