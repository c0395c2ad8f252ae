"""Fan-out of daemon events to WebSocket clients, without ever waiting for a client.

The daemon publishes from its control loop; :meth:`Hub.publish` only encodes the message once
and appends it to each subscribed client's bounded queue, so it costs microseconds whatever
the clients do (issue 7: a slow client never slows the control loop). A full queue drops its
oldest message and counts it; the client's sender tells it how many it lost before the next
message it gets.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from typing import Any, Literal

logger = logging.getLogger(__name__)

Topic = Literal["steps", "state", "errors", "frames"]
TOPICS: tuple[Topic, ...] = ("steps", "state", "errors", "frames")

#: The ``type`` of a message of each topic (a message is one step, one state, ...).
MESSAGE_TYPE: dict[Topic, str] = {
    "steps": "step",
    "state": "state",
    "errors": "error",
    "frames": "frame",
}


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float as None: JSON has no NaN, browsers reject it."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


def encode(message_type: str, data: Any) -> str:
    return json.dumps({"type": message_type, "data": json_safe(data)}, separators=(",", ":"))


class ClientQueue:
    """One client's pending messages: at most ``size``; the oldest go first when full."""

    def __init__(self, size: int, topics: Iterable[Topic]) -> None:
        self.topics: frozenset[Topic] = frozenset(topics)
        self._messages: deque[str] = deque(maxlen=size)
        self._ready = asyncio.Event()
        self.lost = 0  # dropped since the client was last told
        self.lost_total = 0

    def offer(self, text: str) -> bool:
        """Queue ``text``; return False when that pushed out the oldest message."""
        dropped = len(self._messages) == self._messages.maxlen
        if dropped:
            self.lost += 1
            self.lost_total += 1
        self._messages.append(text)
        self._ready.set()
        return not dropped

    async def take(self) -> tuple[int, list[str]]:
        """Wait for messages; return (messages lost since the last take, queued messages)."""
        await self._ready.wait()
        self._ready.clear()
        lost, self.lost = self.lost, 0
        messages = list(self._messages)
        self._messages.clear()
        return lost, messages


class Hub:
    """The set of connected clients and what each subscribed to."""

    def __init__(self, queue_size: int, on_drop: Callable[[int], None] | None = None) -> None:
        self.queue_size = queue_size
        self._clients: set[ClientQueue] = set()
        self._on_drop = on_drop

    def __len__(self) -> int:
        return len(self._clients)

    def connect(self, topics: Iterable[Topic]) -> ClientQueue:
        client = ClientQueue(self.queue_size, topics)
        self._clients.add(client)
        return client

    def disconnect(self, client: ClientQueue) -> None:
        self._clients.discard(client)

    def subscribed(self, topic: Topic) -> bool:
        """Whether anybody listens to ``topic`` (skip costly messages nobody wants)."""
        return any(topic in client.topics for client in self._clients)

    def publish(self, topic: Topic, data: Any) -> None:
        """Send ``data`` to the subscribers of ``topic``; never blocks, never raises."""
        listeners = [client for client in self._clients if topic in client.topics]
        if not listeners:
            return
        try:
            text = encode(MESSAGE_TYPE[topic], data)
        except (TypeError, ValueError):
            logger.exception("cannot encode a %s message; not sent", topic)
            return
        dropped = sum(not client.offer(text) for client in listeners)
        if dropped and self._on_drop is not None:
            self._on_drop(dropped)
