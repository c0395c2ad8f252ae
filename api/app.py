"""The FastAPI application, built from the settings by :func:`create_app`."""

from fastapi import FastAPI

from api.routers import health
from config import Settings
from daemon import __version__

API_PREFIX = "/api/v1"


def create_app(settings: Settings) -> FastAPI:
    """An application bound to ``settings``; routers per resource under ``/api/v1``."""
    app = FastAPI(
        title="thermocomp",
        version=__version__,
        description="Thermal-deformation compensation daemon for robot links.",
    )
    app.state.settings = settings
    app.include_router(health.router, prefix=API_PREFIX)
    return app
