"""HTML pages (Jinja2, no build step). They read through the store and write through the REST API."""

import hmac
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Form, Query, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from fastapi.templating import Jinja2Templates

from app.deps import (
    SESSION_COOKIE,
    GoalSetId,
    RunId,
    SameOrigin,
    SettingsDep,
    StoreDep,
    is_authorised,
    new_session_secret,
    secret_hash,
    token_fingerprint,
)
from app.previews import suggested_env_ids
from app.schemas import GoalExampleOut, GoalSetOut, row_with
from app.views import COMPARE_METRICS, evaluated_policies, list_run_outs, run_detail, run_out, task_settings_out
from contract.algorithms import ALGORITHM_SPECS
from contract.config import FEWEST_GOAL_IMAGES, REAL_ROBOT_GOAL_IMAGES, TrainConfig, config_reference
from contract.store import INT32_MAX, NotFound, QueryStatus, RunStatus

TEMPLATES_DIR = Path(__file__).resolve().parent.parent.parent / "templates"
templates = Jinja2Templates(directory=TEMPLATES_DIR)

router = APIRouter(include_in_schema=False)

FALLBACK_TASKS: dict[str, str] = {
    "pusher": "VisualPusher-v0", "door": "VisualDoor-v0", "picker": "VisualPicker-v0",
    "bookshelf": "VisualBookshelf-v0", "draping": "VisualDraping-v0",
}  # fmt: skip
OptionalId = Annotated[int | None, Query(ge=1, le=INT32_MAX)]
# How many goal photos to give: the goal-set page warns below FEWEST (the README asks for as many), more help (the
# paper's real-robot tasks used PAPER).
GOAL_PHOTOS = {"fewest": FEWEST_GOAL_IMAGES, "paper": REAL_ROBOT_GOAL_IMAGES}


@dataclass(frozen=True)
class Task:
    name: str
    env_id: str


@lru_cache(maxsize=1)
def available_tasks() -> tuple[Task, ...]:
    """The simulator's registered tasks; the three known ids while the sim package cannot be imported."""
    try:
        import sim  # noqa: PLC0415 - imported lazily: it pulls in MuJoCo

        registered: dict[str, Any] = dict(sim.TASKS)
    except Exception:  # noqa: BLE001 - no sim package (yet): fall back to the known ids
        return tuple(Task(name, env_id) for name, env_id in FALLBACK_TASKS.items())
    tasks = []
    for name, task in registered.items():
        env_id = task if isinstance(task, str) else getattr(task, "env_id", None)
        if env_id is None and isinstance(task, dict):
            env_id = task.get("env_id")
        tasks.append(Task(str(name), str(env_id or FALLBACK_TASKS.get(name, name))))
    return tuple(tasks) or tuple(Task(name, env_id) for name, env_id in FALLBACK_TASKS.items())


def _page(request: Request, template: str, settings: Any, store: Any, status_code: int = 200, **context: Any):
    authorised = is_authorised(request, settings, store)
    base = {
        "auth_required": bool(settings.api_token),
        "authorised": authorised,
        "pending_total": store.count_queries(status=QueryStatus.PENDING, live_runs=True) if authorised else 0,
        "path": request.url.path,
        "stale_after_seconds": settings.stale_heartbeat_seconds,
        # values the page scripts need from Python (static/app.js reads them), so they are not retyped there
        "page_constants": {"active_statuses": list(RunStatus.ACTIVE), "live_statuses": list(RunStatus.LIVE)},
    }
    return templates.TemplateResponse(request, template, {**base, **context}, status_code=status_code)


def _not_found(request: Request, settings: Any, store: Any, message: str):
    return _page(request, "not_found.html", settings, store, status_code=404, message=message, title="Not found")


@router.get("/", response_class=HTMLResponse)
def runs_page(request: Request, settings: SettingsDep, store: StoreDep, archived: bool = False):
    runs = [run.model_dump(mode="json") for run in list_run_outs(store, archived=archived)]
    title = "Archived runs" if archived else "Runs"
    return _page(request, "runs.html", settings, store, runs=runs, title=title, archived=archived)


