"""Liveness and database reachability."""

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from app.deps import StoreDep
from app.schemas import HealthOut

router = APIRouter(tags=["health"])


@router.get(
    "/health",
    response_model=HealthOut,
    responses={503: {"model": HealthOut, "description": "The database cannot be reached"}},
)
def health(store: StoreDep) -> HealthOut | JSONResponse:
    try:
        store.ping()
    except Exception as error:  # noqa: BLE001 - any database failure is reported, not raised
        body = HealthOut(status="error", database=f"{type(error).__name__}: {error}".splitlines()[0][:300])
        return JSONResponse(status_code=503, content=body.model_dump())
    return HealthOut(status="ok", database="ok")
