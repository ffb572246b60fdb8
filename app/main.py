"""The web app: REST API under /api, HTML pages, static files. `create_app` is uvicorn's factory."""

import re
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import FastAPI, HTTPException, Request
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.datastructures import Headers
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.routers import events, goal_sets, health, metrics, pages, queries, runs
from app.settings import Settings, get_settings
from app.store import Conflict, InvalidInput, NotFound, Store

ROOT = Path(__file__).resolve().parent.parent
STATIC_DIR = ROOT / "static"
# Without a token the server only listens on loopback (the CLI refuses other addresses), so these are the
# only names a browser can legitimately reach it by; any other Host is a DNS-rebinding page. "testserver"
# is TestClient's host.
LOOPBACK_HOST_NAMES = ["127.0.0.1", "localhost", "[::1]", "::1", "testserver"]
UPLOAD_PATH = re.compile(r"/api/goal-sets/[^/]+/examples/?$")


class UploadSizeLimit:
    """Bound a goal-photo upload's whole request before it is parsed: Starlette spools every part to disk
    or memory before the endpoint runs, so the per-file limit alone would come too late.

    A Content-Length above `limit` is refused with 413 before a byte is read; a body without one (chunked)
    is counted as it arrives and refused with 413 as soon as it passes `limit`.
    """

    def __init__(self, app: ASGIApp, *, max_file_bytes: int) -> None:
        self.app = app
        self.max_file_bytes = max_file_bytes
        self.limit = goal_sets.upload_request_limit(max_file_bytes)

    def _detail(self, size: str) -> str:
        return (
            f"the upload is {size} bytes; the limit for one request is {self.limit:,} bytes "
            f"(at most {goal_sets.MAX_FILES_PER_UPLOAD} files of up to {self.max_file_bytes:,} bytes each); "
            "nothing from this upload was stored"
        )

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "POST" or not UPLOAD_PATH.search(scope["path"]):
            await self.app(scope, receive, send)
            return
        length = Headers(scope=scope).get("content-length")
        if length is not None:
            if not length.strip().isdigit():
                await JSONResponse({"detail": "invalid Content-Length header"}, status_code=400)(scope, receive, send)
                return
            if int(length) > self.limit:
                response = JSONResponse({"detail": self._detail(f"{int(length):,}")}, status_code=413)
                await response(scope, receive, send)
                return
        received = 0

        async def counted_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.limit:
                    # raised inside the form parser; FastAPI re-raises HTTPExceptions and answers with JSON
                    raise HTTPException(status_code=413, detail=self._detail(f"more than {self.limit:,}"))
            return message

        await self.app(scope, counted_receive, send)


def create_app(settings: Settings | None = None) -> FastAPI:
    """One app with one Store, opened here and closed at shutdown. Migrations are applied by the CLI."""
    settings = settings or get_settings()
    store = Store(settings.resolved_database_url)

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        try:
            yield
        finally:
            store.dispose()

    app = FastAPI(
        title="vice-raq",
        summary="Teach a robot a visual skill from goal photos; answer its yes/no questions.",
        version="0.1.0",
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.store = store

    @app.exception_handler(NotFound)
    async def _not_found(_request: Request, error: NotFound) -> JSONResponse:
        return JSONResponse(status_code=404, content={"detail": str(error)})

    @app.exception_handler(Conflict)
    async def _conflict(_request: Request, error: Conflict) -> JSONResponse:
        return JSONResponse(status_code=409, content={"detail": str(error)})

    @app.exception_handler(InvalidInput)
    async def _invalid(_request: Request, error: InvalidInput) -> JSONResponse:
        return JSONResponse(status_code=400, content={"detail": str(error)})

    app.include_router(health.router)
    app.include_router(runs.router)
    app.include_router(goal_sets.router)
    app.include_router(queries.router)
    app.include_router(metrics.router)
    app.include_router(events.router)
    app.include_router(pages.router)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    # The last added is the outermost: check the Host first, then the upload's size.
    app.add_middleware(UploadSizeLimit, max_file_bytes=settings.max_upload_bytes)
    if not settings.api_token:
        app.add_middleware(TrustedHostMiddleware, allowed_hosts=LOOPBACK_HOST_NAMES)
    return app
