"""Serves the dashboard pages and their static files. The pages themselves hold no data:
their JavaScript signs in through ``/api/auth/token``, keeps the bearer token in
``sessionStorage`` and reads everything from the REST API, so these routes need no
authentication (and are left out of the OpenAPI document)."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse, Response

STATIC = Path(__file__).resolve().parent / "static"
TYPES = {".css": "text/css", ".js": "text/javascript", ".svg": "image/svg+xml",
         ".html": "text/html", ".png": "image/png", ".ico": "image/x-icon"}

router = APIRouter(include_in_schema=False)


def _page(name: str) -> FileResponse:
    return FileResponse(STATIC / name, media_type="text/html",
                        headers={"Cache-Control": "no-cache"})


@router.get("/")
def home() -> RedirectResponse:
    return RedirectResponse("/patients")


#: The sign-in page's first-run hint, hidden until the server has no account.
FIRST_RUN_HIDDEN = '<div id="first-run" class="notice" hidden>'


@router.get("/signin")
def signin(request: Request) -> Response:
    """The sign-in page; on a server with no account yet it shows how to make one."""
    from armtrack.server.app import has_accounts

    services = getattr(request.app.state, "services", None)
    if services is None:
        return _page("signin.html")
    with services.db() as db:
        if has_accounts(db):
            return _page("signin.html")
    html = (STATIC / "signin.html").read_text("utf-8")
    return HTMLResponse(html.replace(FIRST_RUN_HIDDEN, FIRST_RUN_HIDDEN.replace(" hidden", "")),
                        headers={"Cache-Control": "no-cache"})


@router.get("/patients")
def patients() -> FileResponse:
    return _page("patients.html")


@router.get("/patients/{patient_id}")
def patient(patient_id: int) -> FileResponse:
    return _page("patient.html")


@router.get("/sessions/{session_id}")
def session(session_id: int) -> FileResponse:
    return _page("session.html")


@router.get("/audit")
def audit_log() -> FileResponse:
    """The audit log (``GET /api/audit``): a therapist's patients' trail, an admin's all."""
    return _page("audit.html")


@router.get("/admin")
def admin() -> FileResponse:
    """The clinic admin's screens (``/api/admin/*``); a non-admin sees a notice only."""
    return _page("admin.html")


@router.get("/account")
def account() -> FileResponse:
    """The signed-in therapist's own account: full name and password."""
    return _page("account.html")


@router.get("/kit")
def kit() -> FileResponse:
    """The phone kit (``docs/phone-kit.md``): the patient's page; its device token comes
    in the URL fragment (``/kit#token=…``), which never reaches the server."""
    return _page("kit.html")


@router.get("/kit.webmanifest")
def kit_manifest() -> FileResponse:
    return FileResponse(STATIC / "kit.webmanifest", media_type="application/manifest+json",
                        headers={"Cache-Control": "no-cache"})


@router.get("/kit-sw.js")
def kit_service_worker() -> FileResponse:
    """The kit's service worker, served from the root so that its scope covers ``/kit``."""
    return FileResponse(STATIC / "kit-sw.js", media_type="text/javascript",
                        headers={"Cache-Control": "no-cache"})


@router.get("/favicon.ico")
def favicon() -> FileResponse:
    """Browsers ask for it whatever the page says: the same icon, as SVG."""
    return FileResponse(STATIC / "favicon.svg", media_type="image/svg+xml",
                        headers={"Cache-Control": "max-age=86400"})


@router.get("/assets/{name}")
def asset(name: str) -> FileResponse:
    path = STATIC / name
    if "/" in name or name.startswith(".") or path.suffix not in TYPES or not path.is_file():
        raise HTTPException(404, f"no asset {name}")
    return FileResponse(path, media_type=TYPES[path.suffix],
                        headers={"Cache-Control": "no-cache"})
