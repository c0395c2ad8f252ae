"""Step exports encoded in worker processes (daemon/storage/exports.py): the same records as the
recorder's own reads, in bounded chunks that join into the whole run."""

from __future__ import annotations

import asyncio
import csv
import io
import json
import math
from pathlib import Path

from daemon.run.workers import Workers
from daemon.storage.exports import csv_chunk, json_chunk
from daemon.storage.recorder import (
    DATABASE_NAME,
    STEP_COLUMNS,
    Recorder,
    StepRecord,
    write_steps_csv,
)

STEPS = 25


def _recorded_run(data_dir: Path) -> tuple[int, list[StepRecord]]:
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run({}, {}, None, "test")
        for step in range(STEPS):
            recorder.write_step(
                StepRecord(
                    run_id=run_id,
                    step=step,
                    scheduled_s=float(step),
                    actual_s=step + 1e-3,
                    lateness_s=1e-3,
                    residual_um=math.nan if step == 3 else 0.1 * step,
                    flags="late" if step == 7 else "",
                )
            )
        return run_id, recorder.steps(run_id)


def test_json_chunks_join_into_the_whole_run_with_nan_as_null(tmp_path: Path) -> None:
    run_id, records = _recorded_run(tmp_path)
    database = tmp_path / DATABASE_NAME
    parts, counts, start = [], [], 0
    while True:
        chunk = json_chunk(database, run_id, start, 10)
        parts.append(chunk.data.decode())
        counts.append(chunk.count)
        if chunk.next_start is None:
            break
        start = chunk.next_start
    assert counts == [10, 10, 5]
    steps = json.loads("[" + ",".join(parts) + "]")
    assert [s["step"] for s in steps] == list(range(STEPS))
    assert steps[3]["residual_um"] is None and steps[4]["residual_um"] == records[4].residual_um
    assert list(steps[0]) == list(STEP_COLUMNS) and steps[7]["flags"] == "late"


def test_csv_chunks_equal_the_recorders_csv(tmp_path: Path) -> None:
    run_id, records = _recorded_run(tmp_path)
    database = tmp_path / DATABASE_NAME
    first = csv_chunk(database, run_id, 0, 20, True)
    rest = csv_chunk(database, run_id, first.next_start or 0, 20, False)
    assert (first.count, first.next_start, rest.count, rest.next_start) == (20, 20, 5, None)
    expected = io.StringIO()
    write_steps_csv(records, expected)
    assert (first.data + rest.data).decode() == expected.getvalue()
    assert len(list(csv.reader(io.StringIO(expected.getvalue())))) == STEPS + 1


async def test_exports_run_in_a_worker_process(tmp_path: Path) -> None:
    run_id, _ = _recorded_run(tmp_path)
    workers = Workers()
    try:
        chunk = await workers.export(json_chunk, tmp_path / DATABASE_NAME, run_id, 0, 5)
    finally:
        await asyncio.to_thread(workers.shutdown)
    assert chunk.count == 5 and chunk.next_start == 5
