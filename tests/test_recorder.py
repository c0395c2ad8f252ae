"""The run database: WAL + synchronous=FULL, steps committed one by one, crash marking,
exports."""

import csv
import importlib.util
import io
import json
import math
import sqlite3
import threading
from pathlib import Path

import numpy as np
import pytest

from daemon.storage.recorder import STEP_COLUMNS, Recorder, RecorderError, StepRecord, step_rows

CONTRACT_COLUMNS = [
    "run_id",
    "step",
    "scheduled_s",
    "actual_s",
    "lateness_s",
    "model_time_s",
    "predicted_x_um",
    "predicted_y_um",
    "predicted_z_um",
    "offset_x_mm",
    "offset_y_mm",
    "offset_z_mm",
    "pose_x_mm",
    "pose_y_mm",
    "pose_z_mm",
    "centroid_x_px",
    "centroid_y_px",
    "centroid_x_um",
    "centroid_y_um",
    "drift_x_um",
    "drift_y_um",
    "residual_um",
    "ir_json",
    "flags",
    "error",
]


def _record(run_id: int, step: int) -> StepRecord:
    return StepRecord(
        run_id=run_id,
        step=step,
        scheduled_s=float(step),
        actual_s=step + 0.001,
        lateness_s=0.001,
        predicted_x_um=1.5 * step,
        residual_um=0.1 * step,
        ir_json=json.dumps({"link": {"mean_c": 25.0, "max_c": 26.0}}),
        flags="late" if step == 2 else "",
    )


def test_step_columns_start_with_the_contract_columns_in_order() -> None:
    assert list(STEP_COLUMNS[: len(CONTRACT_COLUMNS)]) == CONTRACT_COLUMNS


