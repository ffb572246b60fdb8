"""Liveness and database reachability."""

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from app.database_outage import RETRY_AFTER_S, database_outage
from app.deps import StoreDep
from app.schemas import HealthOut
from contract.store import first_line

router = APIRouter(tags=["health"])


@router.get(
    "/health",
    response_model=HealthOut,
    responses={503: {"model": HealthOut, "description": "The database cannot be reached"}},
)
def health(store: StoreDep) -> HealthOut | JSONResponse:
    """ok, or 503 with the database's error: when it cannot be reached, or when a request met a transient error
    in the last 30 s (a full disk: reads work while writes fail)."""
    try:
        store.ping()
    except Exception as error:  # noqa: BLE001 - any database failure is reported, not raised
        body = HealthOut(status="error", database=first_line(error)[:300])
        return JSONResponse(status_code=503, content=body.model_dump(), headers={"Retry-After": str(RETRY_AFTER_S)})
    recent = database_outage.recent()
    if recent is not None:
        body = HealthOut(status="error", database=f"a request met: {recent[:300]}")
        return JSONResponse(status_code=503, content=body.model_dump(), headers={"Retry-After": str(RETRY_AFTER_S)})
    return HealthOut(status="ok", database="ok")