@router.get("/runs/new", response_class=HTMLResponse)
def new_run_page(request: Request, settings: SettingsDep, store: StoreDep, goal_set: OptionalId = None):
    defaults = TrainConfig()
    goal_sets = [
        GoalSetOut.model_validate(row_with(row, example_count=count), from_attributes=True)
        for row, count in store.list_goal_sets()
    ]
    # the set asked for ("Start a run with this set"), else the newest; its task is the form's task
    chosen = next((g for g in goal_sets if g.id == goal_set), goal_sets[-1] if goal_sets else None)
    tasks = available_tasks()
    env_id = (chosen.env_id if chosen else None) or (tasks[0].env_id if tasks else "VisualPusher-v0")
    return _page(
        request,
        "new_run.html",
        settings,
        store,
        title="New run",
        tasks=tasks,
        initial_env_id=env_id,
        env_ids=suggested_env_ids(settings),  # image envs of the allowed modules (the tasks come with `tasks`)
        env_modules=list(settings.env_modules),
        algorithms=[(name, spec.label) for name, spec in ALGORITHM_SPECS.items()],
        goal_sets=goal_sets,
        selected_goal_set=chosen.id if chosen else None,
        defaults=defaults,
        config_reference=config_reference(),
        task_settings={env_id: task.model_dump() for env_id, task in task_settings_out().items()},
    )


@router.get("/runs/{run_id}", response_class=HTMLResponse)
def run_page(run_id: RunId, request: Request, settings: SettingsDep, store: StoreDep):
    try:
        run = run_detail(store, store.get_run(run_id=run_id))
    except NotFound as error:
        return _not_found(request, settings, store, str(error))
    goal_set_name = None
    if run.goal_set_id is not None:
        try:
            goal_set_name = store.get_goal_set(goal_set_id=run.goal_set_id).name
        except NotFound:
            goal_set_name = None
    return _page(
        request,
        "run.html",
        settings,
        store,
        title=f"Run {run.id}",
        run=run.model_dump(mode="json"),
        goal_set_name=goal_set_name,
        policies=evaluated_policies(settings, run.id),  # the export's evaluated policies, labelled
    )


@router.get("/goal-sets", response_class=HTMLResponse)
def goal_sets_page(request: Request, settings: SettingsDep, store: StoreDep):
    goal_sets = []
    for goal_set, count in store.list_goal_sets():
        examples = store.list_goal_examples(goal_set_id=goal_set.id)[:6]
        goal_sets.append(
            (
                GoalSetOut.model_validate(row_with(goal_set, example_count=count), from_attributes=True),
                [GoalExampleOut.model_validate(example, from_attributes=True) for example in examples],
            )
        )
    return _page(
        request, "goal_sets.html", settings, store, title="Goal sets", goal_sets=goal_sets, tasks=available_tasks()
    )


@router.get("/goal-sets/{goal_set_id}", response_class=HTMLResponse)
def goal_set_page(goal_set_id: GoalSetId, request: Request, settings: SettingsDep, store: StoreDep):
    try:
        goal_set = store.get_goal_set(goal_set_id=goal_set_id)
    except NotFound as error:
        return _not_found(request, settings, store, str(error))
    examples = [
        GoalExampleOut.model_validate(example, from_attributes=True)
        for example in store.list_goal_examples(goal_set_id=goal_set_id)
    ]
    return _page(
        request,
        "goal_set.html",
        settings,
        store,
        title=goal_set.name,
        goal_set=GoalSetOut.model_validate(row_with(goal_set, example_count=len(examples)), from_attributes=True),
        examples=examples,
        max_upload_bytes=settings.max_upload_bytes,
        tasks=available_tasks(),
        goal_photos=GOAL_PHOTOS,
    )


