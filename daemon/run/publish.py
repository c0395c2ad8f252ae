"""What a run's session tells the rest of the daemon after each change it made: the state and
step events, the frame for live views, the run's frozen view (daemon/run/readmodel.py) for the API,
and the state persisted in order on the recorder's one thread.

RunSession (daemon/run/session.py) makes every change and then calls this; nothing here changes
the run's state (issue 15): it only reads the views and records it is given.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from daemon.run.events import Event
from daemon.run.readmodel import RunView
from daemon.run.services import SessionServices
from daemon.run.states import RunState
from daemon.run.step import StepOutcome

logger = logging.getLogger(__name__)


class RunPublisher:
    """One run's outlets: the event bus, the daemon's read model, the recorder's run row."""

    def __init__(self, run_id: int, services: SessionServices) -> None:
        self._run_id = run_id
        self._services = services

    def state(self, view: RunView) -> None:
        """The state event, then the new view."""
        self._services.bus.publish(
            Event("state", {"run_id": view.id, "state": view.state.value, "reason": view.reason})
        )
        self._services.read_model.set_view(view)

    def persist_state(self, state: RunState, reason: str | None) -> None:
        """Write the state on the recorder's thread: the writes queue there in the order of the
        changes; a failed write is logged and noted, never raised into the run."""
        services = self._services
        write = services.workers.db(
            services.recorder.set_run_state, self._run_id, state.value, reason
        )
        write.add_done_callback(self._state_written)

    def step(self, outcome: StepOutcome, record: dict[str, Any], view: RunView) -> None:
        """A committed step: its timing, the event, the frame for live views, the new view."""
        services = self._services
        services.timing.add(outcome.record.lateness_s, outcome.stages_s)
        services.bus.publish(
            Event("step", {**record, "serial_round_trips_s": outcome.round_trips_s})
        )
        if outcome.frame is not None:  # for live views; a reference, no copy
            frame = outcome.frame
            services.bus.publish(
                Event(
                    "frame",
                    {
                        "run_id": self._run_id,
                        "step": outcome.record.step,
                        "image": frame.image,
                        "bit_depth": frame.bit_depth,
                        "timestamp_s": frame.timestamp_s,
                        "centroid_x_px": outcome.record.centroid_x_px,
                        "centroid_y_px": outcome.record.centroid_y_px,
                    },
                )
            )
        for camera in outcome.views:  # an arm step: every tool camera's frame
            services.bus.publish(
                Event(
                    "frame",
                    {
                        "run_id": self._run_id,
                        "step": outcome.record.step,
                        "image": camera.image,
                        "camera": camera.camera,
                        "pose": outcome.record.arm_pose,
                        "markers_px": [list(xy) for xy in camera.markers_px],
                    },
                )
            )
        services.read_model.set_view(view)

    def _state_written(self, write: asyncio.Future[None]) -> None:
        if write.cancelled():
            return
        err = write.exception()
        if err is not None:
            logger.error("run %d: cannot record its state: %s", self._run_id, err)
            self._services.errors.note(err, device="storage")
