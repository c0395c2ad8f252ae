"""``thermocomp serve``'s command line: importing it costs nothing (the server, FastAPI and
the daemon are imported when the command runs, from api/serve.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

from config.cli import add_config_argument, port_number


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "serve",
        help="run the daemon with its REST/WebSocket API",
        description="Run the daemon and serve the REST/WebSocket API and the dashboard. "
        "SIGINT or SIGTERM stops it cleanly.",
    )
    add_config_argument(parser)
    parser.add_argument("--host", help="address to bind (default: api.host of the config)")
    parser.add_argument(
        "--port", type=port_number, help="port to bind (default: api.port; 0 = any)"
    )
    parser.add_argument(
        "--data-dir",
        type=Path,
        help="folder of the run database, reports and saved models (default: "
        "storage.data_dir), as for `thermocomp run --data-dir`",
    )
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    # lazy: FastAPI and uvicorn load when the server starts, not for `serve --help` (issue 16)
    from api import serve

    return serve.run(args)
