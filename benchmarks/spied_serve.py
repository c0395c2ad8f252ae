"""``thermocomp serve`` as it runs in production (api/cli.py, real uvicorn), with a spy on the
robot links' serial writers (issue 26): every chunk handed to a port's writer is appended to a
log file as ``<time.monotonic()> <link> <hex>`` (the monotonic clock is the machine's, shared
with the benchmark's client processes). benchmarks/bench_stop.py reads it to find every motion
command and when it went out.

Usage: ``python benchmarks/spied_serve.py LOG_FILE serve --config ... --port ...``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from drivers.c500c import link as console_link
from drivers.c500c import server_link


def install(log_path: Path) -> None:
    log = log_path.open("a", buffering=1, encoding="ascii")

    def wrap(opener: Any, name: str) -> Any:
        async def open_spied(*args: Any, **kwargs: Any) -> tuple[Any, Any]:
            reader, writer = await opener(*args, **kwargs)
            write = writer.write

            def spied(data: bytes) -> None:
                log.write(f"{time.monotonic():.6f} {name} {bytes(data).hex()}\n")
                write(data)

            writer.write = spied
            return reader, writer

        return open_spied

    console_link.open_serial = wrap(console_link.open_serial, "console")  # type: ignore[attr-defined]
    server_link.open_serial = wrap(server_link.open_serial, "server")  # type: ignore[attr-defined]


def main() -> int:
    install(Path(sys.argv[1]))
    from api.cli import main as cli_main

    return cli_main(sys.argv[2:])


if __name__ == "__main__":
    sys.exit(main())
