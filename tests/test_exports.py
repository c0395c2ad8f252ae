"""Step exports encoded in worker processes (daemon/storage/exports.py,
daemon/storage/step_text.py): the same records as the recorder's own reads, in bounded chunks that
join into the whole run, as Python's csv module and json.dumps write them (the oracles), awkward
values included."""

from __future__ import annotations

import asyncio
import csv
import dataclasses
import io
import json
import math
import sqlite3
from pathlib import Path

import pytest

from daemon.run.workers import Workers
from daemon.storage.exports import csv_chunk, json_chunk
from daemon.storage.recorder import (
    DATABASE_NAME,
    STEP_COLUMNS,
    Recorder,
    StepRecord,
)
from daemon.storage.step_text import _json_strings, csv_lines, json_objects, step_text

STEPS = 25


#: values whose text is easy to get wrong: shortest round-trip digits (16 and 17), an
#: exponent, infinities, text to quote in CSV and escape in JSON
AWKWARD: dict[int, dict[str, object]] = {
    5: {"pose_x_mm": 1.2345678901234568e17, "pose_y_mm": 1e-05, "pose_z_mm": 1e16},
    6: {"drift_x_um": math.inf, "drift_y_um": -math.inf, "centroid_x_px": 1 / 3},
    8: {"error": 'camera: "no frame", retried\nthen gave up', "flags": "late,stale-frame"},
    9: {"ir_json": '{"link": {"mean_c": 21.5}}', "frame_path": "frames/1/9.png"},
    11: {"error": "tab\there, a \\ backslash and \u00e9"},
}


def _recorded_run(data_dir: Path) -> tuple[int, list[StepRecord]]:
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run({}, {}, None, "test")
        for step in range(STEPS):
            recorder.write_step(
                dataclasses.replace(
                    StepRecord(
                        run_id=run_id,
                        step=step,
                        scheduled_s=float(step),
                        actual_s=step + 1e-3,
                        lateness_s=1e-3,
                        residual_um=math.nan if step == 3 else 0.1 * step,
                        flags="late" if step == 7 else "",
                    ),
                    **AWKWARD.get(step, {}),
                )
            )
        return run_id, recorder.steps(run_id)


def _python_csv(records: list[StepRecord]) -> str:
    """The oracle: Python's csv module, empty cell for a missing value, repr for floats."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(STEP_COLUMNS)
    for record in records:
        writer.writerow("" if v is None else v for v in dataclasses.astuple(record))
    return text.getvalue()


def _python_json(record: StepRecord) -> dict[str, object]:
    """The oracle: the record's fields, non-finite numbers as null."""
    return {
        k: None if isinstance(v, float) and not math.isfinite(v) else v
        for k, v in dataclasses.asdict(record).items()
    }


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
    text = "[" + ",".join(parts) + "]"
    steps = json.loads(text)
    assert steps == [_python_json(r) for r in records]
    assert "Infinity" not in text and "NaN" not in text  # strict JSON
    assert [s["step"] for s in steps] == list(range(STEPS))
    assert steps[3]["residual_um"] is None and steps[4]["residual_um"] == records[4].residual_um
    assert list(steps[0]) == list(STEP_COLUMNS) and steps[7]["flags"] == "late"


def test_csv_chunks_equal_the_recorders_csv(tmp_path: Path) -> None:
    run_id, records = _recorded_run(tmp_path)
    database = tmp_path / DATABASE_NAME
    first = csv_chunk(database, run_id, 0, 20, True)
    rest = csv_chunk(database, run_id, first.next_start or 0, 20, False)
    assert (first.count, first.next_start, rest.count, rest.next_start) == (20, 20, 5, None)
    expected = _python_csv(records)
    assert (first.data + rest.data).decode() == expected
    rows = list(csv.reader(io.StringIO(expected)))
    assert len(rows) == STEPS + 1
    # every float reads back as the same double
    pose = STEP_COLUMNS.index("pose_x_mm")
    assert float(rows[6][pose]) == 1.2345678901234568e17
    assert rows[7][STEP_COLUMNS.index("drift_x_um")] == "inf"


def test_the_recorders_csv_is_the_exports(tmp_path: Path) -> None:
    run_id, records = _recorded_run(tmp_path)
    with Recorder(tmp_path) as recorder:
        assert recorder.export_csv(run_id) == _python_csv(records)


def test_an_empty_or_finished_range(tmp_path: Path) -> None:
    run_id, _ = _recorded_run(tmp_path)
    database = tmp_path / DATABASE_NAME
    past = csv_chunk(database, run_id, STEPS + 10, 5, True)
    assert (past.data.decode(), past.count, past.next_start) == (
        ",".join(STEP_COLUMNS) + "\n",
        0,
        None,
    )
    exact = json_chunk(database, run_id, STEPS - 5, 5)
    # a full chunk cannot know it was the last: the next one is empty
    assert (exact.count, exact.next_start) == (5, STEPS)
    assert json_chunk(database, run_id, STEPS, 5).count == 0


async def test_exports_run_in_a_worker_process(tmp_path: Path) -> None:
    run_id, _ = _recorded_run(tmp_path)
    workers = Workers()
    try:
        chunk = await workers.export(json_chunk, tmp_path / DATABASE_NAME, run_id, 0, 5)
    finally:
        await asyncio.to_thread(workers.shutdown)
    assert chunk.count == 5 and chunk.next_start == 5


#: values whose CSV layout the msgspec path rewrites (exponents, a decimal point at -4)
LAYOUTS: dict[int, dict[str, object]] = {
    12: {"lateness_s": 5e-05, "actual_s": 12.00005, "pose_x_mm": -1.5e-05, "pose_y_mm": 1e-07},
    13: {"pose_x_mm": 1e16, "pose_y_mm": 1e22, "pose_z_mm": 5e-324, "offset_x_mm": -0.0},
    14: {"ir_json": '{"n": 1e-5, "m": null, "k": "0.00001"}', "error": "100% null, 50%"},
}


