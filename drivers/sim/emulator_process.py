"""The emulated C500C in a process of its own (``bench.emulator = "process"``, issue 30).

Inline, the emulated controller's Python runs in the daemon's process and its GIL time lands in
the daemon's steps: no real controller costs its host anything. Here ``thermocomp emulate c500c``
(drivers/sim/cli.py) runs as a child process on a real pty, paced at its baud rate, and the
daemon's ordinary driver opens that pty as it would the lab's serial port. The child runs at the
control loop's real-time priority when the host permits it: it stands for the controller, a
machine of its own that the lab PC's load does not touch.

The bench's physics reads the arm's pose from the child's shared motion record
(drivers/sim/shared_pose.py); the block is created here and unlinked as soon as the child has
attached it (the child prints its device path only after that), so no name is left in /dev/shm
whatever ends the child or the daemon afterwards; the mapping lives as long as each side holds it.

The child ends with the daemon: its standard input is a pipe from here and it stops when the
pipe closes (``--exit-with-stdin``), however the daemon ended; on exit it is sent SIGTERM, then
SIGKILL after :data:`STOP_S`. A child that dies while the daemon runs is a cut cable to the
driver (EOF, then its reconnection path); one log line says so and a fresh controller is started
behind the same device path (a power cycle: its taught goals are gone), unless the last one died
within :data:`MIN_LIFETIME_S` of its start, when one line says what to do instead.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import logging
import os
import secrets
import shutil
import signal
import sys
import tempfile
import time
from collections.abc import Sequence
from multiprocessing.shared_memory import SharedMemory
from pathlib import Path
from types import TracebackType
from typing import Self

from drivers.errors import DeviceError
from drivers.sim import shared_pose
from drivers.sim.ash_state import Location

logger = logging.getLogger(__name__)
#: The shared pose blocks' names (/dev/shm): the daemon's pid and a random part, so a leak is
#: named and tells whose it is.
SHARED_POSE_PREFIX = "thermocomp-pose-"

#: How long the child may take to print its device path (s): it imports the whole stack first
#: (~1 s on an idle development machine, several on a loaded one).
START_TIMEOUT_S = 30.0
#: How long the child has to stop after SIGTERM (then SIGKILL) (s); it stops within a fraction
#: of a second (drivers/sim/cli.py freezes its heap for a quick exit).
STOP_S = 3.0
#: A child that died sooner than this after its start is not restarted (s): it would only die
#: again (a bad argument, a broken installation).
MIN_LIFETIME_S = 10.0
#: Lines of the child's standard error kept for the error that reports its end.
STDERR_TAIL = 20
#: The device named in errors and log lines.
DEVICE = "emulated controller"


class EmulatorProcessError(DeviceError):
    """The emulator's process did not start (the message carries its standard error's tail)."""

    def __init__(self, message: str) -> None:
        super().__init__(DEVICE, message)


def _ended(status: int) -> str:
    """How a child ended, from its return code (negative: the signal that killed it)."""
    if status < 0:
        with contextlib.suppress(ValueError):
            return f"was killed by {signal.Signals(-status).name}"
        return f"was killed by signal {-status}"
    return f"exited with status {status}"


class EmulatorProcess:
    """``python -m api emulate c500c ARGUMENTS`` as an async context manager.

    ``device_path`` is the pty's stable path (a symlink in a directory this owns, replaced when
    a fresh child starts); :meth:`actual_pose` is the bench's ``PoseSource``.
    """

    def __init__(
        self,
        arguments: Sequence[str],
        *,
        realtime_priority: int = 0,
        start_timeout_s: float = START_TIMEOUT_S,
        python: str = sys.executable,
    ) -> None:
        self._arguments = list(arguments)
        self._priority = realtime_priority
        self._start_timeout_s = start_timeout_s
        self._python = python
        self._directory: str | None = None
        self.device_path = ""
        self._process: asyncio.subprocess.Process | None = None
        self._started_at = 0.0
        self._block: SharedMemory | None = None
        self._stderr: collections.deque[str] = collections.deque(maxlen=STDERR_TAIL)
        self._tasks: set[asyncio.Task[None]] = set()
        self._watcher: asyncio.Task[None] | None = None
        self._closing = False
        #: children started so far (1 after a clean start; more after restarts)
        self.starts = 0

    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.returncode is None

    def actual_pose(self) -> Location:
        """Where the emulated arm is now: the child's motion record at CLOCK_MONOTONIC, the
        clock its event loop runs on (drivers/sim/shared_pose.py)."""
        assert self._block is not None, "the emulator process is not started"
        return shared_pose.read(shared_pose.buffer_of(self._block)).pose_at(time.monotonic())

    # --- lifecycle ---

    async def __aenter__(self) -> Self:
        self._directory = tempfile.mkdtemp(prefix="c500c-process-")
        self.device_path = str(Path(self._directory) / "console")
        try:
            await self._start()
        except BaseException:
            await self.aclose()
            raise
        self._watcher = asyncio.get_running_loop().create_task(self._watch())
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        self._closing = True
        if self._watcher is not None:
            self._watcher.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._watcher
            self._watcher = None
        await self._stop_child()
        if self._block is not None:
            self._release_block(self._block)
            self._block = None
        if self._directory is not None:
            shutil.rmtree(self._directory, ignore_errors=True)
            self._directory = None

    async def _start(self) -> None:
        """One child: a fresh block, the child attached to it, its device path read."""
        block = SharedMemory(
            name=f"{SHARED_POSE_PREFIX}{os.getpid()}-{secrets.token_hex(4)}",
            create=True,
            size=shared_pose.SIZE,
        )
        name = block.name.lstrip("/")
        command = [
            self._python,
            "-m",
            "api",
            "emulate",
            "c500c",
            *self._arguments,
            "--link",
            self.device_path,
            "--pose-shm",
            name,
            "--exit-with-stdin",
            "--realtime-priority",
            str(self._priority),
        ]
        self._stderr.clear()
        try:
            process = await asyncio.create_subprocess_exec(
                *command,
                stdin=asyncio.subprocess.PIPE,
                stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE,
            )
        except OSError as err:
            self._release_block(block)
            raise EmulatorProcessError(f"cannot start {self._python}: {err}") from err
        except BaseException:  # cancelled: no name left in /dev/shm
            self._release_block(block)
            raise
        self._process, self._started_at = process, time.monotonic()
        self.starts += 1
        assert process.stdout is not None and process.stderr is not None
        self._spawn(self._drain_stderr(process.stderr))
        ended = f"no device path within {self._start_timeout_s:g} s"
        try:
            async with asyncio.timeout(self._start_timeout_s):
                line = (await process.stdout.readline()).decode(errors="replace").strip()
                if not line:  # its stdout closed: it is ending
                    ended = _ended(await process.wait())
        except TimeoutError:
            line = ""
        finally:
            # Attached by the child (it prints its path after) or never will be: the name goes
            # now, the mappings stay (shm_unlink(3)).
            with contextlib.suppress(FileNotFoundError):
                block.unlink()
        if not line:
            self._release_block(block)
            await self._stop_child()  # its stderr read to the end
            raise EmulatorProcessError(
                f"did not start ({ended}; its stderr: {self._stderr_tail()})"
            )
        if self._block is not None:
            self._release_block(self._block)
        self._block = block
        self._spawn(self._drain_stdout(process.stdout))
        logger.info("emulated controller: process %d on %s", process.pid, line)

    async def _stop_child(self) -> None:
        process = self._process
        if process is None:
            return
        if process.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                process.terminate()
            try:
                async with asyncio.timeout(STOP_S):
                    await process.wait()
            except TimeoutError:
                logger.warning("emulated controller: no exit %g s after SIGTERM: killed", STOP_S)
                with contextlib.suppress(ProcessLookupError):
                    process.kill()
                await process.wait()
        if process.stdin is not None:
            process.stdin.close()
        # the readers end at the pipes' end (the child is gone)
        tasks = list(self._tasks)
        if tasks:
            await asyncio.gather(*tasks, return_exceptions=True)
        self._process = None

    def _release_block(self, block: SharedMemory) -> None:
        with contextlib.suppress(FileNotFoundError):
            block.unlink()
        block.close()

    # --- the child's output and its end ---

    def _spawn(self, coroutine: collections.abc.Coroutine[object, object, None]) -> None:
        task = asyncio.get_running_loop().create_task(coroutine)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _drain_stderr(self, stream: asyncio.StreamReader) -> None:
        """Keep the tail of the child's standard error and log each line (its scheduling line,
        its warnings); an unread pipe would block the child once full."""
        while line := await stream.readline():
            text = line.decode(errors="replace").rstrip()
            self._stderr.append(text)
            logger.info("emulated controller: %s", text)

    async def _drain_stdout(self, stream: asyncio.StreamReader) -> None:
        while await stream.readline():
            pass

    def _stderr_tail(self) -> str:
        tail = [line for line in self._stderr if line.strip()]
        return " | ".join(tail[-5:]) if tail else "nothing on its standard error"

    async def _watch(self) -> None:
        """The child's unexpected end: one line, then a fresh controller (or why not)."""
        while True:
            process = self._process
            assert process is not None
            status = await process.wait()
            await asyncio.gather(*list(self._tasks), return_exceptions=True)
            if self._closing:
                return
            lived_s = time.monotonic() - self._started_at
            if lived_s < MIN_LIFETIME_S:
                logger.error(
                    "emulated controller: process %d %s %.1f s after its start (its stderr: "
                    "%s); not restarted: the robot's link stays down until the daemon is "
                    "restarted with a working emulator (or bench.emulator = inline)",
                    process.pid,
                    _ended(status),
                    lived_s,
                    self._stderr_tail(),
                )
                return
            logger.error(
                "emulated controller: process %d %s (its stderr: %s); the robot's link is "
                "down (the driver holds and reconnects); starting a fresh controller (a power "
                "cycle: its taught goals are gone)",
                process.pid,
                _ended(status),
                self._stderr_tail(),
            )
            try:
                await self._start()
            except (EmulatorProcessError, OSError) as err:
                logger.error(
                    "emulated controller: the fresh controller did not start (%s); the robot's "
                    "link stays down until the daemon is restarted",
                    err,
                )
                return
