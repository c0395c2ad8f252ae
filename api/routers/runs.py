"""Runs: start one, list them, follow one, pause/resume/stop it (their steps, report and
frames: api/routers/run_data.py)."""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Body, Query, Request
from pydantic import (
    BaseModel,
    Field,
    ValidationError,
    create_model,
    field_validator,
)

from api.broadcast import json_safe
from api.deps import ControlAccess, DaemonDep, ReadAccess, SettingsDep
from api.errors import ApiError, ErrorBody
from api.routers import run_data
from api.tickets import ticket_of
from config.inputs import one_line
from daemon.arm.duty import available_duty_cycles
from daemon.model import available_presets
from daemon.model.presets import NETWORK_NAME
from daemon.run.inputs import check_named_arm_model, check_named_network
from daemon.run.states import RunParameters, RunStateError
from daemon.service import Daemon, RunConflictError
from daemon.storage.recorder import RecorderError, RunRow
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

RunId = run_data.RunId


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
    kind: str | None = Field(
        description="Its run kind's name, as recorded (GET /kinds gives its view); null for a "
        "run recorded before runs said their kind."
    )
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
    summary_pending: bool = Field(
        description="The summary was deferred by a shutdown (its budget within the stop's "
        "timeout ran out) and is computed when the daemon starts next; ``summary`` is null "
        "until then."
    )
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
    if run_data.parquet_available():
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
        kind=live.kind if live is not None else row.kind,
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
        summary_pending=summary is None and row.summary_pending,
        links=_links(row.id),
    )


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
    http_request: Request,
    daemon: DaemonDep,
    settings: SettingsDep,
    request: Annotated[RunRequest | None, Body()] = None,
) -> RunInfo:
    """Start a run; 409 while another one is active; 422 with field-level messages when the
    parameters are invalid or not admissible (e.g. the scaled deformation leaves the chip)."""
    given = {} if request is None else request.model_dump(exclude_none=True)
    for key, check in (("network", check_named_network), ("arm_model", check_named_arm_model)):
        if key not in given:
            continue
        # the named file is loaded, not only found (issue 26: a bad saved network started a
        # run that failed later); on a worker thread: a file and a network's checks
        try:
            await asyncio.to_thread(check, settings, given[key])
        except LookupError as err:  # NetworkNotFoundError, ArmModelNotFoundError
            raise ApiError(404, "not-found", str(err)) from err
        except ValueError as err:  # InputError: a malformed name or a bad file
            message = one_line(err)
            details = [{"field": f"body.{key}", "message": message, "type": "value_error"}]
            raise ApiError(422, "validation", message, details) from err
    try:
        parameters = RunParameters.from_settings(settings, **given)
    except ValidationError as err:
        details = _validation_details(err)
        summary = "; ".join(f"{d['field']}: {d['message']}" for d in details[:5])
        raise ApiError(422, "validation", f"invalid run parameters: {summary}", details) from err
    try:
        info = await daemon.start_run(parameters, ticket_of(http_request))
    except RunConflictError as err:
        raise ApiError(409, "conflict", str(err)) from err
    except ValueError as err:  # RunParameterError, and model/network errors of the check
        details = [{"field": "body", "message": str(err), "type": "not_admissible"}]
        raise ApiError(422, "not-admissible", str(err), details) from err
    except RecorderError as err:
        raise ApiError(503, "storage", str(err)) from err
    return run_info(await run_data.run_row(daemon, int(info["id"])), daemon)


@read_router.get("/runs")
async def list_runs(
    daemon: DaemonDep,
    limit: Annotated[int, Query(ge=1, le=200)] = 20,
    offset: Annotated[int, Query(ge=0, le=2**31)] = 0,
) -> RunPage:
    """Runs, newest first, ``limit`` per page."""
    try:
        rows = await daemon.read(run_data.recorder_of(daemon).runs, limit, offset)
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
    return run_info(await run_data.run_row(daemon, run_id), daemon)


def _current(daemon: Daemon, run_id: int) -> None:
    run = daemon.run
    if run is None or run.id != run_id or not run.is_active:
        raise ApiError(409, "conflict", f"run {run_id} is not the active run")


async def _require_current(daemon: Daemon, run_id: int) -> None:
    """409 unless ``run_id`` is the active run, from the daemon's own view: nothing is read
    from the database before a pause or a stop holds the robot (issue 26); only a run that
    is not the active one is looked up, for its 404."""
    run = daemon.run
    if run is not None and run.id == run_id and run.is_active:
        return
    await run_data.run_row(daemon, run_id)
    _current(daemon, run_id)


async def _answer(daemon: Daemon, run_id: int) -> RunInfo:
    """The run after a control request, read once the robot is held and the request done."""
    return run_info(await run_data.run_row(daemon, run_id), daemon)


@control_router.post("/runs/{run_id}/pause", responses={404: {"model": ErrorBody}})
async def pause_run(run_id: RunId, daemon: DaemonDep) -> RunInfo:
    """Pause the active run: the robot is held where it is (its last compensated pose)."""
    await _require_current(daemon, run_id)
    try:
        await daemon.pause()
    except RunStateError as err:
        raise ApiError(409, "conflict", str(err)) from err
    return await _answer(daemon, run_id)


@control_router.post("/runs/{run_id}/resume", responses={404: {"model": ErrorBody}})
async def resume_run(run_id: RunId, daemon: DaemonDep, request: Request) -> RunInfo:
    """Resume a paused or faulted run; the actual pose is read back first. A hold that came
    after this request arrived wins (409)."""
    ticket = ticket_of(request)  # taken on arrival, before anything is awaited
    await _require_current(daemon, run_id)
    try:
        await daemon.resume(ticket)
    except RunStateError as err:
        raise ApiError(409, "conflict", str(err)) from err
    except DeviceError as err:
        raise ApiError(503, "device", f"resume failed: {err}") from err
    return await _answer(daemon, run_id)


@control_router.post("/runs/{run_id}/stop", responses={404: {"model": ErrorBody}})
async def stop_run(run_id: RunId, daemon: DaemonDep) -> RunInfo:
    """Stop the active run: the robot holds where it is (first, before any database work),
    the recording is committed; answers once the run has ended."""
    await _require_current(daemon, run_id)
    try:
        await daemon.stop()
    except RunStateError as err:
        raise ApiError(409, "conflict", str(err)) from err
    return await _answer(daemon, run_id)