def test_database_is_wal_with_full_sync(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        db = sqlite3.connect(recorder.path)
        assert db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        db.close()
        # synchronous is per connection: the recorder's own must be FULL (2)
        assert recorder._db.execute("PRAGMA synchronous").fetchone()[0] == 2


def test_steps_round_trip_and_run_ends_with_summary(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({"step_s": 1.0}, {"bench": {}}, {"name": "n"}, "1.0")
        for step in range(5):
            recorder.write_step(_record(run_id, step))
        recorder.finish_run(run_id, "finished", {"n": 5}, None)
        steps = recorder.steps(run_id)
        assert [s.step for s in steps] == list(range(5))
        assert steps[3] == _record(run_id, 3)
        assert recorder.steps(run_id, start=3, limit=1) == [_record(run_id, 3)]
        row = recorder.run(run_id)
        assert row is not None
        assert (row.state, row.summary, row.step_count) == ("finished", {"n": 5}, 5)
        assert row.parameters == {"step_s": 1.0} and row.network == {"name": "n"}


def test_a_long_read_never_holds_up_the_next_step(tmp_path: Path) -> None:
    """Reads have their own connection (WAL): a step commits while a read is in progress (as
    the API's or the end-of-run summary's may be), and the read sees its own snapshot."""
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({}, {}, None, "1.0")
        recorder.write_step(_record(run_id, 0))
        with recorder._read() as db:  # a read transaction left open
            assert [row["step"] for row in step_rows(db, run_id)] == [0]  # its snapshot starts
            writer = threading.Thread(target=recorder.write_step, args=(_record(run_id, 1),))
            writer.start()
            writer.join(timeout=30)  # a liveness bound, not a timing claim: it would deadlock
            assert not writer.is_alive(), "the step's commit waited for the read"
            assert [row["step"] for row in step_rows(db, run_id)] == [0]  # and holds
        assert [s.step for s in recorder.steps(run_id)] == [0, 1]
        assert recorder.run_steps(run_id).n_steps == 2


def test_a_step_is_recorded_once(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({}, {}, None, "1.0")
        recorder.write_step(_record(run_id, 0))
        with pytest.raises(RecorderError):
            recorder.write_step(_record(run_id, 0))
        assert len(recorder.steps(run_id)) == 1  # the failed insert left nothing behind


def test_runs_left_live_are_marked_interrupted_on_open(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        live = recorder.create_run({}, {}, None, "1.0", state="running")
        recorder.write_step(_record(live, 0))
        done = recorder.create_run({}, {}, None, "1.0")
        recorder.finish_run(done, "finished", None, None)
    with Recorder(tmp_path) as reopened:
        assert reopened.interrupted_runs == [live]
        live_row, done_row = reopened.run(live), reopened.run(done)
        assert live_row is not None and done_row is not None
        assert live_row.state == "interrupted" and done_row.state == "finished"
        assert reopened.steps(live) == [_record(live, 0)]
        assert [r.id for r in reopened.runs()] == [done, live]  # newest first


def test_csv_export_has_the_contract_header_and_empty_missing_values(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({}, {}, None, "1.0")
        for step in range(3):
            recorder.write_step(_record(run_id, step))
        text = recorder.export_csv(run_id, tmp_path / "steps.csv")
    rows = list(csv.DictReader(io.StringIO(text)))
    assert (tmp_path / "steps.csv").read_text() == text
    assert list(rows[0]) == list(STEP_COLUMNS)
    assert rows[2]["flags"] == "late" and rows[1]["pose_x_mm"] == ""
    assert float(rows[2]["predicted_x_um"]) == 3.0
    assert json.loads(rows[0]["ir_json"])["link"]["max_c"] == 26.0


def test_parquet_export_needs_pyarrow(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({}, {}, None, "1.0")
        recorder.write_step(_record(run_id, 0))
        if importlib.util.find_spec("pyarrow") is None:
            with pytest.raises(RecorderError, match="pyarrow"):
                recorder.export_parquet(run_id, tmp_path / "steps.parquet")
        else:
            recorder.export_parquet(run_id, tmp_path / "steps.parquet")
            assert (tmp_path / "steps.parquet").stat().st_size > 0


def test_frames_are_archived_as_lossless_16_bit_png(tmp_path: Path) -> None:
    import cv2

    image = (np.arange(40 * 30, dtype=np.uint16) * 50).reshape(30, 40)
    with Recorder(tmp_path) as recorder:
        relative = recorder.archive_frame(3, 7, image)
    restored = cv2.imread(str(tmp_path / relative), cv2.IMREAD_UNCHANGED)
    assert restored.dtype == np.uint16 and np.array_equal(restored, image)


def test_unwritable_directory_is_a_recorder_error(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    with pytest.raises(RecorderError, match="cannot open"):
        Recorder(blocker / "data")


def test_nan_values_survive_as_null_free_floats(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({}, {}, None, "1.0")
        record = _record(run_id, 0)
        record.residual_um = None
        record.model_time_s = 0.0
        recorder.write_step(record)
        (back,) = recorder.steps(run_id)
    assert back.residual_um is None and back.model_time_s == 0.0
    assert not math.isnan(back.scheduled_s)


def test_one_process_at_a_time_per_data_directory(tmp_path: Path) -> None:
    # a second recorder would mark the first one's live run interrupted
    with Recorder(tmp_path) as first:
        first.create_run({}, {}, None, "1.0", state="running")
        with pytest.raises(RecorderError, match="in use by another thermocomp process"):
            Recorder(tmp_path)
        (run,) = first.runs()
        assert run.state == "running"
    with Recorder(tmp_path) as after:
        assert after.interrupted_runs == [run.id]


def test_a_database_of_an_older_version_gains_the_new_columns(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({}, {}, None, "0.9")
        recorder.write_step(_record(run_id, 0))
        # an older schema: without the newest extra column
        recorder._db.execute("ALTER TABLE steps DROP COLUMN stage_ms_json")
    with Recorder(tmp_path) as reopened:
        reopened.write_step(_record(run_id, 1))
        assert [s.step for s in reopened.steps(run_id)] == [0, 1]


def test_parquet_export_is_written_batch_by_batch_with_stable_types(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Batches smaller than the run, the first all-null in a column a later one fills: the
    file has every step, each column with its table type."""
    pq = pytest.importorskip("pyarrow.parquet")
    import daemon.storage.recorder as recorder_module

    monkeypatch.setattr(recorder_module, "EXPORT_BATCH_STEPS", 3)
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({}, {}, None, "1.0")
        for step in range(8):
            record = _record(run_id, step)
            if step < 3:
                record.residual_um = None
            recorder.write_step(record)
        recorder.export_parquet(run_id, tmp_path / "steps.parquet")
    file = pq.ParquetFile(tmp_path / "steps.parquet")
    assert file.metadata.num_row_groups == 3
    table = file.read()
    assert table.column_names == list(STEP_COLUMNS)
    assert table.column("step").to_pylist() == list(range(8))
    residual = table.column("residual_um").to_pylist()
    assert residual[:3] == [None] * 3 and residual[7] == pytest.approx(0.7)
    assert str(table.schema.field("residual_um").type) == "double"


SECRET_CONFIG = {
    "api": {"control_token": "clear-control-secret", "read_token": "clear-read-secret"},
    "robot": {"port": "/dev/ttyUSB0"},
}


def test_run_rows_never_store_the_tokens(tmp_path: Path) -> None:
    with Recorder(tmp_path) as recorder:
        run_id = recorder.create_run({}, SECRET_CONFIG, None, "1.0")
        row = recorder.run(run_id)
    assert row is not None
    assert row.config["api"] == {"control_token": "<redacted>", "read_token": "<redacted>"}
    assert row.config["robot"]["port"] == "/dev/ttyUSB0"
    assert b"clear-" not in (tmp_path / "thermocomp.sqlite3").read_bytes()


def test_a_database_with_clear_tokens_is_redacted_when_opened(tmp_path: Path) -> None:
    """Migration: a database written by an older version, tokens in clear in config_json."""
    with Recorder(tmp_path) as recorder:
        old = recorder.create_run({}, {}, None, "0.1.0")
        unset = recorder.create_run({}, {"api": {"control_token": None}}, None, "0.1.0")
    with sqlite3.connect(tmp_path / "thermocomp.sqlite3") as db:  # as the old version wrote
        db.execute("UPDATE runs SET config_json = ? WHERE id = ?", (json.dumps(SECRET_CONFIG), old))
        (clear,) = db.execute("SELECT config_json FROM runs WHERE id = ?", (old,)).fetchone()
    assert "clear-control-secret" in clear
    with Recorder(tmp_path) as recorder:
        row, other = recorder.run(old), recorder.run(unset)
    assert row is not None and other is not None
    assert row.config["api"]["control_token"] == "<redacted>"
    assert row.config["api"]["read_token"] == "<redacted>"
    assert other.config["api"]["control_token"] is None  # unset stays unset
    with sqlite3.connect(tmp_path / "thermocomp.sqlite3") as db:
        stored = [text for (text,) in db.execute("SELECT config_json FROM runs")]
    assert not any("clear-" in text for text in stored)
