"""What the server says while its database is briefly away: a JSON 503 with Retry-After, and /health's report."""

import threading
import time

from fastapi.responses import JSONResponse
from sqlalchemy.exc import SQLAlchemyError

from contract.store import first_line, is_transient

RETRY_AFTER_S = 5
"""What a 503 tells a client to wait before it tries again."""
REMEMBERED_S = 30.0
"""How long /health reports a database error that a request met (reads may work while writes fail)."""


class DatabaseOutage:
    """The last transient database error a request met, and when."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._last: tuple[float, str] | None = None

    def seen(self, reason: str) -> None:
        with self._lock:
            self._last = (time.monotonic(), reason)

    def recent(self) -> str | None:
        """The error a request met in the last REMEMBERED_S seconds, if any."""
        with self._lock:
            if self._last is None or time.monotonic() - self._last[0] > REMEMBERED_S:
                return None
            return self._last[1]


database_outage = DatabaseOutage()


def database_unavailable(reason: str) -> JSONResponse:
    return JSONResponse(
        status_code=503, headers={"Retry-After": str(RETRY_AFTER_S)},
        content={"detail": f"the database is unreachable for now ({reason[:300]}); retry in a few seconds"},
    )  # fmt: skip


def database_error_response(error: SQLAlchemyError) -> JSONResponse:
    """A database that is briefly away (restarting, failing over, its disk full) is a 503 to retry, and /health
    reports it for a while; any other database error is the server's own 500. Neither carries a traceback."""
    if not is_transient(error):
        return JSONResponse(status_code=500, content={"detail": "internal server error"})
    database_outage.seen(first_line(error))
    return database_unavailable(first_line(error))
