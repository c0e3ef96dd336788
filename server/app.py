"""The FastAPI application: ``create_app(settings)``. On start it migrates the database
and starts the group writer; on stop it stores what is queued."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from datetime import UTC, datetime

from armtrack.estimator.orientation import DEFAULT_FILTER
from armtrack.web.pages import api_docs
from armtrack.web.pages import routes as pages
from armtrack.web.viewer import routes as viewer_routes
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse
from sqlalchemy.exc import OperationalError, ProgrammingError

from . import heap
from .api import (
    admin,
    auth_routes,
    clinic,
    device,
    imports,
    lifecycle,
    live_status,
    patients,
    programs,
    reports,
    session_summary,
    sessions,
)
from .api.erase import erase_expired
from .audit import AuditMiddleware
from .builds import RETRY_AFTER_S, BuildsBusy
from .db.errors import lacks_schema, told
from .ingest import endpoint
from .live import endpoint as live_endpoint
from .periodic import every
from .plain_text import database_failed, validation_error
from .security import (
    BodyLimit,
    SecurityHeaders,
    UntrustedProxyNotice,
    UploadGate,
    setting_warnings,
)
from .services import Services
from .settings import Settings
from .store.processing import estimator_version
from .store.silence import close_silent, silent_sessions

log = logging.getLogger("armtrack.retention")


def has_accounts(db) -> bool:
    """Whether any therapist can sign in (an enabled account exists)."""
    from sqlalchemy import select

    from .db import models

    return db.scalar(select(models.Therapist.id)
                     .where(models.Therapist.disabled_at.is_(None)).limit(1)) is not None


async def retention_loop(services: Services) -> None:
    """Erase closed sessions past ``ARMTRACK_RETENTION_DAYS`` now and then (audited)."""
    settings = services.settings
    assert settings.retention_days is not None
    await every(settings.retention_check_s,
                lambda: services.run_db(erase_expired, settings.retention_days),
                log=log, failed="retention: erasing expired sessions failed", at_once=True)


async def close_silent_sessions(services: Services, up_since: float) -> list[int]:
    """Close the interrupted sessions silent for ``ARMTRACK_CLOSE_INTERRUPTED_AFTER_HOURS``
    (docs/extensions/closed-after-silence.md) and estimate them: the ones closed. Each
    under the therapist's close's guard (``Services.closing``: a resume meanwhile is
    refused as closed) and only if still interrupted (a resume that came first wins).

    Silence counts only while this server could hear the kit: from its last data, but
    not before ``up_since`` [s, Unix time], when this server began to serve. A server
    down longer than the setting closed, as it started, the sessions streaming when it
    stopped, before their kits could reconnect; now every kit has the full setting of
    the server's hearing to come back after a restart."""
    hours = services.settings.close_interrupted_after_hours
    cutoff = datetime.now(UTC).timestamp() - 3600.0 * hours
    if up_since > cutoff:  # not up that long: no session is silent for the setting yet
        return []
    closed = []
    for session_id in await services.run_db(silent_sessions, cutoff):
        if session_id in services.closing:
            continue
        services.closing.add(session_id)
        try:
            if not await services.run_db(close_silent, session_id, cutoff, hours):
                continue
            # no stream of it is open (a resume now is refused); a parked live side goes
            await services.end_session_streams(session_id, "session closed after silence")
        finally:
            services.closing.discard(session_id)
        logging.getLogger("armtrack.silence").info(
            "session %s closed after %g h without data from its kit", session_id, hours)
        closed.append(session_id)
        services.process_later(session_id, DEFAULT_FILTER)
    return closed


