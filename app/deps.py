"""FastAPI dependencies as Annotated aliases: the settings, the store, ids in paths and booleans in query strings as
written, authorisation, the cross-site checks of writes and expensive reads; and the login sessions."""

import hashlib
import hmac
import re
import secrets
from typing import Annotated
from urllib.parse import urlsplit

from fastapi import Depends, HTTPException, Path, Request, status
from pydantic import BeforeValidator
from starlette.concurrency import run_in_threadpool

from contract.settings import Settings
from contract.store import INT32_MAX, Store

SESSION_COOKIE = "raq_session"
AUTHORISED_STATE = "raq_authorised"  # set in the request's state by app.security.RequestGuard


# Dependencies that do no blocking work are `async def`: FastAPI runs a plain `def` dependency in its thread pool,
# a hand-off that cost more of a request's server time than the database (py-spy under bench/load.py).
async def get_app_settings(request: Request) -> Settings:
    return request.app.state.settings


async def get_store(request: Request) -> Store:
    return request.app.state.store


SettingsDep = Annotated[Settings, Depends(get_app_settings)]
StoreDep = Annotated[Store, Depends(get_store)]


def _digits_only(value: object) -> object:
    """A path's id as written: ASCII digits and nothing else (" 1", "+1", "1_0" or "١" are not run 1)."""
    if isinstance(value, str) and not re.fullmatch(r"[0-9]+", value):
        raise ValueError("must be a whole number written in the digits 0-9 only")
    return value


def _true_or_false(value: object) -> object:
    """A query string's boolean: "true" or "false" only (not 0, 1, "yes", "off", …)."""
    if isinstance(value, str):
        if value not in ("true", "false"):
            raise ValueError("must be true or false")
        return value == "true"
    return value


# Ids in paths: digits only, bounded to their INTEGER column's range (32-bit on PostgreSQL): a larger one is 422,
# never an overflow inside the database driver.
RunId = Annotated[int, Path(ge=1, le=INT32_MAX, description="A run's id."), BeforeValidator(_digits_only)]
GoalSetId = Annotated[int, Path(ge=1, le=INT32_MAX, description="A goal set's id."), BeforeValidator(_digits_only)]
GoalExampleId = Annotated[
    int, Path(ge=1, le=INT32_MAX, description="A goal example's id."), BeforeValidator(_digits_only)
]
QueryId = Annotated[int, Path(ge=1, le=INT32_MAX, description="A query's id."), BeforeValidator(_digits_only)]
QueryBool = Annotated[bool, BeforeValidator(_true_or_false)]
"""A boolean query parameter (with Query(...) beside it): only the words true and false."""


def token_fingerprint(token: str) -> str:
    """A keyed hash of the API token stored with each session: a new token ends every older session."""
    return hmac.new(token.encode(), b"vice-raq session", hashlib.sha256).hexdigest()


def new_session_secret() -> str:
    """What the login cookie holds: 256 random bits, unrelated to the token."""
    return secrets.token_urlsafe(32)


def secret_hash(secret: str) -> str:
    """What the store keeps of a session's secret (a database reader cannot log in with it)."""
    return hashlib.sha256(secret.encode()).hexdigest()


def has_bearer_token(request: Request, token: str) -> bool:
    scheme, _, credentials = request.headers.get("authorization", "").partition(" ")
    return scheme.lower() == "bearer" and hmac.compare_digest(credentials.strip().encode(), token.encode())


def _authorised_by_headers(request: Request, settings: Settings) -> bool | None:
    """True or False where the headers decide; None where a login session has to be looked up in the store."""
    token = settings.api_token
    if not token or request.scope.get("state", {}).get(AUTHORISED_STATE):
        return True
    if has_bearer_token(request, token):
        return True
    secret = request.cookies.get(SESSION_COOKIE, "")
    if not secret or len(secret) > 200:
        return False
    return None


def _session_is_active(request: Request, settings: Settings, store: Store) -> bool:
    secret = request.cookies[SESSION_COOKIE]
    return store.session_is_active(
        secret_hash=secret_hash(secret), token_fingerprint=token_fingerprint(settings.api_token or "")
    )


def is_authorised(request: Request, settings: Settings, store: Store) -> bool:
    """True without a token; with one, when the request carries the bearer token or a live login session.
    Reads only headers (never the body), so app.security.RequestGuard can call it before the body arrives."""
    decided = _authorised_by_headers(request, settings)
    return decided if decided is not None else _session_is_active(request, settings, store)


