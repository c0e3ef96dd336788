"""The API's reference pages, ``/docs`` (Swagger UI) and ``/redoc`` (ReDoc), served with
their JavaScript and CSS from this server: the pages' Content-Security-Policy
(``server.security.page_csp``) loads scripts from our origin only, so FastAPI's default
pages, which take them from a CDN, stay blank. The files come from the ``fastapi-offline``
package (a dependency; ``pip install`` brings them); the pages start them with
``/assets/api-docs.js`` rather than an inline script."""

from __future__ import annotations

import importlib.resources
from functools import cache
from pathlib import Path

from fastapi import APIRouter, HTTPException
from fastapi.responses import FileResponse

from .routes import _page

router = APIRouter(include_in_schema=False)

#: The vendored files served under ``/docs/assets/`` (and nothing else from the package).
ASSETS = {"swagger-ui-bundle.js": "text/javascript", "swagger-ui.css": "text/css",
          "redoc.standalone.js": "text/javascript"}


@cache
def assets_folder() -> Path:
    """Where ``fastapi-offline`` keeps swagger-ui's and redoc's files."""
    return Path(str(importlib.resources.files("fastapi_offline") / "static"))


@router.get("/docs")
def swagger_ui() -> FileResponse:
    """Swagger UI over ``/openapi.json``: try the routes with a bearer token."""
    return _page("api-docs.html")


@router.get("/redoc")
def redoc() -> FileResponse:
    """ReDoc over ``/openapi.json``: the reference to read."""
    return _page("api-redoc.html")


@router.get("/docs/assets/{name}")
def docs_asset(name: str) -> FileResponse:
    if name not in ASSETS:
        raise HTTPException(404, f"no docs asset {name}")
    path = assets_folder() / name
    if not path.is_file():  # a broken install: say what is missing
        raise HTTPException(500, f"{name} is missing from the fastapi-offline package: "
                                 "reinstall armtrack (pip install armtrack)")
    return FileResponse(path, media_type=ASSETS[name],
                        headers={"Cache-Control": "max-age=86400"})
