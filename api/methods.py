"""Which methods a path answers to, through the routes' own matching: the ``Allow`` header of
a 405 (api/errors.py) and of an OPTIONS answer (api/middleware.py)."""

from __future__ import annotations

from collections.abc import Iterable

from starlette.routing import BaseRoute, Match, Mount

#: The methods probed for ``Allow`` (the API uses no others).
_METHODS = ("GET", "POST", "PUT", "PATCH", "DELETE")


def allowed_methods(routes: Iterable[BaseRoute], path: str) -> list[str]:
    """Every method some route serves at ``path`` (FastAPI answers a 405 or an OPTIONS with
    the first matching route's methods only: /runs has a GET route and a POST route). Each
    method is probed through the routes' own matching, included routers too."""
    methods: set[str] = set()
    for route in routes:
        if isinstance(route, Mount):  # static files: they match any method, serve two
            if path.startswith(route.path + "/"):
                methods |= {"GET", "HEAD"}
            continue
        for method in _METHODS:
            probe = {"type": "http", "path": path, "method": method, "root_path": ""}
            if route.matches({**probe, "headers": [], "query_string": b""})[0] is Match.FULL:
                methods.add(method)
    if methods:
        methods.add("OPTIONS")
        if "GET" in methods:
            methods.add("HEAD")
    return sorted(methods)
