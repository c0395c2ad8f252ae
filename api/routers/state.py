"""``GET /state`` (everything the daemon knows now), ``GET /errors``, ``POST /robot/stop``."""

from __future__ import annotations

import json
import time
from typing import Annotated, Any

from fastapi import APIRouter, Query, Response
from pydantic import BaseModel, Field

from api.broadcast import json_safe
from api.deps import ApiContext, ContextDep, ControlAccess, DaemonDep, ReadAccess
from api.errors import ApiError, ErrorBody
from daemon.service import Daemon
from drivers.errors import DeviceError

read_router = APIRouter(tags=["state"], dependencies=[ReadAccess])
control_router = APIRouter(
    tags=["robot"],
    dependencies=[ControlAccess],
    responses={429: {"model": ErrorBody, "description": "too many control requests"}},
)

#: A /state answer is reused while the run's state, step and errors are unchanged, for at most
#: this long, so polling clients cost the control loop little (the percentiles are not free).
STATE_CACHE_S = 0.1


class StateSnapshot(BaseModel):
    """The daemon's state (idle, starting, running, paused, stopping, fault), its current or
    last run with progress, the last step record, the robot link, timing statistics (lateness
    and stage percentiles in s, overruns) and the recent errors."""

    state: str
    run: dict[str, Any] | None
    last_step: dict[str, Any] | None
    robot: dict[str, Any] | None
    timing: dict[str, Any]
    errors: list[dict[str, Any]]
    websocket_clients: int = Field(description="WebSocket clients connected now.")


class ErrorEntryModel(BaseModel):
    time: float = Field(description="Unix time (s).")
    device: str
    kind: str
    message: str


class ErrorList(BaseModel):
    errors: list[ErrorEntryModel] = Field(description="Newest first.")


class HoldResult(BaseModel):
    held: bool
    state: str = Field(description="The daemon's state after the hold.")


def snapshot_json(context: ApiContext, daemon: Daemon) -> bytes:
    """The snapshot as JSON bytes, from the cache while nothing it shows has changed."""
    version = (context.event_count, daemon.view_version, len(daemon.errors), len(context.hub))
    cache = context.extras.get("state_cache")
    now = time.monotonic()
    if isinstance(cache, tuple) and cache[0] == version and now - cache[1] < STATE_CACHE_S:
        body: bytes = cache[2]
        return body
    snapshot = {**daemon.snapshot(), "websocket_clients": len(context.hub)}
    body = json.dumps(json_safe(snapshot), separators=(",", ":"), default=str).encode()
    context.extras["state_cache"] = (version, now, body)
    return body


@read_router.get("/state", response_model=StateSnapshot)
async def get_state(context: ContextDep, daemon: DaemonDep) -> Response:
    return Response(snapshot_json(context, daemon), media_type="application/json")


@read_router.get("/errors")
async def get_errors(
    daemon: DaemonDep, limit: Annotated[int, Query(ge=1, le=1000)] = 100
) -> ErrorList:
    """Recent device and daemon errors (time, device, kind, message), newest first."""
    entries = list(daemon.errors)[-limit:]
    return ErrorList(errors=[ErrorEntryModel(**json_safe(e.as_dict())) for e in reversed(entries)])


@control_router.post("/robot/stop")
async def stop_robot(daemon: DaemonDep) -> HoldResult:
    """Hold the robot where it is now, whatever the run state (a running run pauses, a
    starting one is cancelled). Answers ``held`` once the robot driver refuses every motion
    command: no motion command can be written any more. What that does to a motion already
    under way depends on the link (docs/explanation/holds.md)."""
    try:
        await daemon.hold_robot()
    except DeviceError as err:
        raise ApiError(503, "device", f"could not hold the robot: {err}") from err
    return HoldResult(held=True, state=str(daemon.snapshot()["state"]))