def test_the_csv_is_the_old_encoders_byte_for_byte(tmp_path: Path) -> None:
    """csv_lines (msgspec prints the numbers) against step_text's CSV (repr prints them), on a
    run with missing cells, NaN (stored as NULL), infinities, quotes, commas, line feeds, %
    and numbers in every layout, chunk by chunk and whole."""
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({}, {}, None, "test")
        for step in range(STEPS):
            recorder.write_step(
                dataclasses.replace(
                    StepRecord(
                        run_id=run_id,
                        step=step,
                        scheduled_s=float(step),
                        actual_s=step + 1e-3,
                        lateness_s=1e-3,
                        residual_um=math.nan if step == 3 else 0.1 * step,
                    ),
                    **AWKWARD.get(step, {}),
                    **LAYOUTS.get(step, {}),
                )
            )
    db = sqlite3.connect(tmp_path / DATABASE_NAME)
    try:
        for start, count in ((0, None), (0, 7), (7, 7), (14, 20), (STEPS, 5)):
            new, found, last = csv_lines(db, run_id, start, count)
            old, old_found, old_last = step_text(db, run_id, start, count, json=False)
            assert (new.decode(), found, last) == (old, old_found, old_last)
        assert csv_lines(db, run_id, 12, 1)[0].count(b"e-05") == 2  # the layouts were there
    finally:
        db.close()


#: values to break a JSON encoder: every kind of missing or non-finite number, integers at the
#: 64-bit edge (the step numbers) and beyond a double's 53 bits (in REAL columns and in text),
#: text SQLite must escape (controls, quotes, backslashes, U+2028, astral characters, NUL)
HOSTILE: dict[int, dict[str, object]] = {
    15: {"pose_x_mm": math.nan, "pose_y_mm": math.inf, "pose_z_mm": -math.inf, "room_c": None},
    16: {"predicted_x_um": 2**53 + 1, "predicted_y_um": -(2**62), "predicted_z_um": 10**18},
    17: {"ir_json": '{"big": 123456789012345678901234567890, "tiny": 1e-400}', "flags": ""},
    18: {"error": "note: \u00e9\u0301 \u05e9\u05dc\u05d5\u05dd \U0001f321\ufe0f \u2028 \x01\x1f"},
    19: {
        "error": 'a "quoted" \\ back\\slash, a tab\t and a NUL \x00 inside',
        "arm_pose": "p\u00b2",
    },
    20: {"observer_json": '{"heat": [1.0, 0.05]}', "frame_path": "frames/\u6e29\u5ea6.png"},
}


def _hostile_run(data_dir: Path) -> int:
    with Recorder(data_dir) as recorder:
        run_id = recorder.create_run({}, {}, None, "test")
        for step in [*range(STEPS), 2**62, 2**63 - 1]:
            recorder.write_step(
                dataclasses.replace(
                    StepRecord(
                        run_id=run_id,
                        step=step,
                        scheduled_s=float(step),
                        actual_s=step + 1e-3,
                        lateness_s=1e-3,
                        residual_um=math.nan if step == 3 else 0.1 * step,
                    ),
                    **AWKWARD.get(step, {}),
                    **LAYOUTS.get(step, {}),
                    **HOSTILE.get(step, {}),
                )
            )
    return run_id


def test_the_json_is_the_old_encoders_byte_for_byte(tmp_path: Path) -> None:
    """json_objects (the CSV's column-at-a-time path, msgspec prints the numbers) against
    step_text's JSON (a % per row, repr prints them) on hostile values, chunk by chunk and
    whole; the text is strict JSON that reads back as the recorder's own records."""
    run_id = _hostile_run(tmp_path)
    db = sqlite3.connect(tmp_path / DATABASE_NAME)
    try:
        for start, count in ((0, None), (0, 7), (7, 7), (14, 20), (STEPS, 5), (2**62, 1)):
            new, found, last = json_objects(db, run_id, start, count)
            old, old_found, old_last = step_text(db, run_id, start, count, json=True)
            assert (new.decode(), found, last) == (old, old_found, old_last)
        whole = json_objects(db, run_id, 0, None)[0].decode()
    finally:
        db.close()
    with Recorder(tmp_path) as recorder:
        records = recorder.steps(run_id)
    steps = json.loads("[" + whole + "]", parse_constant=pytest.fail)
    assert steps == [_python_json(r) for r in records]
    assert [s["step"] for s in steps[-2:]] == [2**62, 2**63 - 1]
    assert steps[16]["predicted_x_um"] == float(2**53 + 1) and "\u2028" in steps[18]["error"]
    assert steps[15]["pose_x_mm"] is None and steps[15]["pose_y_mm"] is None


def test_text_is_escaped_as_sqlites_json_quote_escapes_it() -> None:
    """The JSON's text cells (msgspec) against SQLite's json_quote, which the row-at-a-time
    encoder used: every code point, alone and between others."""
    db = sqlite3.connect(":memory:")
    try:
        points = [*range(0xD800), *range(0xE000, 0x110000, 17), 0x10FFFF]
        texts = ["a" + chr(p) + "\\" + chr(p) for p in points] + ["", '"', "\x00\x7f"]
        quoted = [db.execute("SELECT json_quote(?)", (t,)).fetchone()[0] for t in texts]
    finally:
        db.close()
    escaped = _json_strings(texts)
    wrong = [(t, q, e) for t, q, e in zip(texts, quoted, escaped, strict=True) if q.encode() != e]
    assert not wrong, wrong[:5]
    assert _json_strings([None]) == [b"null"]
