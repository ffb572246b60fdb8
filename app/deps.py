"""FastAPI dependencies as Annotated aliases: the settings, the store, and write authorisation."""

import hashlib
import hmac
from typing import Annotated
from urllib.parse import urlsplit

from fastapi import Depends, HTTPException, Request, status

from app.settings import Settings
from app.store import Store

SESSION_COOKIE = "raq_session"


def get_app_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> Store:
    return request.app.state.store


SettingsDep = Annotated[Settings, Depends(get_app_settings)]
StoreDep = Annotated[Store, Depends(get_store)]


def session_value(token: str) -> str:
    """What the login cookie holds: a keyed hash of the token, so the cookie never carries the token."""
    return hmac.new(token.encode(), b"vice-raq session", hashlib.sha256).hexdigest()


def is_authorised(request: Request, settings: Settings) -> bool:
    """True without a token; with one, when the request carries the bearer token or the login cookie."""
    token = settings.api_token
    if not token:
        return True
    scheme, _, credentials = request.headers.get("authorization", "").partition(" ")
    if scheme.lower() == "bearer" and hmac.compare_digest(credentials.strip().encode(), token.encode()):
        return True
    cookie = request.cookies.get(SESSION_COOKIE, "")
    return bool(cookie) and hmac.compare_digest(cookie.encode(), session_value(token).encode())


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


def require_same_origin(request: Request) -> None:
    """403 for a write a browser sent on behalf of another site (CSRF, DNS rebinding)."""
    reason = cross_site_reason(request)
    if reason is not None:
        raise HTTPException(status_code=status.HTTP_403_FORBIDDEN, detail=CROSS_SITE_DETAIL.format(reason=reason))


def require_write_access(request: Request, settings: SettingsDep) -> None:
    """Writes: first refuse cross-site browser requests (with or without a token), then check the token."""
    require_same_origin(request)
    if not is_authorised(request, settings):
        raise HTTPException(
            status_code=status.HTTP_401_UNAUTHORIZED,
            detail="this server needs a token for changes: send 'Authorization: Bearer <token>' or log in at /login",
            headers={"WWW-Authenticate": "Bearer"},
        )


WriteAuth = Annotated[None, Depends(require_write_access)]
SameOrigin = Annotated[None, Depends(require_same_origin)]
