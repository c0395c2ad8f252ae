"""The daemon's own sections: ``[storage]`` and ``[api]``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import Field, StrictBool, model_validator

from config.section import MAX_CONNECTIONS_LIMIT, PositiveFloat, Section


class StorageSettings(Section):
    """Where runs are recorded (SQLite, WAL)."""

    data_dir: Path = Field(Path("data"), description="Folder of the run database and frames.")
    archive_every: Annotated[int, Field(ge=0, le=2**31)] = Field(
        0, description="Archive every N-th frame as a 16-bit PNG; 0 = none."
    )
    report_at_end: StrictBool = Field(
        True,
        description="Write the run's report (HTML + figures) under data_dir/reports at its end.",
    )


class ApiSettings(Section):
    """The REST/WebSocket server."""

    host: str = Field("127.0.0.1", description="Address the API binds to.")
    port: Annotated[int, Field(ge=0, le=65535)] = Field(8000, description="TCP port; 0: any.")
    control_token: str | None = Field(None, description="Bearer token of the `control` scope.")
    read_token: str | None = Field(None, description="Bearer token of the `read` scope.")
    anonymous_read: StrictBool | None = Field(
        None, description="Allow reads without a token; none: only when bound to loopback."
    )
    allowed_hosts: tuple[str, ...] = Field(
        (),
        description="Host names (or addresses) clients may use to reach the API, besides the "
        "loopback names and the bound address: any other Host header is refused with 400 "
        '(DNS rebinding). E.g. ["lab-pc.example.org"].',
    )
    allowed_origins: tuple[str, ...] = Field(
        (),
        description="Origins allowed to open the WebSocket besides those of the allowed hosts "
        '(e.g. "http://lab-pc:8000").',
    )
    max_connections: Annotated[int, Field(ge=8, le=MAX_CONNECTIONS_LIMIT)] = Field(
        256,
        description="Connections served at once (HTTP and WebSocket): a new connection's "
        "first request beyond gets 503, except a request that holds the robot with the control "
        "token; connections that have sent no whole request are not counted (they are bounded "
        "apart, the oldest closed first).",
    )
    request_timeout_s: Annotated[float, Field(gt=0, le=300)] = Field(
        5.0,
        description="Longest time a client may take to send a whole request (headers and body) "
        "from connecting or from its first byte; then the connection is dropped (slowloris).",
    )
    control_rate_per_s: PositiveFloat = Field(
        2.0, description="Average control requests per second per client (429 beyond)."
    )
    control_burst: Annotated[int, Field(ge=1, le=10_000)] = Field(
        10, description="Control requests a client may make at once before the rate applies."
    )
    max_body_bytes: Annotated[int, Field(ge=1024, le=64 * 2**20)] = Field(
        65536, description="Largest request body accepted (bytes; 413 beyond)."
    )
    ws_max_message_bytes: Annotated[int, Field(ge=64, le=2**20)] = Field(
        4096, description="Largest WebSocket message accepted from a client (bytes)."
    )
    ws_queue_messages: Annotated[int, Field(ge=1, le=100_000)] = Field(
        256, description="Messages queued per WebSocket client; a slow client loses the oldest."
    )
    ws_max_clients: Annotated[int, Field(ge=1, le=MAX_CONNECTIONS_LIMIT)] = Field(
        100, description="WebSocket clients served at once; more are refused."
    )
    ws_frame_interval_s: PositiveFloat = Field(
        1.0, description="Shortest interval between two WebSocket frame thumbnails (s)."
    )

    @model_validator(mode="after")
    def _room_beside_websockets(self) -> ApiSettings:
        if self.ws_max_clients >= self.max_connections:
            raise ValueError(
                f"ws_max_clients ({self.ws_max_clients}) must be below max_connections "
                f"({self.max_connections}): requests, the robot hold among them, need room"
            )
        return self
