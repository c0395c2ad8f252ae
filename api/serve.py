"""``thermocomp serve``: run the daemon and its API under uvicorn until a signal stops it."""

from __future__ import annotations

import argparse
import logging

import uvicorn
from pydantic import ValidationError

from api.app import create_app
from config import ConfigError, Settings, load_settings
from config.cli import add_config_argument
from daemon.service import Daemon

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "serve",
        help="run the daemon with its REST/WebSocket API",
        description="Run the daemon and serve the REST/WebSocket API and the dashboard. "
        "SIGINT or SIGTERM stops it cleanly.",
    )
    add_config_argument(parser)
    parser.add_argument("--host", help="address to bind (default: api.host of the config)")
    parser.add_argument("--port", type=int, help="port to bind (default: api.port; 0 = any)")
    parser.set_defaults(handler=run)


def with_address(settings: Settings, host: str | None, port: int | None) -> Settings:
    """``settings`` with the command line's --host/--port applied over the file's."""
    update: dict[str, object] = {}
    if host is not None:
        update["host"] = host
    if port is not None:
        update["port"] = port
    if not update:
        return settings
    try:
        api = settings.api.model_validate({**settings.api.model_dump(), **update})
    except ValidationError as err:
        reasons = "; ".join(f"--{e['loc'][0]}: {e['msg']}" for e in err.errors())
        raise ConfigError(f"command line: {reasons}") from err
    return settings.model_copy(update={"api": api})


def server_config(settings: Settings) -> uvicorn.Config:
    """The uvicorn configuration of the daemon's server: the application's lifespan opens the
    daemon (devices, recording) at startup and closes it at shutdown (robot held, recording
    committed), so the server is "up" only with the daemon."""
    return uvicorn.Config(
        create_app(settings, service_factory=Daemon),
        host=settings.api.host,
        port=settings.api.port,
        log_config=None,  # logging is configured once, by the entry point
        access_log=False,  # step data goes to the recording, not the log
        lifespan="on",  # a daemon that cannot start fails the server's startup
        # the protocol layer refuses larger client messages before buffering them
        ws_max_size=settings.api.ws_max_message_bytes,
        # compressing every step message once per client costs the shared event loop more
        # than the lab network saves (50 clients: milliseconds per step)
        ws_per_message_deflate=False,
        timeout_graceful_shutdown=10,
    )


def run(args: argparse.Namespace) -> int:
    settings = with_address(load_settings(args.config), args.host, args.port)
    server = uvicorn.Server(server_config(settings))
    logger.info("serving on http://%s:%d", settings.api.host, settings.api.port)
    server.run()  # uvicorn installs the SIGINT/SIGTERM handlers and shuts down cleanly
    if not server.started:  # the daemon or the socket could not be opened (logged above)
        return 1
    return 0
