"""The daemon's event bus and error log: what the API streams and lists.

Publishing never blocks and never fails the control loop: each subscriber has a bounded queue
that drops its oldest event when full and counts the drop (issue 7: a slow reader never slows
a step). Published from the control loop's own thread (daemon/run/control_loop.py), an event
crosses to the API's loop through that loop's bounded outbox (:meth:`EventBus.route`): the
subscribers' queues belong to the API's loop.
"""

from __future__ import annotations

import asyncio
import functools
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

EVENT_QUEUE_DEFAULT = 256
ERROR_HISTORY = 200


@dataclass(frozen=True, slots=True)
class Event:
    """What subscribers receive: ``kind`` is "step", "state", "error" or "frame" (the frame's
    image as an array: subscribe to it only where it is consumed in process)."""

    kind: str
    data: dict[str, Any]


class Subscription:
    """A bounded event queue: when full, the oldest event is dropped and counted."""

    def __init__(self, bus: EventBus, maxsize: int, kinds: frozenset[str] | None) -> None:
        self._bus = bus
        self._queue: asyncio.Queue[Event] = asyncio.Queue(maxsize)
        self.kinds = kinds
        self.dropped = 0

    def put(self, event: Event) -> None:
        if self.kinds is not None and event.kind not in self.kinds:
            return
        if self._queue.full():
            self._queue.get_nowait()
            self.dropped += 1
        self._queue.put_nowait(event)

    async def get(self) -> Event:
        return await self._queue.get()

    def get_nowait(self) -> Event | None:
        try:
            return self._queue.get_nowait()
        except asyncio.QueueEmpty:
            return None

    def close(self) -> None:
        self._bus.unsubscribe(self)

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class EventBus:
    """Fan-out of the daemon's events to every subscription."""

    def __init__(self, queue_size: int = EVENT_QUEUE_DEFAULT) -> None:
        self._queue_size = queue_size
        self._subscriptions: set[Subscription] = set()
        self._post: Callable[[Callable[[], None]], None] | None = None

    def route(self, post: Callable[[Callable[[], None]], None] | None) -> None:
        """Deliver through ``post`` (ControlLoop.post_home: runs a call on the subscribers'
        loop, directly when already there); None: deliver directly."""
        self._post = post

    def subscribe(
        self, maxsize: int | None = None, kinds: frozenset[str] | None = None
    ) -> Subscription:
        subscription = Subscription(self, maxsize or self._queue_size, kinds)
        self._subscriptions.add(subscription)
        return subscription

    def unsubscribe(self, subscription: Subscription) -> None:
        self._subscriptions.discard(subscription)

    def publish(self, event: Event) -> None:
        if self._post is not None:
            self._post(functools.partial(self._deliver, event))
        else:
            self._deliver(event)

    def _deliver(self, event: Event) -> None:
        for subscription in list(self._subscriptions):
            subscription.put(event)


@dataclass(frozen=True, slots=True)
class ErrorEntry:
    time_unix: float
    device: str
    kind: str
    message: str

    def as_dict(self) -> dict[str, Any]:
        return {
            "time": self.time_unix,
            "device": self.device,
            "kind": self.kind,
            "message": self.message,
        }


class ErrorLog:
    """The latest device/storage/daemon errors (bounded), each also published as an event."""

    def __init__(self, bus: EventBus, history: int = ERROR_HISTORY) -> None:
        self._bus = bus
        self.entries: deque[ErrorEntry] = deque(maxlen=history)

    def note(self, err: BaseException, device: str | None = None) -> ErrorEntry:
        entry = ErrorEntry(
            time.time(),
            str(device or getattr(err, "device", "daemon")),
            getattr(err, "kind", type(err).__name__),
            str(err),
        )
        self.entries.append(entry)
        self._bus.publish(Event("error", entry.as_dict()))
        return entry

    def recent(self, limit: int = ERROR_HISTORY) -> list[dict[str, Any]]:
        """The latest entries, oldest first."""
        return [entry.as_dict() for entry in list(self.entries)[-limit:]]

    def __len__(self) -> int:
        return len(self.entries)
