"""``thermocomp serve``: run the daemon and its API under uvicorn until a signal stops it."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import uvicorn

from api.app import create_app
from config import Settings, load_settings

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


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    """The ``--config`` option every command that needs settings shares."""
    parser.add_argument(
        "--config",
        type=Path,
        help="TOML settings file (default: built-in defaults = the simulated bench); "
        "THERMOCOMP_<SECTION>__<FIELD> environment variables override it",
    )


def with_address(settings: Settings, host: str | None, port: int | None) -> Settings:
    """``settings`` with the command line's --host/--port applied over the file's."""
    update: dict[str, object] = {}
    if host is not None:
        update["host"] = host
    if port is not None:
        update["port"] = port
    if not update:
        return settings
    api = settings.api.model_validate({**settings.api.model_dump(), **update})
    return settings.model_copy(update={"api": api})


def run(args: argparse.Namespace) -> int:
    settings = with_address(load_settings(args.config), args.host, args.port)
    app = create_app(settings)
    server = uvicorn.Server(
        uvicorn.Config(
            app,
            host=settings.api.host,
            port=settings.api.port,
            log_config=None,  # logging is configured once, by the entry point
            access_log=False,
        )
    )
    logger.info("serving on http://%s:%d", settings.api.host, settings.api.port)
    server.run()  # uvicorn installs the SIGINT/SIGTERM handlers and shuts down cleanly
    return 0