async def silence_loop(services: Services) -> None:
    """``close_silent_sessions`` now and then (silence counted from this loop's start:
    the server serves from about then)."""
    up_since = datetime.now(UTC).timestamp()
    await every(services.settings.close_interrupted_check_s,
                lambda: close_silent_sessions(services, up_since), log=log,
                failed="closing silent interrupted sessions failed", at_once=True)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        services = Services(settings)
        services.migrate()
        app.state.services = services
        if not settings.demo_mode and not await services.run_db(has_accounts):
            logging.getLogger("armtrack").warning(
                "no therapist account yet: make one with `armtrack create-user NAME` "
                "(same --data-dir/ARMTRACK_DATABASE_URL as this server), then sign in at "
                "/signin")
        if not settings.clinic_name and not settings.demo_mode:
            logging.getLogger("armtrack").warning(
                "ARMTRACK_CLINIC_NAME is not set: session reports (PDF) print no clinic "
                "name; set it to the name reports should carry (docs/operator.md)")
        for words in setting_warnings(settings):
            logging.getLogger("armtrack").warning(words)
        await services.start()
        heap.settle()  # what start-up loaded is out of the collector's way from now on
        retention = (asyncio.create_task(retention_loop(services))
                     if settings.retention_days else None)
        silence = (asyncio.create_task(silence_loop(services))
                   if settings.close_interrupted_after_hours else None)
        try:
            yield
        finally:
            if silence is not None:
                silence.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await silence
            if retention is not None:
                retention.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await retention
            await services.stop()

    async def builds_busy(_request: Request, exc: BuildsBusy) -> JSONResponse:
        # too many requests building or waiting for a report or summary (server/builds.py)
        return JSONResponse(status_code=exc.status, content={"detail": exc.detail},
                            headers={"Retry-After": str(RETRY_AFTER_S)})

    app = FastAPI(title="armtrack", version=estimator_version(), lifespan=lifespan,
                  docs_url=None, redoc_url=None,  # api_docs serves them, CDN-free
                  description="Remote arm rehabilitation: IMU streams in (`/ws/ingest`, "
                  "docs/spec/ingest.md), joint angles, sessions and reports out "
                  "(docs/spec/api.md). "
                  "armtrack supports therapy; it is not a diagnostic device.")
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(OperationalError, database_failed)
    app.add_exception_handler(ProgrammingError, database_failed)
    app.add_exception_handler(BuildsBusy, builds_busy)
    app.include_router(auth_routes.router)
    app.include_router(patients.router)
    app.include_router(device.router)
    app.include_router(sessions.router)
    app.include_router(imports.router)
    app.include_router(reports.router)
    app.include_router(programs.router)
    app.include_router(endpoint.router)
    app.include_router(live_endpoint.router)
    app.include_router(viewer_routes.router)
    app.include_router(live_status.router)
    app.include_router(session_summary.router)
    app.include_router(pages.router)
    app.include_router(api_docs.router)
    app.include_router(admin.router)
    app.include_router(lifecycle.router)
    app.include_router(clinic.router)

    # outermost last: headers on every answer, then body limits, CORS, the audit log
    app.add_middleware(AuditMiddleware)
    if settings.cors_origin_list():
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origin_list(),
                           allow_methods=["GET", "POST", "PUT", "PATCH", "DELETE"],
                           allow_headers=["Authorization", "Content-Type"])
    app.add_middleware(UploadGate)  # inside the body limit: 413 by length comes first
    app.add_middleware(BodyLimit, settings=settings)
    app.add_middleware(SecurityHeaders, settings=settings)
    app.add_middleware(UntrustedProxyNotice, settings=settings)

    @app.get("/healthz", include_in_schema=False)
    def health(request: Request) -> JSONResponse:
        """200 ``ok``; 503 while what kits send cannot be stored (a full disk, a locked
        database): the clinic's monitoring sees it, with the database's words for a full
        disk or a lock (``db.errors.told``), the kind of failure for others; 503
        ``database not upgraded`` once a request or a kit's write met a table or column
        not there and while the database is not at this armtrack's schema
        (``Services.schema_problem``): what to run, which waiting will not replace. No
        path or host is named."""
        services = getattr(request.app.state, "services", None)
        if services is None:
            return JSONResponse({"status": "ok"})
        failing = services.writer.failing
        check = getattr(services, "schema_problem", None)
        if check is not None and failing is not None and lacks_schema(str(failing["reason"])):
            services.schema_suspect()  # a kit's write met a table or column not there
        schema = check() if check is not None else None
        if schema is not None:
            return JSONResponse({"status": "database not upgraded", "detail": schema},
                                status_code=503)
        if failing is None:
            return JSONResponse({"status": "ok"})
        since = datetime.fromtimestamp(failing["since"], UTC).isoformat(timespec="seconds")
        return JSONResponse({"status": "storage failing",  # anyone may ask: no host named
                             "detail": f"what kits send is not stored since {since}: "
                                       f"{told(str(failing['reason']))}"},
                            status_code=503)

    return app
