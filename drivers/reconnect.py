"""One reconnection state machine for every link that reconnects on its own: the console
(drivers/c500c/link.py), the fast path (drivers/c500c/server_link.py) and the GenICam
transport (drivers/genicam/transport.py) each had a copy of it.

After a link fault the driver calls :meth:`Reconnector.start`: one background task (never two:
a second start while one runs does nothing) tries ``attempt()`` until it succeeds, waiting a
capped exponential back-off between attempts (first ``first_backoff_s()``, then x
RECONNECT_BACKOFF_FACTOR up to ``max_backoff_s()``, the driver's
``reconnect_max_backoff_s`` setting). Each attempt runs under the driver's lock when one is
given (the console: no command interleaves with a reconnection), and only a DeviceError is a
failed attempt: anything else ends the task (a bug must not loop), logged with its traceback
and reported through ``on_fatal`` (the driver's link goes to ``fault``: never ``reconnecting``
forever; issue 26). What the link does around it (states, holding motion until an explicit
resume) stays the driver's: ``on_failure`` is called after every failed attempt,
``on_success`` once connected.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable, Iterator

from drivers.errors import DeviceError

logger = logging.getLogger(__name__)

#: First wait before a reconnection attempt (s): long enough for a USB adapter or a camera to
#: come back after a replug, short enough that a blip costs a few steps at most.
RECONNECT_FIRST_BACKOFF_S = 0.5
#: Each failed attempt doubles the wait, up to the driver's configured cap.
RECONNECT_BACKOFF_FACTOR = 2.0

Sleep = Callable[[float], Awaitable[None]]


def backoffs(first_s: float, cap_s: float) -> Iterator[float]:
    """The waits between attempts: ``first_s``, then doubled each time and capped at ``cap_s``
    (the first wait is the caller's own and is not capped)."""
    delay = first_s
    while True:
        yield delay
        delay = min(delay * RECONNECT_BACKOFF_FACTOR, cap_s)


class Reconnector:
    """A link's background reconnection: one task at a time, capped back-off, counted attempts."""

    def __init__(
        self,
        device: str,
        attempt: Callable[[], Awaitable[None]],
        *,
        first_backoff_s: Callable[[], float],
        max_backoff_s: Callable[[], float],
        lock: asyncio.Lock | None = None,
        wait_first: bool = False,
        before: Callable[[], Awaitable[None]] | None = None,
        on_failure: Callable[[DeviceError], None] | None = None,
        on_success: Callable[[], None] | None = None,
        on_fatal: Callable[[BaseException], None] | None = None,
        task_name: str = "reconnect",
        sleep: Sleep = asyncio.sleep,
    ) -> None:
        """``wait_first``: wait one back-off before the first attempt (a camera that was just
        pulled is not back at once); ``before``: run once before the attempts (close what is
        left of the old link); ``sleep``: how back-offs are waited (tests record them)."""
        self.device = device
        self._attempt = attempt
        self._first_backoff_s = first_backoff_s
        self._max_backoff_s = max_backoff_s
        self._lock = lock
        self._wait_first = wait_first
        self._before = before
        self._on_failure = on_failure
        self._on_success = on_success
        self._on_fatal = on_fatal
        self.fatal: BaseException | None = None  # the unexpected error that ended it
        self._task_name = task_name
        self._sleep = sleep
        self.attempts = 0  # every attempt ever made (status pages show it)
        self.task: asyncio.Task[None] | None = None

    @property
    def running(self) -> bool:
        return self.task is not None and not self.task.done()

    def start(self) -> None:
        """Reconnect in the background unless a reconnection is already under way."""
        if not self.running:
            self.task = asyncio.get_running_loop().create_task(self._run(), name=self._task_name)

    async def cancel(self) -> None:
        """Stop a reconnection under way (closing the link) and wait until it has stopped."""
        task, self.task = self.task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    async def _try(self) -> None:
        if self._lock is None:
            await self._attempt()
            return
        async with self._lock:
            await self._attempt()

    async def _run(self) -> None:
        delays = backoffs(self._first_backoff_s(), self._max_backoff_s())
        if self._before is not None:
            await self._before()
        if self._wait_first:
            await self._sleep(next(delays))
        while True:
            self.attempts += 1
            try:
                await self._try()
            except asyncio.CancelledError:
                raise
            except Exception as err:
                if not isinstance(err, DeviceError):
                    logger.exception(
                        "%s: reconnection failed with an unexpected error; the link is failed "
                        "until it is opened again",
                        self.device,
                    )
                    self.fatal = err
                    if self._on_fatal is not None:
                        self._on_fatal(err)
                    return
                delay = next(delays)
                logger.warning(
                    "%s: reconnection attempt %d failed (%s); next in %.2f s",
                    self.device,
                    self.attempts,
                    err,
                    delay,
                )
                if self._on_failure is not None:
                    self._on_failure(err)
                await self._sleep(delay)
                continue
            if self._on_success is not None:
                self._on_success()
            return
