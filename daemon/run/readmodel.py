"""What the API may read of a run: a frozen view, replaced (never changed) by the run's session
at each state change and each recorded step. The API never reads a live run object (issue 15),
so a request can neither see a half-made change nor make one."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

from daemon.run.states import RunParameters, RunState
from drivers.base import RobotStatus


@dataclass(frozen=True, slots=True)
class RunView:
    id: int
    state: RunState
    reason: str | None
    step: int  # last recorded step, -1 before the first
    parameters: RunParameters
    start_s: float = math.nan  # run clock at step 0
    end_s: float = math.nan  # run clock when it ended (its progress stops there)
    summary: dict[str, Any] | None = None
    overruns: int = 0
    skipped: int = 0
    last_record: dict[str, Any] | None = None
    kind: str = ""  # its run kind's name (daemon/run/kinds.py)

    @property
    def is_active(self) -> bool:
        return self.state.is_active

    def progress(self, clock_now: float) -> tuple[float, float]:
        """Percent of the duration elapsed on the run clock, and run-clock seconds left. A
        finished run is complete whenever its last step came: its last step is scheduled one
        step before the duration's end, and it ends when that step is recorded."""
        if self.state is RunState.FINISHED:
            return 100.0, 0.0
        now = clock_now if math.isnan(self.end_s) else min(clock_now, self.end_s)
        elapsed = 0.0 if math.isnan(self.start_s) else max(now - self.start_s, 0.0)
        duration = self.parameters.duration_s
        return min(100.0, 100.0 * elapsed / duration), max(duration - elapsed, 0.0)

    def info(self, clock_now: float) -> dict[str, Any]:
        progress, remaining = self.progress(clock_now)
        return {
            "id": self.id,
            "kind": self.kind,
            "state": self.state.value,
            "reason": self.reason,
            "step": self.step,
            "parameters": self.parameters.model_dump(mode="json"),
            "progress_percent": progress,
            "remaining_s": remaining,
            "summary": self.summary,
        }


class RunReadModel:
    """The one owner of what the API reads of runs: the current or last run's frozen view (and
    its version, which caches key on), and when the control loop last showed it is alive (the
    systemd watchdog, issue 10). Sessions replace the view; the daemon and the API read it."""

    def __init__(self) -> None:
        self.view: RunView | None = None
        self.version = 0
        #: monotonic time of the control loop's last sign of life
        self.last_progress_monotonic = time.monotonic()

    def set_view(self, view: RunView) -> None:
        self.view = view
        self.version += 1

    def progress(self) -> None:
        self.last_progress_monotonic = time.monotonic()

    def control_loop_alive(self, max_silence_s: float) -> bool:
        """For the systemd watchdog (issue 10): False when a running run has recorded no step
        for ``max_silence_s`` beyond its step period, i.e. the control loop hangs."""
        view = self.view
        if view is None or view.state is not RunState.RUNNING:
            return True
        silence_s = time.monotonic() - self.last_progress_monotonic
        return silence_s <= max_silence_s + view.parameters.step_s

    def snapshot(
        self,
        clock_now: float,
        *,
        robot: RobotStatus | None,
        timing: dict[str, Any],
        errors: list[dict[str, Any]],
    ) -> dict[str, Any]:
        """The daemon's state as the API shows it (GET /state, the WebSocket's first message):
        the run's, the robot's ``robot`` status, the steps' ``timing`` and the latest
        ``errors``."""
        view = self.view
        return {
            "state": RunState.IDLE.value
            if view is None or not view.is_active
            else view.state.value,
            "run": None if view is None else view.info(clock_now),
            "last_step": None if view is None else view.last_record,
            "robot": None
            if robot is None
            else {
                "link": robot.link.value,
                "motion_held": robot.motion_held,
                "hold_reason": robot.hold_reason,
                "last_error": robot.last_error,
            },
            "timing": {
                **timing,
                "overruns": 0 if view is None else view.overruns,
                "skipped": 0 if view is None else view.skipped,
            },
            "errors": errors,
        }
