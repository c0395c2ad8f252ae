"""The permit's ticket of a request that may release a hold, taken when the request ARRIVES
(issue 26): before its body is read, before any dependency, route or lock is awaited.

A start or resume releases only the holds that came before it (drivers/permit.py). The earliest
point this application sees a request is its ASGI call, on the request line and headers: a
hold whose answer the operator has seen was taken before any request that arrives after it,
and after every request that was already in flight -- whose release it therefore wins. One
plain ASGI layer that costs a dictionary look-up on a POST and nothing on other methods.
"""

from __future__ import annotations

from collections.abc import Callable

from starlette.requests import Request
from starlette.types import ASGIApp, Receive, Scope, Send

from drivers.permit import MotionPermit, Ticket

#: Where the ticket is kept in the ASGI scope's state (request.state.motion_ticket).
TICKET_KEY = "motion_ticket"


class TicketAtArrival:
    """Takes ``permit().ticket()`` for every POST as it arrives (no permit: none)."""

    def __init__(self, app: ASGIApp, permit: Callable[[], MotionPermit | None]) -> None:
        self.app = app
        self._permit = permit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] == "POST":
            permit = self._permit()
            if permit is not None:
                scope.setdefault("state", {})[TICKET_KEY] = permit.ticket()
        await self.app(scope, receive, send)


def ticket_of(request: Request) -> Ticket | None:
    """The ticket taken when ``request`` arrived (None: the service takes one now)."""
    ticket = request.scope.get("state", {}).get(TICKET_KEY)
    return ticket if isinstance(ticket, Ticket) else None
