"""Liveness: is the daemon up, which version, and the state of its device links."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter
from pydantic import BaseModel, Field

from api.deps import ContextDep
from daemon import __version__

router = APIRouter(tags=["health"])


class Health(BaseModel):
    status: Literal["ok", "degraded"] = Field(
        description="ok; degraded when the run database cannot be written (storage)."
    )
    version: str
    daemon: Literal["running", "unavailable"] = Field(
        description="Whether the daemon service is open (devices and recording)."
    )
    devices: dict[str, str] = Field(
        description="Per device: the robot's link state (e.g. connected, reconnecting); the "
        "camera's and IR reader's last grab/read: open (none yet), ok, stale or "
        "'<kind> error' (e.g. timeout error); none when the robot does without it (a UR "
        "followed by its joint temperatures)."
    )
    storage: str = Field(
        "ok",
        description="The run database: ok, or 'failing: <error>' when its latest write failed "
        "(disk full, read-only): nothing new can be recorded until a write succeeds.",
    )


@router.get("/health")
async def health(context: ContextDep) -> Health:
    """Answers as soon as the server listens, without a token (for health checks)."""
    daemon = context.service
    devices: dict[str, str] = {}
    storage = "ok"
    if daemon is not None:
        recorder = daemon.recorder
        failure = None if recorder is None else recorder.write_error
        if failure is not None:
            storage = f"failing: {failure}"
        robot = daemon.snapshot().get("robot")
        if isinstance(robot, dict) and robot.get("link"):
            devices["robot"] = str(robot["link"])
        devices.update(daemon.sensor_states)
    return Health(
        status="ok" if storage == "ok" else "degraded",
        storage=storage,
        version=__version__,
        daemon="unavailable" if daemon is None else "running",
        devices=devices,
    )
