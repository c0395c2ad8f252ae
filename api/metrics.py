"""Prometheus metrics of one application, in a registry of its own (not the global default,
so two apps in one process, as in the tests, never collide). They are fed from the daemon's
step and error events as the relay (api.relay) hands them on.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

#: Step lateness buckets (s): from the 20 ms step's sub-millisecond goal to 10 s.
LATENESS_BUCKETS = (
    0.0001,
    0.00025,
    0.0005,
    0.001,
    0.002,
    0.005,
    0.01,
    0.02,
    0.05,
    0.1,
    0.25,
    0.5,
    1.0,
    2.5,
    10.0,
)
#: Stage and serial buckets (s): from 100 µs to a slow 60 s move.
DURATION_BUCKETS = (
    0.0001,
    0.0005,
    0.001,
    0.0025,
    0.005,
    0.01,
    0.025,
    0.05,
    0.1,
    0.25,
    0.5,
    1.0,
    5.0,
    60.0,
)


class ApiMetrics:
    """Every metric of issue 7; ``registry`` is what ``/metrics`` exposes."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=True)
        registry = self.registry
        self.step_lateness = Histogram(
            "thermocomp_step_lateness_seconds",
            "How late each step began after its deadline.",
            buckets=LATENESS_BUCKETS,
            registry=registry,
        )
        self.stage_duration = Histogram(
            "thermocomp_stage_duration_seconds",
            "Wall time of each stage of a step (model, move, frame = grab, centroid, ir, record).",
            ["stage"],
            buckets=DURATION_BUCKETS,
            registry=registry,
        )
        self.serial_round_trip = Histogram(
            "thermocomp_serial_round_trip_seconds",
            "Round trip of one robot console command (sent until its prompt came back).",
            buckets=DURATION_BUCKETS,
            registry=registry,
        )
        self.steps = Counter(
            "thermocomp_steps", "Steps recorded since the API started.", registry=registry
        )
        self.overruns = Counter(
            "thermocomp_overruns",
            "Steps that ran past the next deadline (the missed deadlines were skipped).",
            registry=registry,
        )
        self.device_errors = Counter(
            "thermocomp_device_errors",
            "Errors reported by the devices, by device and kind.",
            ["device", "kind"],
            registry=registry,
        )
        self.websocket_clients = Gauge(
            "thermocomp_websocket_clients", "WebSocket clients connected.", registry=registry
        )
        self.websocket_dropped = Counter(
            "thermocomp_websocket_dropped_messages",
            "Messages dropped from slow WebSocket clients' queues.",
            registry=registry,
        )
        self.websocket_refused = Counter(
            "thermocomp_websocket_refused",
            "WebSocket connections refused, by reason.",
            ["reason"],
            registry=registry,
        )

    def observe_step(self, record: Mapping[str, Any], new_overruns: int = 0) -> None:
        """Feed one step record (the "Step record" columns plus ``stage_ms_json``) and the
        overruns the scheduler counted since the previous step."""
        self.steps.inc()
        if new_overruns > 0:
            self.overruns.inc(new_overruns)
        lateness = record.get("lateness_s")
        if isinstance(lateness, int | float) and math.isfinite(lateness):
            self.step_lateness.observe(max(float(lateness), 0.0))
        for stage, milliseconds in _stages_ms(record.get("stage_ms_json")).items():
            self.stage_duration.labels(stage=stage).observe(milliseconds / 1000.0)
        for seconds in record.get("serial_round_trips_s") or ():
            self.serial_round_trip.observe(float(seconds))

    def observe_error(self, error: Mapping[str, Any]) -> None:
        device = str(error.get("device") or "daemon")
        self.device_errors.labels(device=device, kind=str(error.get("kind") or "error")).inc()


def _stages_ms(raw: object) -> dict[str, float]:
    if isinstance(raw, str) and raw:
        try:
            raw = json.loads(raw)
        except ValueError:
            return {}
    if not isinstance(raw, Mapping):
        return {}
    return {
        str(stage): float(ms)
        for stage, ms in raw.items()
        if isinstance(ms, int | float) and math.isfinite(ms) and ms >= 0
    }
