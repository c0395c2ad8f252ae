"""Runs: start one, list them, follow one, pause/resume/stop it, read its steps and report."""

from __future__ import annotations

import importlib.util
import logging
import sqlite3
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, Query, Response
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, JSONResponse, StreamingResponse
from pydantic import (
    AfterValidator,
    BaseModel,
    Field,
    GetJsonSchemaHandler,
    ValidationError,
    create_model,
    field_validator,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema

from api.broadcast import json_safe
from api.deps import ControlAccess, DaemonDep, ReadAccess, SettingsDep
from api.errors import ApiError, ErrorBody
from daemon.arm.arm_model import ArmModelNotFoundError, named_arm_model_path
from daemon.arm.duty import available_duty_cycles
from daemon.exports import CHUNK_STEPS, Chunk, csv_chunk, json_chunk
from daemon.model import available_presets
from daemon.model.presets import NETWORK_NAME, NetworkNotFoundError, named_network_path
from daemon.recorder import Recorder, RecorderError, RunRow
from daemon.report_queue import ReportStatus
from daemon.runs import RunParameters, RunState, RunStateError
from daemon.service import Daemon, RunConflictError
from drivers.errors import DeviceError

logger = logging.getLogger(__name__)

read_router = APIRouter(tags=["runs"], dependencies=[ReadAccess])
control_router = APIRouter(
    tags=["runs"],
    dependencies=[ControlAccess],
    responses={
        409: {"model": ErrorBody, "description": "the run's state does not allow it"},
        429: {"model": ErrorBody, "description": "too many control requests"},
    },
)

RunId = Annotated[int, PathParam(ge=1, le=2**62, description="Run id.")]


def _optional_fields() -> dict[str, Any]:
    """RunParameters' fields, each optional: what a request leaves out comes from the config.

    Over the API ``network`` is a NAME, never a path (a path would let a client make the
    daemon read any file): an installed preset or an identified network saved in the data
    directory (GET /networks lists both); the schema gives the name's pattern and the presets
    as examples. A malformed name is a 422, an unknown one a 404."""
    fields: dict[str, Any] = {}
    for name, info in RunParameters.model_fields.items():
        annotation: Any = info.annotation
        if name == "network":
            annotation = Annotated[
                str,
                Field(
                    pattern=f"^{NETWORK_NAME.pattern}$",
                    max_length=64,
                    examples=available_presets(),
                ),
            ]
            fields[name] = (
                annotation | None,
                Field(
                    None,
                    description="A preset or an identified network saved in the data "
                    "directory, by name (GET /networks); never a path.",
                ),
            )
            continue
        if name == "arm_model":  # likewise a name (identify --save), never a path
            fields[name] = (
                Annotated[str, Field(pattern=f"^{NETWORK_NAME.pattern}$", max_length=64)] | None,
                Field(None, description=info.description),
            )
            continue
        if name == "duty_cycle":  # likewise a preset (config/duty), never a path
            annotation = Literal[tuple(available_duty_cycles()) or ("",)]
        elif info.metadata:
            annotation = Annotated[(annotation, *info.metadata)]
        fields[name] = (annotation | None, Field(None, description=info.description))
    return fields


def _no_boolean(value: Any) -> Any:
    """No run parameter is a boolean, and the schema says so: ``true`` for a number (which
    pydantic's lax mode would take as 1.0) is refused, as the schema's types promise."""
    if isinstance(value, bool):
        raise ValueError("a boolean is not a valid value here")
    return value


RunRequest: type[BaseModel] = create_model(
    "RunRequest",
    __config__={"extra": "forbid", "allow_inf_nan": False},
    __doc__="Run parameters (issue 6); every field left out takes the configured default.",
    __validators__={"no_boolean": field_validator("*", mode="before")(_no_boolean)},
    **_optional_fields(),
)


class RunInfo(BaseModel):
    id: int
    state: str
    reason: str | None
    started_at: float = Field(description="Unix time (s).")
    ended_at: float | None
    parameters: dict[str, Any]
    steps_recorded: int
    progress_percent: float = Field(description="Run clock elapsed over the duration, in %.")
    remaining_s: float = Field(description="Run-clock seconds left (0 once it has ended).")
    eta_s: float | None = Field(
        description="Estimated wall-clock seconds left, from the progress so far."
    )
    summary: dict[str, Any] | None = Field(description="Thesis Table 6.1 figures, at the end.")
    links: dict[str, str]


class RunPage(BaseModel):
    runs: list[RunInfo] = Field(description="Newest first.")
    limit: int
    offset: int
    next_offset: int | None


def _links(run_id: int) -> dict[str, str]:
    base = f"/api/v1/runs/{run_id}"
    links = {
        "self": base,
        "steps_json": f"{base}/steps?format=json",
        "steps_csv": f"{base}/steps?format=csv",
        "report": f"{base}/report",
    }
    if parquet_available():
        links["steps_parquet"] = f"{base}/steps?format=parquet"
    return links


def run_info(row: RunRow, daemon: Daemon) -> RunInfo:
    """A run as recorded, with the live progress when it is the daemon's current run (read
    from its frozen view: what the daemon knows is newer than the database, e.g. the end of a
    run that the disk could not record yet)."""
    view = daemon.run
    live = view if view is not None and view.id == row.id else None
    parameters = row.parameters
    duration = float(parameters.get("duration_s") or 1.0)
    step_s = float(parameters.get("step_s") or 0.0)
    state, reason, summary = row.state, row.reason, row.summary
    remaining: float
    if live is not None:
        state, reason = live.state.value, live.reason
        summary = live.summary if live.summary is not None else summary
        progress, remaining = live.progress(daemon.clock.now())
        remaining = remaining if live.is_active else 0.0
    else:
        # not running here: what it recorded is how far it got (a stopped run stays short)
        progress = min(100.0, 100.0 * row.step_count * step_s / duration)
        remaining = 0.0
    eta: float | None = None
    if live is not None and live.is_active and 0.0 < progress < 100.0:
        elapsed_wall = time.time() - row.started_at
        eta = elapsed_wall * (100.0 - progress) / progress
    elif live is None or not live.is_active:
        eta = 0.0  # ended
    return RunInfo(
        id=row.id,
        state=state,
        reason=reason,
        started_at=row.started_at,
        ended_at=row.ended_at,
        parameters=json_safe(parameters),
        steps_recorded=row.step_count,
        progress_percent=progress,
        remaining_s=remaining,
        eta_s=eta,
        summary=json_safe(summary),
        links=_links(row.id),
    )


def _recorder(daemon: Daemon) -> Recorder:
    if daemon.recorder is None:
        raise ApiError(503, "unavailable", "the run database is not open")
    return daemon.recorder


async def _row(daemon: Daemon, run_id: int) -> RunRow:
    try:
        row = await daemon.read(_recorder(daemon).run, run_id)
    except RecorderError as err:
        raise ApiError(503, "storage", str(err)) from err
    if row is None:
        raise ApiError(404, "not-found", f"no run {run_id}")
    return row


def _validation_details(err: ValidationError) -> list[dict[str, str]]:
    return [
        {
            "field": ".".join(["body", *(str(p) for p in item["loc"])]),
            "message": str(item["msg"]).removeprefix("Value error, "),
            "type": str(item["type"]),
        }
        for item in err.errors()
    ]


@control_router.post(
    "/runs",
    status_code=201,
    responses={
        400: {"model": ErrorBody, "description": "the body is not readable (e.g. not UTF-8)"},
        404: {"model": ErrorBody, "description": "no network or arm model of that name"},
        422: {"model": ErrorBody, "description": "parameters not admissible"},
    },
)
async def start_run(
    daemon: DaemonDep,
    settings: SettingsDep,
    request: Annotated[RunRequest | None, Body()] = None,
) -> RunInfo:
    """Start a run; 409 while another one is active; 422 with field-level messages when the
    parameters are invalid or not admissible (e.g. the scaled deformation leaves the chip)."""
    given = {} if request is None else request.model_dump(exclude_none=True)
    if "network" in given:
        try:
            named_network_path(given["network"], settings.storage.data_dir)
        except NetworkNotFoundError as err:
            raise ApiError(404, "not-found", str(err)) from err
        except ValueError as err:
            details = [{"field": "body.network", "message": str(err), "type": "value_error"}]
            raise ApiError(422, "validation", str(err), details) from err
    if "arm_model" in given:
        try:
            named_arm_model_path(given["arm_model"], settings.storage.data_dir)
        except ArmModelNotFoundError as err:
            raise ApiError(404, "not-found", str(err)) from err
        except ValueError as err:
            details = [{"field": "body.arm_model", "message": str(err), "type": "value_error"}]
            raise ApiError(422, "validation", str(err), details) from err
    try:
        parameters = RunParameters.from_settings(settings, **given)
    except ValidationError as err:
        details = _validation_details(err)
        summary = "; ".join(f"{d['field']}: {d['message']}" for d in details[:5])
        raise ApiError(422, "validation", f"invalid run parameters: {summary}", details) from err
    try:
        info = await daemon.start_run(parameters)
    except RunConflictError as err:
        raise ApiError(409, "conflict", str(err)) from err
    except ValueError as err:  # RunParameterError, and model/network errors of the check
        details = [{"field": "body", "message": str(err), "type": "not_admissible"}]
        raise ApiError(422, "not-admissible", str(err), details) from err
    except RecorderError as err:
        raise ApiError(503, "storage", str(err)) from err
    return run_info(await _row(daemon, int(info["id"])), daemon)


@read_router.get("/runs")
async def list_runs(
    daemon: DaemonDep,
    limit: Annotated[int, Query(ge=1, le=200)] = 20,
    offset: Annotated[int, Query(ge=0, le=2**31)] = 0,
) -> RunPage:
    """Runs, newest first, ``limit`` per page."""
    try:
        rows = await daemon.read(_recorder(daemon).runs, limit, offset)
    except RecorderError as err:
        raise ApiError(503, "storage", str(err)) from err
    return RunPage(
        runs=[run_info(row, daemon) for row in rows],
        limit=limit,
        offset=offset,
        next_offset=offset + limit if len(rows) == limit else None,
    )


@read_router.get("/runs/{run_id}", responses={404: {"model": ErrorBody}})
async def get_run(run_id: RunId, daemon: DaemonDep) -> RunInfo:
    """Parameters, state, progress in percent and estimated time left, summary when ended."""
    return run_info(await _row(daemon, run_id), daemon)


def _current(daemon: Daemon, run_id: int) -> None:
    run = daemon.run
    if run is None or run.id != run_id or not run.is_active:
        raise ApiError(409, "conflict", f"run {run_id} is not the active run")


@control_router.post("/runs/{run_id}/pause", responses={404: {"model": ErrorBody}})
async def pause_run(run_id: RunId, daemon: DaemonDep) -> RunInfo:
    """Pause the active run (the robot stays at its last compensated pose)."""
    await _row(daemon, run_id)
    _current(daemon, run_id)
    try:
        await daemon.pause()
    except RunStateError as err:
        raise ApiError(409, "conflict", str(err)) from err
    return run_info(await _row(daemon, run_id), daemon)


@control_router.post("/runs/{run_id}/resume", responses={404: {"model": ErrorBody}})
async def resume_run(run_id: RunId, daemon: DaemonDep) -> RunInfo:
    """Resume a paused or faulted run; the actual pose is read back first."""
    await _row(daemon, run_id)
    _current(daemon, run_id)
    try:
        await daemon.resume()
    except RunStateError as err:
        raise ApiError(409, "conflict", str(err)) from err
    except DeviceError as err:
        raise ApiError(503, "device", f"resume failed: {err}") from err
    return run_info(await _row(daemon, run_id), daemon)


@control_router.post("/runs/{run_id}/stop", responses={404: {"model": ErrorBody}})
async def stop_run(run_id: RunId, daemon: DaemonDep) -> RunInfo:
    """Stop the active run: the robot holds where it is, the recording is committed; answers
    once the run has ended."""
    await _row(daemon, run_id)
    _current(daemon, run_id)
    try:
        await daemon.stop()
    except RunStateError as err:
        raise ApiError(409, "conflict", str(err)) from err
    return run_info(await _row(daemon, run_id), daemon)


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
#: stream chunk by chunk (daemon/exports.py's CHUNK_STEPS), encoded in export processes.
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
    """The run's step records (daemon/recorder.py's StepRecord columns) from step ``from``, at
    most ``limit``: JSON ``{"run_id", "steps": [...], "next_from"}`` (1,000 steps per answer
    by default, at most 5,000; ``next_from`` is the next page's ``from``, null at the end),
    CSV (streamed, all steps unless ``limit``) or Parquet (the whole run, written batch by
    batch; only with the ``parquet`` extra)."""
    await _row(daemon, run_id)
    recorder = _recorder(daemon)
    if format == "parquet":
        return await _parquet(daemon, recorder, run_id)
    # every chunk is read and encoded in an export process (daemon/exports.py): never by this
    # process, whose control loop would wait for the GIL meanwhile (issue 15, point 6)
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
    while True:
        if chunk.data:
            yield (b"," if sent else b"") + chunk.data
        sent += chunk.count
        if chunk.next_start is None or sent >= page:
            break
        try:
            chunk = await daemon.export(
                json_chunk, database, run_id, chunk.next_start, min(CHUNK_STEPS, page - sent)
            )
        except (sqlite3.Error, OSError):
            logger.exception("run %d: JSON page cut short", run_id)
            return  # the client sees JSON that does not parse: never a silent short page
    next_from = "null" if chunk.next_start is None else str(chunk.next_start)
    yield f'],"next_from":{next_from}}}'.encode()


async def _csv_stream(
    daemon: Daemon, database: Path, run_id: int, first: Chunk, limit: int | None
) -> AsyncIterator[bytes]:
    chunk = first
    remaining = None if limit is None else limit - chunk.count
    yield chunk.data
    while chunk.next_start is not None and remaining != 0:
        try:
            chunk = await daemon.export(
                csv_chunk, database, run_id, chunk.next_start, _chunk(remaining), False
            )
        except (sqlite3.Error, OSError):
            logger.exception("run %d: CSV export cut short", run_id)
            return
        remaining = None if remaining is None else remaining - chunk.count
        yield chunk.data


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
    being written, 404 when there is none; a request never renders one."""
    row = await _row(daemon, run_id)
    status = daemon.report_status(run_id)
    if status in (ReportStatus.QUEUED, ReportStatus.WRITING):
        message = f"the report of run {run_id} is being written; ask again shortly"
        body = {"status": 202, "kind": "pending", "message": message, "details": None}
        headers = {"Retry-After": str(REPORT_RETRY_AFTER_S)}
        return JSONResponse(body, status_code=202, headers=headers)
    if not RunState(row.state).is_terminal:
        raise ApiError(409, "conflict", f"run {run_id} is {row.state}: no report before it ends")
    html = daemon.reports.html_path(run_id)
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
    recorder = _recorder(daemon)
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
