"""Liveness: is the daemon up, and which version is it."""

from typing import Literal

from fastapi import APIRouter
from pydantic import BaseModel

from daemon import __version__

router = APIRouter(tags=["health"])


class Health(BaseModel):
    status: Literal["ok"]
    version: str


@router.get("/health")
async def health() -> Health:
    """Answers as soon as the server listens."""
    return Health(status="ok", version=__version__)
