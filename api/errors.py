"""One JSON shape for every error the API returns: ``{status, kind, message, details}``.

Clients (the dashboard, scripts, curl users) branch on ``kind``, show ``message`` and may read
``details`` (field-level messages of a 422, the retry delay of a 429 ...). A stack trace never
leaves the process: an unexpected exception is logged here and answered with a bare 500.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException as StarletteHTTPException

from api.methods import allowed_methods

logger = logging.getLogger(__name__)

#: ``kind`` of the errors Starlette raises itself (unknown route, wrong method ...).
_KIND_BY_STATUS = {
    400: "bad-request",
    401: "unauthorized",
    403: "forbidden",
    404: "not-found",
    405: "method-not-allowed",
    409: "conflict",
    413: "too-large",
    415: "unsupported-media-type",
    422: "validation",
    429: "rate-limited",
    503: "unavailable",
}


class ErrorBody(BaseModel):
    """The body of every error response."""

    status: int = Field(description="The HTTP status, repeated for clients that lose it.")
    kind: str = Field(description="Stable machine-readable category, e.g. `conflict`.")
    message: str = Field(description="What went wrong, for a person.")
    details: Any = Field(None, description="Structured extras, e.g. field-level messages.")


class ApiError(StarletteHTTPException):
    """An error with a chosen ``kind``; raise it from routes and dependencies.

    It is a Starlette HTTPException so that errors raised while FastAPI reads the body (a body
    over the size limit) keep their status instead of becoming a generic 400.
    """

    def __init__(
        self,
        status: int,
        kind: str,
        message: str,
        details: Any = None,
        headers: dict[str, str] | None = None,
    ) -> None:
        super().__init__(status_code=status, detail=message, headers=headers)
        self.kind = kind
        self.message = message
        self.details = details


def error_response(
    status: int,
    kind: str,
    message: str,
    details: Any = None,
    headers: Mapping[str, str] | None = None,
) -> JSONResponse:
    body = ErrorBody(status=status, kind=kind, message=message, details=details)
    return JSONResponse(
        body.model_dump(mode="json"), status_code=status, headers=dict(headers or {})
    )


def field_errors(error: RequestValidationError) -> list[dict[str, str]]:
    """Pydantic's errors as ``{"field": "body.duration_s", "message": ..., "type": ...}``."""
    fields = []
    for item in error.errors():
        location = ".".join(str(part) for part in item.get("loc", ()))
        message = str(item.get("msg", "invalid")).removeprefix("Value error, ")
        fields.append({"field": location, "message": message, "type": str(item.get("type"))})
    return fields


async def _api_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    if isinstance(exc, ApiError):
        return error_response(exc.status_code, exc.kind, exc.message, exc.details, exc.headers)
    kind = _KIND_BY_STATUS.get(exc.status_code, "error")
    headers = dict(exc.headers or {})
    if exc.status_code == 405:  # every method of the path, not the first route's only
        methods = allowed_methods(request.app.router.routes, request.url.path)
        if methods:
            headers["Allow"] = ", ".join(methods)
    return error_response(exc.status_code, kind, str(exc.detail), None, headers)


def _position(document: object, offset: int) -> str:
    """``line L, column C`` (1-based) of a character offset in the request body."""
    text = (
        document.decode("utf-8", "replace")
        if isinstance(document, bytes | bytearray)
        else str(document)
    )
    before = text[:offset]
    line = before.count("\n") + 1
    column = offset - (before.rfind("\n") + 1) + 1
    return f"line {line}, column {column}"


def _body_problem(request: Request, exc: RequestValidationError) -> str | None:
    """The one thing wrong with the body as a whole, in a curl user's words: not JSON (where),
    or not sent as JSON (the Content-Type to use). None when its fields are the problem."""
    for item in exc.errors():
        if item.get("type") == "json_invalid":
            loc = item.get("loc", ())
            offset = loc[1] if len(loc) > 1 and isinstance(loc[1], int) else 0
            reason = item.get("ctx", {}).get("error", "invalid JSON")
            return f"the body is not valid JSON: {reason} at {_position(exc.body, offset)}"
    content_type = request.headers.get("content-type")
    if request.method in ("POST", "PUT", "PATCH") and any(
        tuple(item.get("loc", ()))[:1] == ("body",) for item in exc.errors()
    ):
        main = (content_type or "").split(";", 1)[0].strip().lower()
        if main != "application/json" and not main.endswith("+json"):
            got = f"got {content_type!r}" if content_type else "none was given"
            return (
                "expected a JSON body with Content-Type: application/json "
                f"({got}; curl: -H 'Content-Type: application/json')"
            )
    return None


async def _validation_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    fields = field_errors(exc)
    problem = _body_problem(request, exc)
    if problem is not None:
        details = [{"field": "body", "message": problem, "type": "body"}]
        return error_response(422, "validation", problem, details)
    summary = "; ".join(f"{f['field']}: {f['message']}" for f in fields[:5])
    return error_response(422, "validation", f"invalid request: {summary}", fields)


async def _unexpected_error(request: Request, exc: Exception) -> JSONResponse:
    logger.error("unhandled error in %s %s", request.method, request.url.path, exc_info=exc)
    return error_response(500, "internal", "internal error; the daemon log has the details")


def install_error_handlers(app: FastAPI) -> None:
    app.add_exception_handler(StarletteHTTPException, _api_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(Exception, _unexpected_error)


#: The error responses every route may give, for the OpenAPI description.
COMMON_ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    status: {"model": ErrorBody, "description": kind}
    for status, kind in (
        (401, "no or unknown token"),
        (403, "token lacks the scope"),
        (413, "request body too large"),
        (422, "invalid request, with field-level messages in details"),
        (503, "the daemon, its storage or a device is unavailable"),
    )
}
