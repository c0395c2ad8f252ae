"""A recorded run's data: its steps (JSON, CSV, Parquet; streamed), its report and its
archived frames. The row lookup and the run id's type are shared with api/routers/runs.py."""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import logging
import sqlite3
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, JSONResponse, StreamingResponse
from pydantic import AfterValidator, BaseModel, Field, GetJsonSchemaHandler
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema

from api.deps import ContextDep, DaemonDep, ReadAccess
from api.errors import ApiError, ErrorBody
from daemon.run.states import RunState
from daemon.service import Daemon
from daemon.storage.exports import CHUNK_STEPS, Chunk, csv_chunk, json_chunk
from daemon.storage.recorder import Recorder, RecorderError, RunRow
from daemon.storage.report_queue import ReportStatus
from daemon.storage.reports import drift_removed_of

logger = logging.getLogger(__name__)

read_router = APIRouter(tags=["runs"], dependencies=[ReadAccess])

RunId = Annotated[int, PathParam(ge=1, le=2**62, description="Run id.")]


def recorder_of(daemon: Daemon) -> Recorder:
    if daemon.recorder is None:
        raise ApiError(503, "unavailable", "the run database is not open")
    return daemon.recorder


async def run_row(daemon: Daemon, run_id: int) -> RunRow:
    try:
        row = await daemon.read(recorder_of(daemon).run, run_id)
    except RecorderError as err:
        raise ApiError(503, "storage", str(err)) from err
    if row is None:
        raise ApiError(404, "not-found", f"no run {run_id}")
    return row


def parquet_available() -> bool:
    """Whether the optional ``parquet`` extra (pyarrow) is installed: only then does this
    server offer (OpenAPI enum, run links) and accept ``format=parquet``."""
    return importlib.util.find_spec("pyarrow") is not None


PARQUET_MISSING = (
    "Parquet export needs the optional `parquet` extra (pyarrow), not installed on this "
    "server: pip install 'thermocomp[parquet]'"
)


def _exportable(value: str) -> str:
    if value == "parquet" and not parquet_available():
        raise ValueError(PARQUET_MISSING)
    return value


class _OfferedFormats:
    """The schema of ``format`` lists only the formats this installation can write, so a
    client (or a fuzzer) reading the OpenAPI description never asks for one it cannot."""

    def __get_pydantic_json_schema__(
        self, core_schema: CoreSchema, handler: GetJsonSchemaHandler
    ) -> JsonSchemaValue:
        schema = handler(core_schema)
        schema["enum"] = [f for f in schema["enum"] if f != "parquet" or parquet_available()]
        return schema


#: ``parquet`` is refused with a 422 naming the missing extra when pyarrow is not installed
StepFormat = Annotated[
    Literal["json", "csv", "parquet"], AfterValidator(_exportable), _OfferedFormats()
]
#: Steps per JSON answer when no limit is given, and at most (``next_from`` continues): ~0.9 kB
#: a step, so 5,000 steps is ~4.5 MB (50,000 were 44 MB and 5 s, issue 16). Both JSON and CSV
#: stream chunk by chunk (daemon/storage/exports.py's CHUNK_STEPS), encoded in export processes.
JSON_PAGE_STEPS = 1_000
JSON_MAX_STEPS = 5_000
#: Steps read and encoded per CSV chunk: a long run's CSV never fills the memory.
CSV_CHUNK_STEPS = CHUNK_STEPS


@read_router.get(
    "/runs/{run_id}/steps",
    responses={
        200: {"content": {"text/csv": {}, "application/vnd.apache.parquet": {}}},
        404: {"model": ErrorBody},
    },
)
async def get_steps(
    run_id: RunId,
    daemon: DaemonDep,
    format: StepFormat = "json",
    start: Annotated[int, Query(alias="from", ge=0, le=2**62, description="First step.")] = 0,
    limit: Annotated[int | None, Query(ge=1, le=10_000_000)] = None,
) -> Response:
    """The run's step records (daemon/storage/recorder.py's StepRecord columns) from step ``from``,
    at most ``limit``: JSON ``{"run_id", "steps": [...], "next_from"}`` (1,000 steps per answer
    by default, at most 5,000; ``next_from`` is the next page's ``from``, null at the end),
    CSV (streamed, all steps unless ``limit``) or Parquet (the whole run, written batch by
    batch; only with the ``parquet`` extra)."""
    await run_row(daemon, run_id)
    recorder = recorder_of(daemon)
    if format == "parquet":
        return await _parquet(daemon, recorder, run_id)
    # every chunk is read and encoded in an export process (daemon/storage/exports.py): never by
    # this process, whose control loop would wait for the GIL meanwhile (issue 15, point 6)
    database = recorder.path
    count = _chunk(limit) if format == "csv" else min(limit or JSON_PAGE_STEPS, JSON_MAX_STEPS)
    try:
        if format == "csv":
            first = await daemon.export(csv_chunk, database, run_id, start, count, True)
        else:
            first = await daemon.export(
                json_chunk, database, run_id, start, min(CHUNK_STEPS, count)
            )
    except (sqlite3.Error, OSError) as err:
        raise ApiError(503, "storage", f"cannot read run {run_id}: {err}") from err
    if format == "csv":
        filename = f"run-{run_id}-steps.csv"
        return StreamingResponse(
            _csv_stream(daemon, database, run_id, first, limit),
            media_type="text/csv",
            headers={"Content-Disposition": f'attachment; filename="{filename}"'},
        )
    return StreamingResponse(
        _json_stream(daemon, database, run_id, first, count), media_type="application/json"
    )


