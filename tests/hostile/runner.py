"""Run ``thermocomp`` in a child process with a time and memory bound, fast.

Each case is a real process (its own exit status, stdout and stderr, killed when it runs over
its time, refused memory beyond its budget: ``RLIMIT_AS``), forked from a fork server that has
imported the command once (multiprocessing's "forkserver": a clean single-threaded parent), so
a case costs tens of milliseconds instead of the half second of a fresh interpreter's imports.
"""

from __future__ import annotations

import functools
import multiprocessing
import os
import resource
import sys
import time
import traceback
from dataclasses import dataclass
from multiprocessing.context import ForkServerContext
from pathlib import Path

#: What the fork server imports once: the command line and what its commands load.
PRELOAD = [
    "tests.hostile.runner",
    "api.cli",
    "api.serve",
    "daemon.service",
    "daemon.commands.run",
    "daemon.model.cli",
    "daemon.vision.cli",
    "daemon.arm.controller",
    "daemon.arm.urdf",
]

#: Memory a case may take beyond what the fork server holds (its imports): the known failures
#: took 1.65 GB (cyclic URDF) and 2.3 GB (0.0001 mm node spacing) before they were bounded.
MEMORY_BUDGET_BYTES = 768 * 1024 * 1024
#: Time a case may take (s): a refusal is milliseconds; this is a ceiling for a loaded machine.
TIME_LIMIT_S = 60.0


@dataclass(frozen=True)
class Outcome:
    status: int | None  # None: killed at the time limit
    out: str
    err: str
    seconds: float

    @property
    def err_lines(self) -> list[str]:
        return [line for line in self.err.splitlines() if line.strip()]


def _vm_bytes() -> int:
    with open("/proc/self/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


def _child(argv: list[str], cwd: str, out_path: str, err_path: str, env: dict[str, str]) -> None:
    limit = _vm_bytes() + MEMORY_BUDGET_BYTES
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    os.chdir(cwd)
    os.environ.update(env)
    for fd, path in ((1, out_path), (2, err_path)):
        target = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        os.dup2(target, fd)
        os.close(target)
    sys.stdout = open(1, "w", encoding="utf-8", closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", encoding="utf-8", closefd=False)  # noqa: SIM115
    status = 0
    try:
        from api.cli import main

        status = main(argv)
    except SystemExit as exit_:
        code = exit_.code
        if isinstance(code, int) or code is None:
            status = code or 0
        else:
            print(code, file=sys.stderr)
            status = 1
    except BaseException:  # a crash: the test shows its traceback
        traceback.print_exc()
        status = 70
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
    os._exit(status)


@functools.cache
def _fork_server() -> ForkServerContext:
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(PRELOAD)
    return context


def run_bounded(
    argv: list[str],
    cwd: Path,
    env: dict[str, str] | None = None,
    timeout_s: float = TIME_LIMIT_S,
) -> Outcome:
    """``thermocomp argv`` in a child: its status, output and time (killed after timeout_s)."""
    out_path, err_path = cwd / ".hostile-stdout", cwd / ".hostile-stderr"
    process = _fork_server().Process(
        target=_child, args=(argv, str(cwd), str(out_path), str(err_path), env or {})
    )
    started = time.monotonic()
    process.start()
    process.join(timeout_s)
    status: int | None = process.exitcode
    if process.is_alive():
        process.kill()
        process.join()
        status = None
    seconds = time.monotonic() - started
    read = lambda path: path.read_text("utf-8", "replace") if path.exists() else ""  # noqa: E731
    outcome = Outcome(status, read(out_path), read(err_path), seconds)
    for path in (out_path, err_path):
        path.unlink(missing_ok=True)
    return outcome