async def is_authorised_async(request: Request, settings: Settings, store: Store) -> bool:
    """is_authorised from the event loop: only a login session's lookup goes to the thread pool."""
    decided = _authorised_by_headers(request, settings)
    if decided is not None:
        return decided
    return await run_in_threadpool(_session_is_active, request, settings, store)


DEFAULT_PORTS = {"http": 80, "https": 443}
CROSS_SITE_DETAIL = (
    "refused a change sent from another web site ({reason}); "
    "use this server's own pages, or a program that sends no Origin header (curl, httpx, raq oracle)"
)


def _split_host_port(netloc: str, default_port: int | None) -> tuple[str, int | None] | None:
    """'Host:port' (or '[::1]:port') as (lower-case host, port); None when it cannot be read."""
    try:
        parts = urlsplit(f"//{netloc}")
        return (parts.hostname or "").lower(), parts.port or default_port
    except ValueError:
        return None


def cross_site_reason(request: Request) -> str | None:
    """Why this request looks like it was sent by a page of another site, or None when it does not.

    Browsers label every request they send: `Sec-Fetch-Site` (modern browsers) and `Origin` (on every
    POST/PUT/DELETE, also on same-origin ones). A write whose Origin is not this server's own Host is
    refused; a request with neither header (curl, httpx, the oracle) is not a browser's and passes.
    """
    if request.headers.get("sec-fetch-site", "").strip().lower() == "cross-site":
        return "Sec-Fetch-Site: cross-site"
    origin = request.headers.get("origin")
    if origin is None:
        return None
    parts = urlsplit(origin.strip())
    if parts.scheme not in DEFAULT_PORTS or not parts.netloc:
        return f"Origin {origin!r}"  # 'null' (sandboxed frames, file: pages) or junk
    default_port = DEFAULT_PORTS[parts.scheme]
    origin_host = _split_host_port(parts.netloc, default_port)
    host_header = request.headers.get("host", "")
    host = _split_host_port(host_header, default_port)
    if origin_host is None or host is None or not host[0] or origin_host != host:
        return f"Origin {origin!r} is not this server's Host {host_header!r}"
    return None


async def require_same_origin(request: Request) -> None:
    """403 for a write a browser sent on behalf of another site (CSRF, DNS rebinding)."""
    reason = cross_site_reason(request)
    if reason is not None:
        raise HTTPException(status_code=status.HTTP_403_FORBIDDEN, detail=CROSS_SITE_DETAIL.format(reason=reason))


CROSS_SITE_READ_DETAIL = (
    "refused a read sent from another web site's page (Sec-Fetch-Site: cross-site): previews, images and exports "
    "are served to this server's own pages and to programs (curl, httpx, raq oracle) only"
)


async def require_same_site_read(request: Request) -> None:
    """403 for an expensive read (a preview, an image, an export) that a browser sent from another site's page,
    say as an <img> tag: such a page could make this server render and hold frames for it. Browsers label the
    request Sec-Fetch-Site: cross-site; this server's own pages send same-origin, a typed address none, and curl
    or httpx no such header at all, and those pass."""
    if request.headers.get("sec-fetch-site", "").strip().lower() == "cross-site":
        raise HTTPException(status_code=status.HTTP_403_FORBIDDEN, detail=CROSS_SITE_READ_DETAIL)


UNAUTHORISED_DETAIL = "this server needs a token: send 'Authorization: Bearer <token>' or log in at /login"


def unauthorised() -> HTTPException:
    return HTTPException(
        status_code=status.HTTP_401_UNAUTHORIZED, detail=UNAUTHORISED_DETAIL, headers={"WWW-Authenticate": "Bearer"}
    )


async def require_read_access(request: Request, settings: SettingsDep, store: StoreDep) -> None:
    """Reads need the token too when one is set. RequestGuard has refused such a request already, before its
    body; this dependency documents the 401 in the OpenAPI spec and holds if the guard is ever bypassed."""
    if not await is_authorised_async(request, settings, store):
        raise unauthorised()


async def require_write_access(request: Request, settings: SettingsDep, store: StoreDep) -> None:
    """Writes: first refuse cross-site browser requests (with or without a token), then check the token."""
    await require_same_origin(request)
    if not await is_authorised_async(request, settings, store):
        raise unauthorised()


ReadAuth = Annotated[None, Depends(require_read_access)]
WriteAuth = Annotated[None, Depends(require_write_access)]
SameOrigin = Annotated[None, Depends(require_same_origin)]
SameSiteRead = Annotated[None, Depends(require_same_site_read)]