def _chunk(remaining: int | None) -> int:
    return CSV_CHUNK_STEPS if remaining is None else min(CSV_CHUNK_STEPS, remaining)


async def _json_stream(
    daemon: Daemon, database: Path, run_id: int, first: Chunk, page: int
) -> AsyncIterator[bytes]:
    """``{"run_id", "steps": [...], "next_from"}``, the steps chunk by chunk."""
    yield b'{"run_id":%d,"steps":[' % run_id
    chunk, sent = first, 0

    def following(chunk: Chunk, sent: int) -> asyncio.Task[Chunk] | None:
        if chunk.next_start is None or sent >= page:
            return None
        count = min(CHUNK_STEPS, page - sent)
        return asyncio.create_task(
            daemon.export(json_chunk, database, run_id, chunk.next_start, count)
        )

    coming = following(chunk, chunk.count)
    try:
        while True:
            if chunk.data:
                yield (b"," if sent else b"") + chunk.data
            sent += chunk.count
            if coming is None:
                break
            try:
                chunk = await coming
            except (sqlite3.Error, OSError):
                logger.exception("run %d: JSON page cut short", run_id)
                return  # the client sees JSON that does not parse: never a silent short page
            # the export process encodes the next chunk while this one is sent
            coming = following(chunk, sent + chunk.count)
    finally:
        await _drop(coming)
    next_from = "null" if chunk.next_start is None else str(chunk.next_start)
    yield f'],"next_from":{next_from}}}'.encode()


async def _csv_stream(
    daemon: Daemon, database: Path, run_id: int, first: Chunk, limit: int | None
) -> AsyncIterator[bytes]:
    chunk = first
    remaining = None if limit is None else limit - chunk.count

    def following(chunk: Chunk, remaining: int | None) -> asyncio.Task[Chunk] | None:
        if chunk.next_start is None or remaining == 0:
            return None
        return asyncio.create_task(
            daemon.export(csv_chunk, database, run_id, chunk.next_start, _chunk(remaining), False)
        )

    # the export process encodes the next chunk while this one is sent
    coming = following(chunk, remaining)
    try:
        yield chunk.data
        while coming is not None:
            try:
                chunk = await coming
            except (sqlite3.Error, OSError):
                coming = None
                logger.exception("run %d: CSV export cut short", run_id)
                return
            remaining = None if remaining is None else remaining - chunk.count
            coming = following(chunk, remaining)
            yield chunk.data
    finally:
        await _drop(coming)


async def _drop(task: asyncio.Task[Chunk] | None) -> None:
    """A chunk encoded ahead that the client will not get (it left): cancelled, waited for."""
    if task is not None:
        task.cancel()  # a no-op once done; awaiting it then collects its outcome
        with contextlib.suppress(asyncio.CancelledError, sqlite3.Error, OSError):
            await task


async def _parquet(daemon: Daemon, recorder: Recorder, run_id: int) -> Response:
    def export() -> bytes:
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / "steps.parquet"
            recorder.export_parquet(run_id, path)
            return path.read_bytes()

    try:
        data = await daemon.read(export)
    except RecorderError as err:
        raise ApiError(503, "storage", str(err)) from err
    return Response(
        data,
        media_type="application/vnd.apache.parquet",
        headers={"Content-Disposition": f'attachment; filename="run-{run_id}-steps.parquet"'},
    )


#: An active run's "drift removed so far" is recomputed at most this often (s): at a 20 ms
#: step every request would otherwise read the whole run again.
REMOVED_REFRESH_S = 2.0


class DriftRemoved(BaseModel):
    """What the compensation has removed so far (daemon/analysis/removed.py)."""

    run_id: int
    kind: str = Field(description="arm or two-link.")
    steps: int = Field(description="Steps the figures cover (the run's so far).")
    measured: int = Field(description="Of them, steps with a measured error.")
    compensation: str | None
    basis: str = Field(
        description="reference: against the measured drift of the uncompensated reference "
        "run; prediction: no reference run, only the model's prediction; drift: this run is "
        "uncompensated, its error is the drift."
    )
    reference_run: int | None
    span_s: float | None = Field(description="Run time both runs cover (maxima over it).")
    residual_max_um: float | None = Field(description="Largest |error| (arm: 3-D drift).")
    reference_max_um: float | None = Field(description="Reference run's largest drift.")
    removed_percent: float | None = Field(
        description="100 (1 - residual max / reference max), on the reference basis only."
    )
    predicted_max_um: float | None
    vs_prediction_percent: float | None = Field(
        description="Against the model's prediction (not a measured reduction)."
    )
    noise_um: float | None = Field(description="Arm: the 3-D measurement's 1-sigma.")
    rotation: dict[str, float | None] | None = Field(description="Arm: the same, rotation.")
    headline: str = Field(description="One sentence for people.")


