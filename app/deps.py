"""FastAPI dependencies as Annotated aliases: the settings, the store, and write authorisation."""

import hashlib
import hmac
from typing import Annotated

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


def require_write_access(request: Request, settings: SettingsDep) -> None:
    if not is_authorised(request, settings):
        raise HTTPException(
            status_code=status.HTTP_401_UNAUTHORIZED,
            detail="this server needs a token for changes: send 'Authorization: Bearer <token>' or log in at /login",
            headers={"WWW-Authenticate": "Bearer"},
        )


WriteAuth = Annotated[None, Depends(require_write_access)]
