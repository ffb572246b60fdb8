"""Queries the learner asks: list, the next one to answer, images, answer, skip, undo."""

from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response

from app.deps import StoreDep, WriteAuth
from app.routers.runs import run_out
from app.schemas import AnswerIn, GoalExampleOut, QueryOut, QueueItem, SkipIn
from app.store import NotFound, QueryStatus

router = APIRouter(prefix="/api/queries", tags=["queries"])

PENDING_COUNT_LIMIT = 100_000


@router.get("", response_model=list[QueryOut])
def list_queries(
    store: StoreDep,
    run_id: int | None = None,
    status: Annotated[Literal["pending", "answered", "skipped"] | None, Query()] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
) -> list[QueryOut]:
    """Pending queries come oldest first (the order to answer them); others newest first."""
    rows = store.list_queries(run_id=run_id, status=status, limit=limit, oldest_first=status == QueryStatus.PENDING)
    return [QueryOut.of(query) for query in rows]


@router.get("/next", response_model=QueueItem)
def next_query(store: StoreDep, run_id: int | None = None) -> QueueItem:
    """The oldest pending query (of one run, or of all), its run and the run's goal photos."""
    if run_id is not None:
        store.get_run(run_id=run_id)
    pending = store.pending_queries(run_id=run_id, limit=PENDING_COUNT_LIMIT)
    pending_all_runs = len(pending) if run_id is None else len(store.pending_queries(limit=PENDING_COUNT_LIMIT))
    if not pending:
        run = store.get_run(run_id=run_id) if run_id is not None else None
        return QueueItem(
            query=None,
            pending=0,
            pending_all_runs=pending_all_runs,
            run=run_out(store, run) if run else None,
            goal_examples=[],
        )
    query = pending[0]
    run = store.get_run(run_id=query.run_id)
    examples: list[GoalExampleOut] = []
    if run.goal_set_id is not None:
        try:
            examples = [GoalExampleOut.of(e) for e in store.list_goal_examples(goal_set_id=run.goal_set_id)]
        except NotFound:
            examples = []
    return QueueItem(
        query=QueryOut.of(query),
        pending=len(pending),
        pending_all_runs=pending_all_runs,
        run=run_out(store, run),
        goal_examples=examples,
    )


@router.get("/{query_id}", response_model=QueryOut)
def get_query(query_id: int, store: StoreDep) -> QueryOut:
    return QueryOut.of(store.get_query(query_id=query_id))


@router.get("/{query_id}/image", response_class=Response, responses={200: {"content": {"image/png": {}}}})
def query_image(
    query_id: int,
    store: StoreDep,
    resolution: Annotated[Literal["model", "display"], Query()] = "display",
) -> Response:
    """model: the observation the learner scored (e.g. 48x48); display: the larger render of the same state."""
    data = store.query_image(query_id=query_id, resolution=resolution)
    return Response(content=data, media_type="image/png", headers={"Cache-Control": "private, max-age=86400"})


@router.post("/{query_id}/answer", response_model=QueryOut, responses={409: {"description": "Answered otherwise"}})
def answer_query(query_id: int, body: AnswerIn, store: StoreDep, _auth: WriteAuth) -> QueryOut:
    """The same answer twice is fine; a different second answer is 409 and the first is kept."""
    return QueryOut.of(store.answer_query(query_id=query_id, success=body.success, labeler=body.labeler))


@router.post("/{query_id}/skip", response_model=QueryOut)
def skip_query(query_id: int, store: StoreDep, _auth: WriteAuth, body: SkipIn | None = None) -> QueryOut:
    return QueryOut.of(store.skip_query(query_id=query_id, labeler=body.labeler if body else ""))


@router.post("/{query_id}/undo", response_model=QueryOut, responses={409: {"description": "Already used"}})
def undo_answer(query_id: int, store: StoreDep, _auth: WriteAuth) -> QueryOut:
    """Back to pending, while the learner has not used the answer (409 once it has)."""
    return QueryOut.of(store.undo_answer(query_id=query_id))