@router.get("/compare", response_class=HTMLResponse)
def compare_page(
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    runs: Annotated[str, Query(max_length=600)] = "",
    metric: Annotated[str, Query(max_length=100)] = "eval/success_rate",
):
    run_ids = [int(part) for part in runs.split(",") if part.strip().isdigit() and 1 <= int(part) <= INT32_MAX]
    for run_id in run_ids:
        try:
            store.get_run(run_id=run_id)
        except NotFound as error:
            return _not_found(request, settings, store, str(error))
    metric = metric if metric in COMPARE_METRICS else "eval/success_rate"
    return _page(
        request, "compare.html", settings, store, title="Compare runs", run_ids=run_ids, metric=metric,
        metrics=COMPARE_METRICS,
    )  # fmt: skip


@router.get("/queue", response_class=HTMLResponse)
def queue_page(request: Request, settings: SettingsDep, store: StoreDep, run: OptionalId = None):
    run_summary = None
    if run is not None:
        try:
            run_summary = run_out(store, store.get_run(run_id=run))
        except NotFound as error:
            return _not_found(request, settings, store, str(error))
    return _page(request, "queue.html", settings, store, title="Answer queue", run_id=run, run=run_summary)


def _local_path(target: str | None) -> str:
    """Only redirect within this site."""
    if not target or not target.startswith("/") or target.startswith("//") or "\\" in target:
        return "/"
    return target


@router.get("/login", response_class=HTMLResponse)
def login_page(request: Request, settings: SettingsDep, store: StoreDep, next: str | None = None):
    return _page(request, "login.html", settings, store, title="Log in", next=_local_path(next), error=None)


def _client_address(request: Request) -> str:
    return request.client.host if request.client else "unknown"


@router.post("/login", response_model=None)
def login(
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    _origin: SameOrigin,
    token: Annotated[str, Form(max_length=1000)] = "",
    next: Annotated[str, Form(max_length=2000)] = "/",
) -> Response:
    """A right token starts a server-side session (the cookie holds its random secret); failed attempts are
    limited per client address (429 with Retry-After once over RAQ_LOGIN_ATTEMPTS_PER_MINUTE)."""
    target = _local_path(next)
    if not settings.api_token:
        return RedirectResponse(target, status_code=303)
    client = _client_address(request)
    wait = store.login_attempt(client=client, per_minute=settings.login_attempts_per_minute)  # counted as failed
    if wait is not None:
        refused = _page(
            request, "login.html", settings, store, status_code=429, title="Log in", next=target,
            error=f"Too many wrong tokens from your address: try again in {wait} s.",
        )  # fmt: skip
        refused.headers["Retry-After"] = str(wait)
        return refused
    if not hmac.compare_digest(token.strip().encode(), settings.api_token.encode()):
        return _page(
            request, "login.html", settings, store, status_code=401, title="Log in", next=target,
            error="That token is not right.",
        )  # fmt: skip
    store.login_succeeded(client=client)
    secret = new_session_secret()
    store.create_session(
        secret_hash=secret_hash(secret),
        token_fingerprint=token_fingerprint(settings.api_token),
        max_age_seconds=settings.session_max_age_seconds,
        client=f"{client} {request.headers.get('user-agent', '')}",
    )
    response = RedirectResponse(target, status_code=303)
    response.set_cookie(
        SESSION_COOKIE,
        secret,
        max_age=settings.session_max_age_seconds,
        httponly=True,
        samesite="strict",
        secure=request.url.scheme == "https",
        path="/",
    )
    return response


@router.post("/logout", response_model=None)
def logout(request: Request, store: StoreDep, _origin: SameOrigin) -> Response:
    """Ends the session on the server (the cookie alone no longer works) and drops the cookie."""
    secret = request.cookies.get(SESSION_COOKIE, "")
    if secret:
        store.end_session(secret_hash=secret_hash(secret))
    response = RedirectResponse("/login" if request.app.state.settings.api_token else "/", status_code=303)
    response.delete_cookie(SESSION_COOKIE, path="/")
    return response
