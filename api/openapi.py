"""The OpenAPI description's security, matching what the server does.

The dependencies read the ``Authorization`` header themselves (any scheme but Bearer is a 401),
so the description is written here: one ``bearer`` scheme; a control operation requires it; a
read requires it or, where anonymous reads are on (loopback by default), nothing (``{}``);
``/health`` and the WebSocket need nothing declared here.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi.routing import RouteContext, iter_route_contexts

from api.deps import require_control, require_read

SCHEME = "bearer"


def _access(context: RouteContext) -> str | None:
    dependant = getattr(context.route, "dependant", None)
    if dependant is None:
        return None
    calls = {dependency.call for dependency in dependant.dependencies}
    if require_control in calls:
        return "control"
    if require_read in calls:
        return "read"
    return None


def install_openapi(app: FastAPI, anonymous_read: bool) -> None:
    """Replace ``app.openapi`` by one that declares the security each operation has."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is not None:
            return app.openapi_schema
        schema = get_openapi(
            title=app.title,
            version=app.version,
            description=app.description,
            routes=app.routes,
        )
        schema.setdefault("components", {})["securitySchemes"] = {
            SCHEME: {
                "type": "http",
                "scheme": "bearer",
                "description": "`Authorization: Bearer <token>`; the control token also "
                "grants read. Any other scheme is refused (401) like a wrong token.",
            }
        }
        paths: dict[str, dict[str, Any]] = schema.get("paths", {})
        for context in iter_route_contexts(app.routes):  # included routers too
            access = _access(context)
            if access is None or context.path_format not in paths:
                continue
            requirement: list[dict[str, list[str]]] = [{SCHEME: []}]
            if access == "read" and anonymous_read:
                requirement.append({})  # no credentials at all is accepted too
            for method in context.methods or ():
                operation = paths[context.path_format].get(method.lower())
                if operation is not None:
                    operation["security"] = requirement
        app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]
