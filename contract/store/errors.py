"""Errors the store raises; the web app maps them to HTTP status codes (404, 409, 400, and 503 for a database that
is briefly away)."""

from sqlalchemy import exc


class StoreError(Exception):
    """Base class: the message is meant for the person or program that asked."""


class NotFound(StoreError):
    pass


class Conflict(StoreError):
    pass


class InvalidInput(StoreError):
    pass


class StoreSilent(StoreError):
    """The store did not answer within the bound a caller set (contract/store/bounded.py): it counts as away."""


# What a database says while it is briefly away: a restart or failover (the connection drops, or none can be made),
# a full disk, or another writer holding SQLite's lock past the busy timeout. The request or step may succeed later.
TRANSIENT_MESSAGES = (
    "database or disk is full", "disk i/o error", "unable to open database file", "database is locked",
    "server closed the connection", "connection refused", "terminating connection", "connection is closed",
    "the database system is starting up", "the database system is shutting down", "could not connect",
    "connection failed", "consuming input failed", "is the server running", "no space left on device",
    "cannot connect", "connection timeout expired", "the connection is lost", "ssl connection has been closed",
)  # fmt: skip


def is_transient(error: BaseException) -> bool:
    """Is `error` (or the error it wraps) a database that is briefly away, not a bad statement or bad data?

    Only the database's own errors count (SQLAlchemy's OperationalError and friends with one of the messages
    above, or a connection the pool found dropped): an OSError of anything else (a full checkpoint disk, an env's
    connection reset) is that thing's failure, never a blink."""
    for current in error_chain(error):
        if isinstance(current, StoreSilent):
            return True
        if isinstance(current, exc.DBAPIError) and current.connection_invalidated:
            return True
        if isinstance(current, exc.OperationalError | exc.InterfaceError | exc.DisconnectionError | exc.TimeoutError):
            message = str(current).lower()
            if any(text in message for text in TRANSIENT_MESSAGES):
                return True
    return False


def first_line(error: BaseException) -> str:
    """The error's type and the first line of its message, as a failure reason a person can read."""
    message = next((line.strip() for line in str(error).splitlines() if line.strip()), "")
    return f"{type(error).__name__}: {message}" if message else type(error).__name__


def error_chain(error: BaseException) -> list[BaseException]:
    """`error` and every error it wraps or was raised while handling (a driver's error, a cause, a context)."""
    seen: list[BaseException] = []
    current: BaseException | None = error
    while current is not None and current not in seen:
        seen.append(current)
        current = getattr(current, "orig", None) or current.__cause__ or current.__context__
    return seen
