"""``GET /metrics``: Prometheus text exposition of this application's registry."""

from __future__ import annotations

from fastapi import APIRouter, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from api.deps import ContextDep, ReadAccess

router = APIRouter(tags=["metrics"], dependencies=[ReadAccess])


@router.get("/metrics", response_class=Response)
async def metrics(context: ContextDep) -> Response:
    """Step lateness, stage durations, serial round trips, device errors, WebSocket clients and
    dropped messages, steps and overruns."""
    return Response(generate_latest(context.metrics.registry), media_type=CONTENT_TYPE_LATEST)
