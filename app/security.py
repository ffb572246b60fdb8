"""What every request goes through before any route runs.

RequestGuard (an ASGI middleware, outermost) does, in this order, before a byte of the body is read:
0. takes the client address from X-Forwarded-For only when the request comes from one of RAQ_TRUSTED_PROXIES
   (uvicorn's own proxy-header handling is off: `raq serve` starts it with proxy_headers=False).
1. with RAQ_API_TOKEN set, refuses a request that carries neither the bearer token nor a live login session:
   pages (GET) are redirected to /login, everything else gets 401; only /login, /logout, /health and /static
   are public. The body of a refused request is never read. Wrong bearer tokens count against the client
   address's login limit (RAQ_LOGIN_ATTEMPTS_PER_MINUTE, shared with /login): once over it every bearer request
   from that address, the right token included, is 429 with Retry-After until the window frees a try.
2. caps the body: a Content-Length over the route's limit is 413 at once; a body without one (chunked) is
   counted as it arrives and refused with 413 as soon as it passes the limit.
3. adds X-Content-Type-Options: nosniff, a Content-Security-Policy and friends to every response.
A database that is away while 1. looks up a login session or the token's rate limit is the same JSON 503 with
Retry-After that the routes answer (app.database_outage).
"""

import ipaddress
import re
from urllib.parse import quote

from fastapi import HTTPException
from fastapi.responses import JSONResponse, RedirectResponse
from sqlalchemy.exc import SQLAlchemyError
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import Headers, MutableHeaders
from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.database_outage import database_error_response
from app.deps import AUTHORISED_STATE, UNAUTHORISED_DETAIL, has_bearer_token, is_authorised_async
from app.routers.goal_sets import MAX_FILES_PER_UPLOAD
from contract.settings import Settings
from contract.store import Store

UPLOAD_PATH = re.compile(r"^/api/goal-sets/[^/]+/(examples|photo-check)/?$")
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


def _parse_address(text: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    text = text.strip()
    if text.startswith("[") and "]" in text:  # [v6]:port
        text = text[1 : text.index("]")]
    elif text.count(":") == 1:  # v4:port
        text = text.partition(":")[0]
    try:
        return ipaddress.ip_address(text)
    except ValueError:
        return None


def client_address(peer: str, forwarded_for: list[str], trusted: tuple[str, ...]) -> str:
    """The client a request is from: its peer, unless the peer is a trusted proxy; then the right-most address of
    X-Forwarded-For that is not a trusted proxy (each proxy appends the address it was reached from, so only the
    entries the trusted proxies added are believed; a client can put anything on the left)."""
    if not trusted or not forwarded_for:
        return peer
    networks = [ipaddress.ip_network(item, strict=False) for item in trusted]

    def is_trusted(address: ipaddress.IPv4Address | ipaddress.IPv6Address | None) -> bool:
        return address is not None and any(address in network for network in networks)

    if not is_trusted(_parse_address(peer)):
        return peer
    hops = [hop.strip() for value in forwarded_for for hop in value.split(",") if hop.strip()]
    for hop in reversed(hops):
        address = _parse_address(hop)
        if address is None:
            return peer  # junk where a proxy's entry should be: believe nothing
        if not is_trusted(address):
            return str(address)
    return peer


def _bearer_presented(scope: Scope) -> bool:
    scheme, _, credentials = Headers(scope=scope).get("authorization", "").partition(" ")
    return scheme.lower() == "bearer" and bool(credentials.strip())


def too_many_tries(wait: int) -> JSONResponse:
    return JSONResponse(
        {"detail": f"too many wrong tokens from your address: try again in {wait} s"},
        status_code=429, headers={"Retry-After": str(wait)},
    )  # fmt: skip


class RequestGuard:
    def __init__(self, app: ASGIApp, *, settings: Settings, store: Store, upload_limit: int) -> None:
        self.app = app
        self.settings = settings
        self.store = store
        self.upload_limit = upload_limit

    def _resolve_client(self, scope: Scope) -> None:
        """scope["client"] as the client address every route and limit sees (X-Forwarded-For via trusted proxies)."""
        if not self.settings.trusted_proxies or not scope.get("client"):
            return
        peer, port = scope["client"]
        forwarded = [value.decode("latin-1") for name, value in scope["headers"] if name == b"x-forwarded-for"]
        address = client_address(peer, forwarded, self.settings.trusted_proxies)
        if address != peer:
            scope["client"] = (address, 0)

    async def _token_limit(self, scope: Scope, *, authorised: bool) -> JSONResponse | None:
        """A wrong bearer token is a failed try of the client's address (as a wrong /login is); an address over
        its limit is refused (429), whatever token it sends, until a try frees up."""
        client = scope["client"][0] if scope.get("client") else "unknown"
        per_minute = self.settings.login_attempts_per_minute
        if authorised:
            wait = await run_in_threadpool(lambda: self.store.login_wait(client=client, per_minute=per_minute))
        else:
            wait = await run_in_threadpool(lambda: self.store.login_attempt(client=client, per_minute=per_minute))
        return too_many_tries(wait) if wait is not None else None

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

        self._resolve_client(scope)
        try:
            refusal = await self._refusal(scope)
        except SQLAlchemyError as error:  # the token's rate limit or a login session met the database away
            refusal = database_error_response(error)
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
                if has_bearer_token(request, self.settings.api_token):
                    limited = await self._token_limit(scope, authorised=True)
                    if limited is not None:
                        return limited
                scope.setdefault("state", {})[AUTHORISED_STATE] = True  # the routes' checks need not look again
            else:
                if _bearer_presented(scope):
                    limited = await self._token_limit(scope, authorised=False)
                    if limited is not None:
                        return limited
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
