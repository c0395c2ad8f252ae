"""Request dependencies: what a route may ask for, resolved from the application's state."""

from typing import Annotated

from fastapi import Depends, Request

from config import Settings


def get_settings(request: Request) -> Settings:
    """The settings the application was built with (never a module-level global)."""
    settings: Settings = request.app.state.settings
    return settings


SettingsDep = Annotated[Settings, Depends(get_settings)]
