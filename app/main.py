"""The web app: REST API under /api, HTML pages, static files, and the answers to errors (a database away is a JSON
503, a 405 names every method of its path). `create_app` is uvicorn's factory."""

import gc
import math
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request, Response, status
from fastapi.encoders import jsonable_encoder
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from sqlalchemy.exc import SQLAlchemyError
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.routing import Match
from starlette.types import Scope

from app.database_outage import database_error_response
from app.routers import (
    compare,
    config,
    docs,
    envs,
    events,
    exports,
    goal_sets,
    health,
    metrics,
    pages,
    queries,
    reward_health,
    robot,
    runs,
)  # fmt: skip
from app.schemas import errors
from app.security import RequestGuard
from contract.settings import Settings, get_settings
from contract.store import Conflict, InvalidInput, NotFound, Store

ROOT = Path(__file__).resolve().parent.parent
STATIC_DIR = ROOT / "static"
# Without a token the server only listens on loopback (the CLI refuses other addresses), so these are the
# only names a browser can legitimately reach it by; any other Host is a DNS-rebinding page. "testserver"
# is TestClient's host.
LOOPBACK_HOST_NAMES = ["127.0.0.1", "localhost", "[::1]", "::1", "testserver"]


def json_safe(value: Any) -> Any:
    """Non-finite floats as strings ("inf", "nan") and lone surrogates as "?", recursively: what JSON in UTF-8
    can carry."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, str):
        return value.encode("utf-8", "replace").decode("utf-8")
    if isinstance(value, dict):
        return {key: json_safe(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(item) for item in value]
    return value


HTTP_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")


def allowed_methods(app: FastAPI, scope: Scope) -> list[str]:
    """Every method that some route takes at this request's path (asked of the app's own routing, one method at a
    time)."""
    allowed = []
    for method in HTTP_METHODS:
        asked = {**scope, "method": method}
        if any(route.matches(asked)[0] == Match.FULL for route in app.router.routes):
            allowed.append(method)
    return allowed


def create_app(settings: Settings | None = None) -> FastAPI:
    """One app with one Store, opened here and closed at shutdown. Migrations are applied by the CLI."""
    settings = settings or get_settings()
    store = Store(settings.resolved_database_url)

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        # Everything built at start (modules, routes, schemas) lives as long as the server: out of the
        # collector's way. A full collection scanned it all, stopping every request for ~90 ms under load
        # (bench/load.py's p99 tail).
        gc.collect()
        gc.freeze()
        try:
            yield
        finally:
            gc.unfreeze()
            store.dispose()

    app = FastAPI(
        title="vice-raq",
        summary="Teach a robot a visual skill from goal photos; answer its yes/no questions.",
        version="0.1.0",
        lifespan=lifespan,
        docs_url=None,  # app.routers.docs serves Swagger UI's files itself (no CDN); ReDoc needs one, so none
        redoc_url=None,
        # app.security.RequestGuard may answer any route so: a malformed Content-Length, a body over the cap
        responses=errors(400, 413),
    )
    app.state.settings = settings
    app.state.store = store

    @app.exception_handler(RequestValidationError)
    async def _validation(_request: Request, error: RequestValidationError) -> JSONResponse:
        """FastAPI's 422, with the offending input made JSON-safe: a body may hold the literals NaN or Infinity
        (Python's json reads them) or a lone surrogate ("\\ud800"), which the response cannot carry back (FastAPI's
        own handler failed with a 500)."""
        return JSONResponse(status_code=422, content={"detail": json_safe(jsonable_encoder(error.errors()))})

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, error: StarletteHTTPException) -> Response:
        """FastAPI's own answer, except that a 405's Allow names every method of the path (Starlette names only those
        of the first route whose path matched, so /api/runs/1 said "GET" where it also takes PATCH and DELETE)."""
        if error.status_code == status.HTTP_405_METHOD_NOT_ALLOWED:
            error.headers = {**(error.headers or {}), "Allow": ", ".join(allowed_methods(app, request.scope))}
        return await http_exception_handler(request, error)

    @app.exception_handler(NotFound)
    async def _not_found(_request: Request, error: NotFound) -> JSONResponse:
        return JSONResponse(status_code=404, content={"detail": str(error)})

    @app.exception_handler(Conflict)
    async def _conflict(_request: Request, error: Conflict) -> JSONResponse:
        return JSONResponse(status_code=409, content={"detail": str(error)})

    @app.exception_handler(InvalidInput)
    async def _invalid(_request: Request, error: InvalidInput) -> JSONResponse:
        return JSONResponse(status_code=400, content={"detail": str(error)})

    @app.exception_handler(SQLAlchemyError)
    async def _database(_request: Request, error: SQLAlchemyError) -> JSONResponse:
        return database_error_response(error)

    # Requests are matched against the routes in this order: the labelling API, the busiest, first.
    app.include_router(queries.router)
    app.include_router(health.router)
    app.include_router(runs.router)
    app.include_router(exports.router)
    app.include_router(compare.router)
    app.include_router(goal_sets.router)
    app.include_router(metrics.router)
    app.include_router(reward_health.router)
    app.include_router(robot.router)
    app.include_router(events.router)
    app.include_router(envs.router)
    app.include_router(config.router)
    app.include_router(pages.router)
    app.include_router(docs.router)
    app.mount(docs.SWAGGER_UI_PREFIX, StaticFiles(directory=docs.SWAGGER_UI_DIR), name="swagger-ui")
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    # The last added is the outermost: the guard (token, body size, security headers) sees every request
    # first, then (without a token) the Host is checked.
    if not settings.api_token:
        app.add_middleware(TrustedHostMiddleware, allowed_hosts=LOOPBACK_HOST_NAMES)
    app.add_middleware(
        RequestGuard,
        settings=settings,
        store=store,
        upload_limit=goal_sets.upload_request_limit(settings.max_upload_bytes),
    )
    return app
