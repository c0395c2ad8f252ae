"""``GET /config``: the effective settings, secrets redacted."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from api.deps import ReadAccess, SettingsDep
from config import redact_secrets

router = APIRouter(tags=["config"], dependencies=[ReadAccess])


@router.get("/config")
async def get_config(settings: SettingsDep) -> dict[str, Any]:
    """Every setting in effect (file, environment and defaults merged); a configured token
    shows as ``"<redacted>"``, an unset one as null."""
    dumped: dict[str, Any] = redact_secrets(settings.model_dump(mode="json"))
    return dumped
