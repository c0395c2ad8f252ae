"""The FastAPI application, built from the settings by :func:`create_app`."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from contextlib import AbstractAsyncContextManager, AsyncExitStack, asynccontextmanager
from pathlib import Path

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

from api.broadcast import Hub
from api.deps import ApiContext
from api.errors import COMMON_ERROR_RESPONSES, install_error_handlers
from api.limits import BodySizeLimit
from api.metrics import ApiMetrics
from api.relay import Relay
from api.routers import configuration, devices, health, metrics, networks, runs, state, ws
from api.security import Authenticator, RateLimiter
from config import Settings
from daemon import __version__
from daemon.service import Daemon

API_PREFIX = "/api/v1"
STATIC_DIR = Path(__file__).resolve().parent / "static"
SWAGGER_UI = "/static/vendor/swagger-ui"

#: Builds the daemon service from the settings; entered at startup, left at shutdown.
ServiceFactory = Callable[[Settings], AbstractAsyncContextManager[Daemon]]


def create_app(settings: Settings, service_factory: ServiceFactory | None = None) -> FastAPI:
    """An application bound to ``settings``; routers per resource under ``/api/v1``.

    ``service_factory`` builds the daemon service the routes drive; the application's
    lifespan opens it at startup and closes it at shutdown. Without one (tests of the parts
    that need no daemon) the routes that need it answer 503.
    """
    api_metrics = ApiMetrics()
    context = ApiContext(
        settings=settings,
        auth=Authenticator(settings.api),
        control_limiter=RateLimiter(settings.api.control_rate_per_s, settings.api.control_burst),
        hub=Hub(settings.api.ws_queue_messages, on_drop=api_metrics.websocket_dropped.inc),
        metrics=api_metrics,
    )

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        async with AsyncExitStack() as stack:
            relay: asyncio.Task[None] | None = None
            if service_factory is not None:
                daemon = await stack.enter_async_context(service_factory(settings))
                context.service = daemon
                relay = asyncio.create_task(Relay(daemon, context).run(), name="api-relay")
            try:
                yield
            finally:
                context.service = None
                if relay is not None:
                    relay.cancel()
                    with contextlib.suppress(asyncio.CancelledError):
                        await relay

    app = FastAPI(
        title="thermocomp",
        version=__version__,
        description="Thermal-deformation compensation daemon for robot links: runs, steps, "
        "devices, errors. Reads need the `read` scope (or anonymous reads on loopback), "
        "control needs the `control` scope: `Authorization: Bearer <token>`.",
        lifespan=lifespan,
        responses=COMMON_ERROR_RESPONSES,
        docs_url=None,  # served from vendored files below: lab PCs are often offline
        redoc_url=None,
    )
    app.state.context = context
    install_error_handlers(app)
    app.add_middleware(BodySizeLimit, max_bytes=settings.api.max_body_bytes)
    for router in (
        health.router,
        state.read_router,
        state.control_router,
        runs.read_router,
        runs.control_router,
        configuration.router,
        networks.router,
        devices.router,
        ws.router,
    ):
        app.include_router(router, prefix=API_PREFIX)
    app.include_router(metrics.router)
    _mount_dashboard(app)
    return app


def _mount_dashboard(app: FastAPI) -> None:
    """The single-page dashboard at ``/`` and its files (no build step) under ``/static``."""
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.get("/", include_in_schema=False)
    async def dashboard() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", media_type="text/html")

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        """Swagger UI from the vendored copy in static/vendor (no CDN)."""
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title="thermocomp API",
            swagger_js_url=f"{SWAGGER_UI}/swagger-ui-bundle.js",
            swagger_css_url=f"{SWAGGER_UI}/swagger-ui.css",
            swagger_favicon_url=f"{SWAGGER_UI}/favicon-32x32.png",
        )
