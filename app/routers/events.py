"""What happened to a run, newest first."""

from typing import Annotated

from fastapi import APIRouter, Query

from app.deps import ReadAuth, RunId, StoreDep
from app.schemas import EventOut, errors
from contract.store import INT32_MAX

router = APIRouter(prefix="/api/runs", tags=["events"], responses=errors(401))


@router.get("/{run_id}/events", response_model=list[EventOut], responses=errors(404))
def run_events(
    run_id: RunId,
    store: StoreDep,
    _auth: ReadAuth,
    since_id: Annotated[int, Query(ge=0, le=INT32_MAX, description="Only events with id > since_id.")] = 0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
) -> list[EventOut]:
    store.get_run(run_id=run_id)
    events = store.events(run_id=run_id, since_id=since_id, limit=limit)
    return [EventOut.model_validate(event, from_attributes=True) for event in events]