@read_router.get("/runs/{run_id}/drift-removed", responses={404: {"model": ErrorBody}})
async def get_drift_removed(run_id: RunId, daemon: DaemonDep, context: ContextDep) -> DriftRemoved:
    """How much drift the compensation has removed so far, against the measured drift of the
    run's uncompensated reference run (its ``reference_run`` parameter) over the time both
    cover; without one, only the model's prediction is stated and nothing is called removed.
    The end-of-run summary's own figures over the steps recorded until now."""
    row = await run_row(daemon, run_id)
    cache: dict[int, tuple[int, float, DriftRemoved]] = context.extras.setdefault(
        "drift_removed", {}
    )
    cached = cache.get(run_id)
    now = time.monotonic()
    active = not RunState(row.state).is_terminal
    if cached is not None and (
        cached[0] == row.step_count or (active and now - cached[1] < REMOVED_REFRESH_S)
    ):
        return cached[2]
    parameters = row.parameters
    reference = parameters.get("reference_run")
    try:
        figures = await daemon.export(
            drift_removed_of,
            recorder_of(daemon).path,
            run_id,
            parameters.get("compensation"),
            int(reference) if isinstance(reference, int) else None,
            active,  # an ended run's sentence says what it removed, not "so far"
        )
    except (sqlite3.Error, OSError) as err:
        raise ApiError(503, "storage", f"cannot read run {run_id}: {err}") from err
    answer = DriftRemoved.model_validate({**figures, "run_id": run_id})
    if len(cache) > 16:
        cache.clear()
    cache[run_id] = (row.step_count, now, answer)
    return answer


#: When to ask again for a report still being written (s).
REPORT_RETRY_AFTER_S = 2


@read_router.get(
    "/runs/{run_id}/report",
    response_class=FileResponse,
    responses={
        200: {"content": {"text/html": {}}},
        202: {"model": ErrorBody, "description": "the report is being written: ask again"},
        404: {"model": ErrorBody, "description": "no report (none written, or no such run)"},
        409: {"model": ErrorBody, "description": "the run has not ended yet"},
    },
)
async def get_report(run_id: RunId, daemon: DaemonDep) -> Response:
    """The analysis report of an ended run (a self-contained HTML page). Only the daemon
    writes reports (storage.report_at_end, or ``thermocomp report RUN``): 202 while it is
    being written; a request never renders one. An ended run without one (never written, or
    its writer killed: a shutdown, a crash) gets it queued now: 202 (issue 26). 404 when
    writing it failed in this daemon's lifetime."""
    row = await run_row(daemon, run_id)
    status = daemon.report_status(run_id)
    ended = RunState(row.state).is_terminal
    html = daemon.reports.html_path(run_id)
    if ended and status is None and row.step_count > 0 and not html.is_file():
        daemon.reports.submit(run_id)  # regenerated on demand, by the daemon's one writer
        status = daemon.report_status(run_id)
    if status in (ReportStatus.QUEUED, ReportStatus.WRITING):
        message = f"the report of run {run_id} is being written; ask again shortly"
        body = {"status": 202, "kind": "pending", "message": message, "details": None}
        headers = {"Retry-After": str(REPORT_RETRY_AFTER_S)}
        return JSONResponse(body, status_code=202, headers=headers)
    if not ended:
        raise ApiError(409, "conflict", f"run {run_id} is {row.state}: no report before it ends")
    if not html.is_file():
        hint = f"`thermocomp report {run_id}` writes one"
        if status is ReportStatus.FAILED:
            hint = f"writing it failed (see the daemon's log); {hint}"
        raise ApiError(404, "not-found", f"no report for run {run_id}: {hint}")
    return FileResponse(html, media_type="text/html")


@read_router.get(
    "/runs/{run_id}/frames/{step}",
    response_class=FileResponse,
    responses={200: {"content": {"image/png": {}}}, 404: {"model": ErrorBody}},
)
async def get_frame(
    run_id: RunId,
    step: Annotated[int, PathParam(ge=0, le=2**62)],
    daemon: DaemonDep,
) -> FileResponse:
    """The archived 16-bit PNG of a step (storage.archive_every), when there is one."""
    recorder = recorder_of(daemon)
    try:
        records = await daemon.read(recorder.steps, run_id, step, 1)
    except RecorderError as err:
        raise ApiError(503, "storage", str(err)) from err
    if not records or records[0].step != step or not records[0].frame_path:
        raise ApiError(404, "not-found", f"no archived frame for run {run_id} step {step}")
    path = (recorder.data_dir / records[0].frame_path).resolve()
    if not path.is_relative_to(recorder.data_dir.resolve()) or not path.is_file():
        raise ApiError(404, "not-found", f"archived frame of run {run_id} step {step} is missing")
    return FileResponse(path, media_type="image/png")
