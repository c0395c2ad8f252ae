"""``GET /config``: the effective settings, secrets redacted."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from api.deps import ReadAccess, SettingsDep

router = APIRouter(tags=["config"], dependencies=[ReadAccess])

#: Fields whose value is a secret: shown only as whether they are set.
SECRET_SUFFIXES = ("token", "password", "secret")
REDACTED = "<redacted>"


def redact(value: Any) -> Any:
    """``value`` (a settings dump) with every secret field's value replaced."""
    if isinstance(value, dict):
        return {
            key: (
                REDACTED
                if key.lower().endswith(SECRET_SUFFIXES) and item is not None
                else redact(item)
            )
            for key, item in value.items()
        }
    if isinstance(value, list):
        return [redact(item) for item in value]
    return value


@router.get("/config")
async def get_config(settings: SettingsDep) -> dict[str, Any]:
    """Every setting in effect (file, environment and defaults merged); a configured token
    shows as ``"<redacted>"``, an unset one as null."""
    dumped: dict[str, Any] = redact(settings.model_dump(mode="json"))
    return dumped
