"""The states of the two C500C links and every transition they may take (drivers.base.LinkState):
the console link (drivers/c500c/link.py) and the fast path's (drivers/c500c/server_link.py).
Each link's ``_enter`` refuses any transition not listed here. :class:`LinkLifecycle` is what
both links do alike around their states and the shared reconnector (drivers/reconnect.py).

The console link:

    DISCONNECTED --__aenter__--> CONNECTING --synchronised--> CONNECTED
    CONNECTED --a command cut (cancelled)--> RESYNCHRONISING --probe answered--> CONNECTED
    CONNECTED --link fault--> RECONNECTING --attempt ok--> CONNECTED (motion held)
    RECONNECTING --attempt fails--> wait backoff, try again (first 0.5 s, x2, capped)
    CONNECTED --"Press the PAUSE/CONTINUE..."--> AWAITING_POINT_OF_CONTROL --button--> CONNECTED
    any --__aexit__--> DISCONNECTED
"""

from __future__ import annotations

import asyncio
from types import TracebackType

from drivers.base import LinkState
from drivers.c500c.texts import DEVICE  # the fast path's too (c500c_server_protocol)
from drivers.errors import DeviceTimeoutError
from drivers.reconnect import Reconnector

#: The console link's state machine: every allowed transition (drivers.base.LinkState). A broken
#: link is RECONNECTING, a device-reported fault holds motion instead; FAULT is a reconnection
#: that ended on an unexpected error (drivers/reconnect.py): failed until the link is reopened.
TRANSITIONS: dict[LinkState, frozenset[LinkState]] = {
    LinkState.DISCONNECTED: frozenset({LinkState.CONNECTING}),
    LinkState.CONNECTING: frozenset({LinkState.CONNECTED, LinkState.DISCONNECTED}),
    LinkState.CONNECTED: frozenset(
        {
            LinkState.AWAITING_POINT_OF_CONTROL,
            LinkState.RESYNCHRONISING,
            LinkState.RECONNECTING,
            LinkState.DISCONNECTED,
        }
    ),
    LinkState.AWAITING_POINT_OF_CONTROL: frozenset(
        {
            LinkState.CONNECTED,
            LinkState.RESYNCHRONISING,
            LinkState.RECONNECTING,
            LinkState.DISCONNECTED,
        }
    ),
    LinkState.RESYNCHRONISING: frozenset(
        {
            LinkState.CONNECTED,
            LinkState.AWAITING_POINT_OF_CONTROL,
            LinkState.RECONNECTING,
            LinkState.DISCONNECTED,
        }
    ),
    LinkState.RECONNECTING: frozenset(
        {LinkState.CONNECTED, LinkState.DISCONNECTED, LinkState.FAULT}
    ),
    LinkState.FAULT: frozenset({LinkState.DISCONNECTED}),
}
#: States in which commands can be exchanged.
LINK_UP = frozenset(
    {LinkState.CONNECTED, LinkState.AWAITING_POINT_OF_CONTROL, LinkState.RESYNCHRONISING}
)

#: The fast path link's state machine (drivers.base.LinkState), the console link's without its
#: point-of-control state: the program takes the point of control once, at its start.
SERVER_TRANSITIONS: dict[LinkState, frozenset[LinkState]] = {
    LinkState.DISCONNECTED: frozenset({LinkState.CONNECTING}),
    LinkState.CONNECTING: frozenset({LinkState.CONNECTED, LinkState.DISCONNECTED}),
    LinkState.CONNECTED: frozenset({LinkState.RECONNECTING, LinkState.DISCONNECTED}),
    LinkState.RECONNECTING: frozenset(
        {LinkState.CONNECTED, LinkState.DISCONNECTED, LinkState.FAULT}
    ),
    LinkState.FAULT: frozenset({LinkState.DISCONNECTED}),
}


class LinkLifecycle:
    """The lifecycle both C500C links share: closed on leaving the context, a wait until the
    link is up again, the reconnection attempts counted. Each link's own ``_close`` stops what
    only it owns (the console's resynchronisation task, the fast path's heartbeats) and drops
    its connection; the hold and the motion checks stay each link's own."""

    _reconnector: Reconnector
    #: set while the link is up, cleared by a fault or the close
    _connected_event: asyncio.Event

    async def _close(self) -> None:
        raise NotImplementedError

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        await self._close()

    @property
    def _reconnect_attempts(self) -> int:
        return self._reconnector.attempts

    async def wait_connected(self, timeout_s: float) -> None:
        """Wait until the link is up (after a reconnection); DeviceTimeoutError otherwise."""
        try:
            await asyncio.wait_for(self._connected_event.wait(), timeout_s)
        except TimeoutError as err:
            raise DeviceTimeoutError(DEVICE, f"not reconnected within {timeout_s:g} s") from err
