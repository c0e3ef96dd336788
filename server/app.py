"""The FastAPI application: ``create_app(settings)``. On start it migrates the database
and starts the group writer; on stop it stores what is queued."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from armtrack.web.pages import routes as pages
from armtrack.web.viewer import routes as viewer_routes
from fastapi import FastAPI

from .api import auth_routes, live_status, patients, reports, session_summary, sessions
from .ingest import endpoint
from .live import endpoint as live_endpoint
from .services import Services
from .settings import Settings
from .store.processing import estimator_version


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        services = Services(settings)
        services.migrate()
        app.state.services = services
        await services.start()
        try:
            yield
        finally:
            await services.stop()

    app = FastAPI(title="armtrack", version=estimator_version(), lifespan=lifespan,
                  description="Remote arm rehabilitation: IMU streams in (`/ws/ingest`, "
                  "spec/ingest.md), joint angles, sessions and reports out (spec/api.md). "
                  "armtrack supports therapy; it is not a diagnostic device.")
    app.include_router(auth_routes.router)
    app.include_router(patients.router)
    app.include_router(sessions.router)
    app.include_router(reports.router)
    app.include_router(endpoint.router)
    app.include_router(live_endpoint.router)
    app.include_router(viewer_routes.router)
    app.include_router(live_status.router)
    app.include_router(session_summary.router)
    app.include_router(pages.router)

    @app.get("/healthz", include_in_schema=False)
    def health() -> dict[str, str]:
        return {"status": "ok"}

    return app
