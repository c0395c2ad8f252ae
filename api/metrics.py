"""Prometheus metrics of one application, in a registry of its own (not the global default,
so two apps in one process, as in the tests, never collide). They are fed from the daemon's
step and error events as the relay (api.relay) hands them on.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from daemon.run.gc_policy import GcPolicy

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

#: Stage lateness buckets (s): where in the step a stage ended, past its deadline: the 20 ms
#: step's sub-millisecond stages to a 10 min step (scheduler.MAX_PERIOD_S).
STAGE_LATENESS_BUCKETS = (
    0.0005,
    0.001,
    0.002,
    0.005,
    0.01,
    0.015,
    0.02,
    0.03,
    0.05,
    0.1,
    0.25,
    0.5,
    1.0,
    5.0,
    60.0,
    600.0,
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
        self.stage_lateness = Histogram(
            "thermocomp_stage_lateness_seconds",
            "How late past the step's deadline each stage ended: the step's lateness at its "
            "start plus its stages until this one's end (the step overran when record's is past "
            "thermocomp_step_period_seconds).",
            ["stage"],
            buckets=STAGE_LATENESS_BUCKETS,
            registry=registry,
        )
        self.step_period = Gauge(
            "thermocomp_step_period_seconds",
            "The running run's step period: the budget every step's stages share.",
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

        #: the daemon's collector policy while it is served (api/app.py serving)
        self.gc_policy: GcPolicy | None = None
        registry.register(_GcCollector(self))

    def observe_step(self, record: Mapping[str, Any], new_overruns: int = 0) -> None:
        """Feed one step event (the "Step record" columns, and daemon/run/publish.py's
        ``stage_s``, ``stage_lateness_s``, ``step_period_s`` and ``serial_round_trips_s``; a
        record alone gives its stage times from ``stage_ms_json``) and the overruns the
        scheduler counted since the previous step."""
        self.steps.inc()
        if new_overruns > 0:
            self.overruns.inc(new_overruns)
        lateness = record.get("lateness_s")
        if isinstance(lateness, int | float) and math.isfinite(lateness):
            self.step_lateness.observe(max(float(lateness), 0.0))
        if "stage_s" in record:  # the step event's: the record stage's own time too
            durations = _finite_seconds(record["stage_s"])
        else:
            durations = {
                k: ms / 1000.0 for k, ms in _stages_ms(record.get("stage_ms_json")).items()
            }
        for stage, seconds in durations.items():
            self.stage_duration.labels(stage=stage).observe(seconds)
        for stage, seconds in _finite_seconds(record.get("stage_lateness_s")).items():
            self.stage_lateness.labels(stage=stage).observe(seconds)
        period = record.get("step_period_s")
        if isinstance(period, int | float) and math.isfinite(period) and period > 0:
            self.step_period.set(float(period))
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
    return _finite_seconds(raw)


def _finite_seconds(raw: object) -> dict[str, float]:
    """A ``{stage: number}`` mapping's finite numbers not below zero (anything else is no
    sample: a stage neither lasts nor ends before its step's deadline)."""
    if not isinstance(raw, Mapping):
        return {}
    return {
        str(stage): float(value)
        for stage, value in raw.items()
        if isinstance(value, int | float) and math.isfinite(value) and value >= 0
    }


#: The quantiles of the recent garbage collection pauses exposed (1 = the largest).
GC_PAUSE_QUANTILES = (0.5, 0.99, 1.0)


class _GcCollector(Collector):
    """The process's garbage collections (daemon/run/gc_policy.py's watch), read when scraped."""

    def __init__(self, metrics: ApiMetrics) -> None:
        self._metrics = metrics

    def describe(self) -> list[Metric]:
        return []  # nothing to check against at registration: families come at collect

    def collect(self) -> list[Metric]:
        policy = self._metrics.gc_policy
        if policy is None:
            return []
        watch = policy.watch
        collections = CounterMetricFamily(
            "thermocomp_gc_collections",
            "Garbage collections of the daemon's process, by generation (2 = full).",
            labels=["generation"],
        )
        in_step = CounterMetricFamily(
            "thermocomp_gc_collections_in_step",
            "Of them, those that ran while a step was under way.",
            labels=["generation"],
        )
        pauses = GaugeMetricFamily(
            "thermocomp_gc_pause_seconds",
            "How long the recent collections stopped the process (the last 10,000 of each "
            "generation), by quantile (1 = the longest).",
            labels=["generation", "quantile"],
        )
        for generation in range(3):
            label = str(generation)
            collections.add_metric([label], watch.collections[generation])
            in_step.add_metric([label], watch.in_step[generation])
            recent = np.fromiter(tuple(watch.pauses_s[generation]), dtype=np.float64)
            if recent.size:
                for quantile, value in zip(
                    GC_PAUSE_QUANTILES,
                    np.quantile(recent, GC_PAUSE_QUANTILES),
                    strict=True,
                ):
                    pauses.add_metric([label, f"{quantile:g}"], float(value))
        between = CounterMetricFamily(
            "thermocomp_gc_full_between_steps",
            "Full collections the step loop did between steps, with the slack for them.",
            value=policy.between_steps,
        )
        forced = CounterMetricFamily(
            "thermocomp_gc_full_forced",
            "Full collections the step loop did without the slack for them: deferred too long "
            "(the bound on memory).",
            value=policy.forced,
        )
        return [collections, in_step, pauses, between, forced]
