"""The FastAPI application, built from the settings by :func:`create_app`."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator, Callable
from contextlib import AbstractAsyncContextManager, AsyncExitStack, asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, Request, Response
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles
from starlette.routing import Route

from api.broadcast import Hub
from api.deps import ApiContext, require_read_now
from api.errors import COMMON_ERROR_RESPONSES, ApiError, install_error_handlers
from api.metrics import ApiMetrics
from api.middleware import Gate
from api.openapi import install_openapi
from api.relay import Relay
from api.routers import (
    arm_models,
    budget,
    configuration,
    devices,
    health,
    kinds,
    metrics,
    networks,
    run_data,
    runs,
    state,
    ws,
)
from api.security import Authenticator, HostAllowList, RateLimiter
from api.tickets import TicketAtArrival
from config import ConfigError, Settings
from config.cli import EXIT_DEVICE, EXIT_USAGE
from config.inputs import InputError, one_line
from daemon import __version__
from daemon.service import Daemon
from daemon.storage.recorder import RecorderError
from drivers.errors import DeviceError
from drivers.permit import MotionPermit

API_PREFIX = "/api/v1"
STATIC_DIR = Path(__file__).resolve().parent / "static"
SWAGGER_UI = "/static/vendor/swagger-ui"

logger = logging.getLogger(__name__)


class DaemonStartFailed(Exception):
    """The daemon could not open its devices or recording; already logged in one line (the
    traceback uvicorn would log is dropped by api.startup's log filter). ``status`` is the
    exit status it asks of ``serve``: 3 for a device, 2 for a file or name of the settings."""

    def __init__(self, message: str, status: int = EXIT_DEVICE) -> None:
        super().__init__(message)
        self.status = status


#: Builds the daemon service from the settings; entered at startup, left at shutdown.
ServiceFactory = Callable[[Settings], AbstractAsyncContextManager[Daemon]]


def create_app(settings: Settings, service_factory: ServiceFactory | None = None) -> FastAPI:
    """An application bound to ``settings``; routers per resource under ``/api/v1``.

    ``service_factory`` builds the daemon service the routes drive; the application's
    lifespan opens it at startup and closes it at shutdown. Without one (tests of the parts
    that need no daemon) the routes that need it answer 503.
    """
    api_metrics = ApiMetrics()
    api = settings.api
    context = ApiContext(
        settings=settings,
        auth=Authenticator(api),
        control_limiter=RateLimiter(api.control_rate_per_s, api.control_burst),
        hosts=HostAllowList(api),
        hub=Hub(settings.api.ws_queue_messages, on_drop=api_metrics.websocket_dropped.inc),
        metrics=api_metrics,
    )

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        if service_factory is None:
            yield
            return
        async with AsyncExitStack() as stack:
            daemon = await open_service(stack, settings, service_factory)
            async with serving(context, daemon):
                yield

    app = FastAPI(
        title="thermocomp",
        version=__version__,
        description="Thermal-deformation compensation daemon for robot links: runs, steps, "
        "devices, errors. Reads need the `read` scope (or none where anonymous reads are on: "
        "by default when bound to loopback), control needs the `control` scope: "
        "`Authorization: Bearer <token>`. HEAD is answered wherever GET is.",
        lifespan=lifespan,
        responses=COMMON_ERROR_RESPONSES,
        docs_url=None,  # served from vendored files below: lab PCs are often offline
        redoc_url=None,
    )
    app.state.context = context
    install_error_handlers(app)
    app.add_middleware(
        Gate,  # Host allow-list, OPTIONS, HEAD, body limit, security headers: one layer
        hosts=context.hosts,
        routes=app.router.routes,
        max_body_bytes=api.max_body_bytes,
        api_prefixes=(API_PREFIX, "/metrics", "/openapi.json"),
    )
    # outermost: a start's or resume's ticket is taken before the Gate reads its body
    app.add_middleware(TicketAtArrival, permit=lambda: _permit(context))
    for router in (
        health.router,
        state.read_router,
        state.control_router,
        runs.read_router,
        runs.control_router,
        run_data.read_router,
        configuration.router,
        networks.router,
        arm_models.router,
        kinds.router,
        budget.router,
        devices.router,
        ws.router,
    ):
        app.include_router(router, prefix=API_PREFIX)
    app.include_router(metrics.router)
    _mount_dashboard(app)
    app.router.routes.insert(0, _polled_state_route(context))
    install_openapi(app, context.auth.anonymous_read)
    return app


async def open_service(
    stack: AsyncExitStack, settings: Settings, service_factory: ServiceFactory
) -> Daemon:
    """Open the daemon (devices, recording) on ``stack``, which closes it; a device or
    recording that fails is logged in one line and raised as :class:`DaemonStartFailed`."""
    try:
        return await stack.enter_async_context(service_factory(settings))
    except InputError as err:
        # a file or name of the settings (network, arm, duty cycle ...) that the start-up
        # checks did not meet: a configuration error, exit 2 -- never 3, which systemd
        # retries forever
        logger.error("cannot start the daemon: %s", one_line(err))
        raise DaemonStartFailed(one_line(err), EXIT_USAGE) from None
    except (DeviceError, RecorderError, ConfigError, OSError) as err:
        # a device that is there but does not answer (the start-up checks, api/startup.py,
        # found it present): one line, not a traceback; `serve` exits with 3, the status of
        # a device failure
        logger.error("cannot start the daemon: %s", err)
        raise DaemonStartFailed(str(err)) from None


@asynccontextmanager
async def serving(context: ApiContext, daemon: Daemon) -> AsyncIterator[None]:
    """The application's routes and WebSocket relay drive ``daemon`` while inside; then they
    answer 503 again (the application's lifespan, or ``thermocomp serve``, which owns the
    daemon itself: api/serve.py)."""
    settings = context.settings
    logger.info("serving on http://%s:%d", settings.api.host, settings.api.port)
    context.service = daemon
    context.metrics.gc_policy = daemon.gc_policy
    relay = asyncio.create_task(Relay(daemon, context).run(), name="api-relay")
    try:
        yield
    finally:
        context.service = None
        context.metrics.gc_policy = None
        relay.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await relay


def _permit(context: ApiContext) -> MotionPermit | None:
    """The robot's permit while the daemon runs with its devices open."""
    daemon = context.service
    try:
        return None if daemon is None else daemon.permit
    except RuntimeError:  # the daemon's devices are not open
        return None


def _polled_state_route(context: ApiContext) -> Route:
    """``GET /api/v1/state`` (documented by api/routers/state.py, same answer and errors) as a
    plain route ahead of the FastAPI ones: dashboards and scripts poll it, and FastAPI's
    dependency solving and included-router matching were a third of each answer's cost
    (issue 16: /state at >= 0.7x the bare stack). Same checks as ReadAccess and DaemonDep."""

    async def polled_state(request: Request) -> Response:
        require_read_now(context, request)
        daemon = context.service
        if daemon is None:
            raise ApiError(503, "unavailable", "the daemon is not running")
        return Response(state.snapshot_json(context, daemon), media_type="application/json")

    return Route(f"{API_PREFIX}/state", polled_state, methods=["GET"], include_in_schema=False)


def _mount_dashboard(app: FastAPI) -> None:
    """The single-page dashboard at ``/`` and its files (no build step) under ``/static``."""
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.get("/", include_in_schema=False)
    async def dashboard() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", media_type="text/html")

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        """Swagger UI from the vendored copy in static/vendor (no CDN), started by a script
        file rather than FastAPI's inline one (the CSP allows no inline script)."""
        return HTMLResponse(DOCS_PAGE)


DOCS_PAGE = f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1.0">
<link type="text/css" rel="stylesheet" href="{SWAGGER_UI}/swagger-ui.css">
<link rel="icon" href="{SWAGGER_UI}/favicon-32x32.png">
<title>thermocomp API</title>
</head>
<body>
<div id="swagger-ui"></div>
<script src="{SWAGGER_UI}/swagger-ui-bundle.js"></script>
<script src="/static/swagger-init.js"></script>
</body>
</html>
"""
