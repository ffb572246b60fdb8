"""What every request goes through before any route runs.

RequestGuard (an ASGI middleware, outermost) does, in this order, before a byte of the body is read:
1. with RAQ_API_TOKEN set, refuses a request that carries neither the bearer token nor a live login session:
   pages (GET) are redirected to /login, everything else gets 401; only /login, /logout, /health and /static
   are public. The body of a refused request is never read.
2. caps the body: a Content-Length over the route's limit is 413 at once; a body without one (chunked) is
   counted as it arrives and refused with 413 as soon as it passes the limit.
3. adds X-Content-Type-Options: nosniff, a Content-Security-Policy and friends to every response.
"""

import re
from urllib.parse import quote

from fastapi import HTTPException
from fastapi.responses import JSONResponse, RedirectResponse
from starlette.datastructures import Headers, MutableHeaders
from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.deps import AUTHORISED_STATE, UNAUTHORISED_DETAIL, is_authorised_async
from app.routers.goal_sets import MAX_FILES_PER_UPLOAD
from contract.settings import Settings
from contract.store import Store

UPLOAD_PATH = re.compile(r"^/api/goal-sets/[^/]+/examples/?$")
PUBLIC_PATHS = ("/login", "/logout", "/health")
PUBLIC_PREFIXES = ("/static/",)
LOGIN_BODY_LIMIT = 16 * 1024  # a token and a path

# The pages load their scripts, styles and images from /static and the API, and set no inline script.
# style-src-attr allows the style="" attributes of the templates (no script can run from one).
PAGE_CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self'; style-src-attr 'unsafe-inline'; "
    "img-src 'self' data: blob:; connect-src 'self'; font-src 'self'; object-src 'none'; base-uri 'none'; "
    "form-action 'self'; frame-ancestors 'none'"
)
# /docs: Swagger UI from the app's own /static/swagger-ui (no CDN, no inline script); it sets inline styles.
DOCS_CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:; "
    "font-src 'self'; worker-src 'self' blob:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
    "form-action 'self'; frame-ancestors 'none'"
)
DOCS_PATHS = ("/docs",)
SECURITY_HEADERS = {
    "x-content-type-options": "nosniff",
    "referrer-policy": "same-origin",
    "x-frame-options": "DENY",
    "cross-origin-opener-policy": "same-origin",
}


def is_public(path: str) -> bool:
    return path in PUBLIC_PATHS or path.startswith(PUBLIC_PREFIXES)


def is_page(path: str) -> bool:
    """A path a browser navigates to (redirected to /login), not one a program calls (401)."""
    return not (path.startswith("/api/") or path == "/api" or path == "/openapi.json")


class RequestGuard:
    def __init__(self, app: ASGIApp, *, settings: Settings, store: Store, upload_limit: int) -> None:
        self.app = app
        self.settings = settings
        self.store = store
        self.upload_limit = upload_limit

    def body_limit(self, method: str, path: str) -> int:
        if method == "POST" and UPLOAD_PATH.match(path):
            return self.upload_limit
        if path == "/login":
            return LOGIN_BODY_LIMIT
        return self.settings.max_json_bytes

    def too_large(self, size: str, limit: int, path: str) -> str:
        if UPLOAD_PATH.match(path):
            return (
                f"the upload is {size} bytes; the limit for one request is {limit:,} bytes (at most "
                f"{MAX_FILES_PER_UPLOAD} files of up to {self.settings.max_upload_bytes:,} bytes each); "
                "nothing from this upload was stored"
            )
        return f"the request body is {size} bytes; the limit for {path} is {limit:,} bytes"

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path: str = scope["path"]
        csp = DOCS_CSP if path in DOCS_PATHS else PAGE_CSP

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                for name, value in SECURITY_HEADERS.items():
                    headers[name] = value
                headers["content-security-policy"] = csp
            await send(message)

        refusal = await self._refusal(scope)
        if refusal is not None:
            # The body stays unread: uvicorn closes the connection after this response instead of reading it.
            await refusal(scope, receive, send_with_headers)
            return
        await self.app(scope, self._counted(scope, receive), send_with_headers)

    async def _refusal(self, scope: Scope) -> JSONResponse | RedirectResponse | None:
        path: str = scope["path"]
        method: str = scope["method"]
        if self.settings.api_token and not is_public(path):
            request = Request(scope)  # headers and cookies only; nothing here touches the body
            if await is_authorised_async(request, self.settings, self.store):
                scope.setdefault("state", {})[AUTHORISED_STATE] = True  # the routes' checks need not look again
            else:
                if method in ("GET", "HEAD") and is_page(path):
                    target = path + (f"?{scope['query_string'].decode('latin-1')}" if scope["query_string"] else "")
                    return RedirectResponse(f"/login?next={quote(target, safe='')}", status_code=303)
                return JSONResponse(
                    {"detail": UNAUTHORISED_DETAIL}, status_code=401, headers={"WWW-Authenticate": "Bearer"}
                )
        length = Headers(scope=scope).get("content-length")
        if length is not None:
            if not length.strip().isdigit() or len(length.strip()) > 20:
                return JSONResponse({"detail": "invalid Content-Length header"}, status_code=400)
            limit = self.body_limit(method, path)
            if int(length) > limit:
                return JSONResponse({"detail": self.too_large(f"{int(length):,}", limit, path)}, status_code=413)
        return None

    def _counted(self, scope: Scope, receive: Receive) -> Receive:
        limit = self.body_limit(scope["method"], scope["path"])
        received = 0

        async def counted_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    # raised inside FastAPI's body or form parsing, which answers HTTPExceptions with JSON
                    raise HTTPException(
                        status_code=413, detail=self.too_large(f"more than {limit:,}", limit, scope["path"])
                    )
            return message

        return counted_receive
