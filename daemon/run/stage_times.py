"""One step's stage timings: each stage's wall time and how far into the step it ended.

The step's lateness budget (issue 30, ``/metrics``): a step is due at its deadline and must be
done before the next one, so what each stage costs is its duration, and what it leaves is
where in the period it ended. The stages run one after the other on the control thread, so
an end is the step's own start plus everything before it, gaps included (scheduler.STAGES
order); the API adds the step's lateness at its start to make it "late past the deadline".
"""

from __future__ import annotations

import time


class StageTimes(dict[str, float]):
    """``stage -> seconds`` it took (a dict: the record's ``stage_ms_json``, TimingStats) and
    :attr:`ends_s`, ``stage -> seconds`` from this object's creation (the step's start) to
    the stage's end, both on ``time.perf_counter``."""

    def __init__(self) -> None:
        super().__init__()
        self.begun = time.perf_counter()
        self.ends_s: dict[str, float] = {}

    def end(self, stage: str, started: float) -> None:
        """``stage`` ran from ``started`` (``time.perf_counter``) until now."""
        now = time.perf_counter()
        self[stage] = now - started
        self.ends_s[stage] = now - self.begun
