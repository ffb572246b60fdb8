"""Queries the learner asks: list, the next one to answer, images, answer, skip, undo.

The labelling endpoints are `async def` and hand only their store call to the thread pool. A plain `def` endpoint
costs two hand-offs to the pool (the call, then FastAPI's validation of the returned model), which under
bench/load.py took more of the server's time per request than the database did.
"""

from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response
from starlette.concurrency import run_in_threadpool

from app.deps import QueryId, ReadAuth, SameSiteRead, StoreDep, WriteAuth
from app.schemas import WRITE_ERRORS, AnswerIn, GoalExampleOut, QueryOut, QueueItem, SkipIn, errors
from app.views import run_out
from contract.store import INT32_MAX, NotFound, QueryStatus, Store
from contract.store import Query as QueryRow

router = APIRouter(prefix="/api/queries", tags=["queries"], responses=errors(401))


def query_out(query: QueryRow) -> QueryOut:
    return QueryOut.model_validate(query, from_attributes=True)


RunFilter = Annotated[int | None, Query(ge=1, le=INT32_MAX, description="Only this run's queries.")]


@router.get("", response_model=list[QueryOut])
async def list_queries(
    store: StoreDep,
    _auth: ReadAuth,
    run_id: RunFilter = None,
    status: Annotated[Literal["pending", "answered", "skipped"] | None, Query()] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 200,
) -> list[QueryOut]:
    """Pending queries come oldest first (the order to answer them); others newest first."""
    oldest_first = status == QueryStatus.PENDING
    rows = await run_in_threadpool(
        store.list_queries, run_id=run_id, status=status, limit=limit, oldest_first=oldest_first
    )
    return [query_out(query) for query in rows]


@router.get("/next", response_model=QueueItem, responses=errors(404))
async def next_query(store: StoreDep, _auth: ReadAuth, run_id: RunFilter = None) -> QueueItem:
    """The oldest pending query of one run, or of all runs the oldest of a live run (queued, starting, training)
    before those of stopped, finished or failed runs; its run and the run's goal photos. `pending_all_runs`
    counts only live runs' questions (the badge)."""
    return await run_in_threadpool(_queue_item, store, run_id)


def _queue_item(store: Store, run_id: int | None) -> QueueItem:
    if run_id is not None:
        store.get_run(run_id=run_id)
    query = store.next_pending_query(run_id=run_id)
    if query is not None:  # a page shows it now: the person's answering time counts from here
        store.mark_query_shown(query_id=query.id)
    # the badge counts the questions of live runs (queued, starting, training); the all-runs queue shows theirs
    # first and those of stopped, finished or failed runs after them, so its count includes those
    pending_all_runs = store.count_queries(status=QueryStatus.PENDING, live_runs=True)
    pending = store.count_queries(run_id=run_id, status=QueryStatus.PENDING)
    if query is None:
        run = store.get_run(run_id=run_id) if run_id is not None else None
        return QueueItem(
            query=None,
            pending=0,
            pending_all_runs=pending_all_runs,
            run=run_out(store, run) if run else None,
            goal_examples=[],
        )
    run = store.get_run(run_id=query.run_id)
    examples: list[GoalExampleOut] = []
    if run.goal_set_id is not None:
        try:
            examples = [
                GoalExampleOut.model_validate(example, from_attributes=True)
                for example in store.list_goal_examples(goal_set_id=run.goal_set_id)
            ]
        except NotFound:
            examples = []
    return QueueItem(
        query=query_out(query),
        pending=pending,
        pending_all_runs=pending_all_runs,
        run=run_out(store, run),
        goal_examples=examples,
    )


@router.get("/{query_id}", response_model=QueryOut, responses=errors(404))
async def get_query(query_id: QueryId, store: StoreDep, _auth: ReadAuth) -> QueryOut:
    return query_out(await run_in_threadpool(store.get_query, query_id=query_id))


@router.get(
    "/{query_id}/image", response_class=Response, responses={200: {"content": {"image/png": {}}}, **errors(403, 404)}
)
def query_image(
    query_id: QueryId,
    store: StoreDep,
    _auth: ReadAuth,
    _same_site: SameSiteRead,
    resolution: Annotated[Literal["model", "display"], Query()] = "display",
) -> Response:
    """model: the observation the learner scored (e.g. 48x48); display: the larger render of the same state."""
    data = store.query_image(query_id=query_id, resolution=resolution)
    return Response(content=data, media_type="image/png", headers={"Cache-Control": "private, max-age=86400"})


@router.post("/{query_id}/answer", response_model=QueryOut, responses=errors(404, 409, *WRITE_ERRORS))
async def answer_query(query_id: QueryId, body: AnswerIn, store: StoreDep, _auth: WriteAuth) -> QueryOut:
    """The same answer twice is fine; a different second answer is 409 and the first is kept."""
    answer = {"query_id": query_id, "success": body.success, "labeler": body.labeler}
    return query_out(await run_in_threadpool(store.answer_query, **answer))


@router.post("/{query_id}/skip", response_model=QueryOut, responses=errors(404, 409, *WRITE_ERRORS))
async def skip_query(query_id: QueryId, store: StoreDep, _auth: WriteAuth, body: SkipIn | None = None) -> QueryOut:
    labeler = body.labeler if body else ""
    return query_out(await run_in_threadpool(store.skip_query, query_id=query_id, labeler=labeler))


@router.post("/{query_id}/undo", response_model=QueryOut, responses=errors(404, 409, *WRITE_ERRORS))
async def undo_answer(query_id: QueryId, store: StoreDep, _auth: WriteAuth) -> QueryOut:
    """Back to pending, while the learner has not used the answer (409 once it has)."""
    return query_out(await run_in_threadpool(store.undo_answer, query_id=query_id))
