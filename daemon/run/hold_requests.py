"""Holds asked on the API's thread and not yet carried out on the control loop (daemon/service.py:
a hold, with the pause or stop that follows it). While one is on its way, a step the hold
refuses is not a fault of the run: its request came first (daemon/run/session.py ``_judge``).

The one owner of that count; read from any thread.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator


class HoldRequests:
    def __init__(self) -> None:
        self._in_flight = 0
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def asked(self) -> Iterator[None]:
        """While a hold asked here is on its way to the control loop."""
        with self._lock:
            self._in_flight += 1
        try:
            yield
        finally:
            with self._lock:
                self._in_flight -= 1

    def pending(self) -> bool:
        """A hold request has held the permit and has not yet reached the run (any thread)."""
        return self._in_flight > 0
