"""Runs: create (validated with TrainConfig), list, read, stop, resume, and the latest rollout animation."""

from typing import Any

import pydantic
from fastapi import APIRouter, HTTPException, Response, status

from app.deps import ReadAuth, RunId, SettingsDep, StoreDep, WriteAuth
from app.schemas import WRITE_ERRORS, RolloutOut, RunCreate, RunDetail, RunOut, errors
from app.settings import Settings
from app.store import NotFound, Run, Store
from learner.algorithms import ALGORITHM_SPECS
from learner.config import TrainConfig, host_cuda_devices, host_memory_bytes
from learner.envs import env_id_problem

router = APIRouter(prefix="/api/runs", tags=["runs"], responses=errors(401))

TOP_LEVEL_FIELDS = ("env_id", "algorithm", "seed")
_config_adapter = pydantic.TypeAdapter(TrainConfig)


def run_out(store: Store, run: Run) -> RunOut:
    return RunOut.of(
        run,
        queries=store.query_counts(run_id=run.id),
        success_rate=store.latest_metric(run_id=run.id, name="eval/success_rate"),
        steps_per_second=store.latest_metric(run_id=run.id, name="perf/steps_per_second"),
        eta_seconds=store.latest_metric(run_id=run.id, name="perf/eta_seconds"),
    )


def run_detail(store: Store, run: Run) -> RunDetail:
    rollout = store.latest_rollout(run_id=run.id)
    return RunDetail(
        **run_out(store, run).model_dump(),
        config=run.config or {},
        latest_rollout=RolloutOut.of(rollout) if rollout is not None else None,
    )


def _field_error(location: list[str | int], field: str, message: str) -> dict[str, Any]:
    return {"loc": location, "msg": f"{field}: {message}", "type": "value_error"}


def validate_run_config(body: RunCreate, settings: Settings) -> TrainConfig:
    """The body's settings as a TrainConfig, or HTTP 422 whose detail names every bad field: a value out of its
    bounds, more than this host can run (memory, GPU), or an env id that is not registered or allowed."""
    values = dict(body.config)
    given_on_top = {name for name in TOP_LEVEL_FIELDS if getattr(body, name) is not None}
    for name in given_on_top:
        values[name] = getattr(body, name)

    def location(field: str) -> list[str | int]:
        return ["body", field] if field in given_on_top else ["body", "config", field]

    known = {field.name for field in TrainConfig.__dataclass_fields__.values()}
    unknown = sorted(set(values) - known)
    if unknown:
        raise HTTPException(
            status_code=422, detail=[_field_error(location(name), name, "unknown config field") for name in unknown]
        )
    try:
        config = _config_adapter.validate_python(values)
    except pydantic.ValidationError as error:
        detail = []
        for item in error.errors(include_url=False):
            if item["loc"]:
                field = str(item["loc"][0])
                detail.append(_field_error(location(field), field, item["msg"]))
            else:  # TrainConfig.__post_init__: "field: message"
                cause = str(item.get("ctx", {}).get("error", item["msg"]))
                field, _, message = cause.partition(": ")
                detail.append(_field_error(location(field), field, message or cause))
        raise HTTPException(status_code=422, detail=detail) from None
    problems = config.resource_errors(memory_bytes=host_memory_bytes(), cuda_devices=host_cuda_devices())
    env_problem = env_id_problem(config.env_id, allowed_modules=settings.env_modules)
    if env_problem:
        problems.append(("env_id", env_problem))
    if problems:
        raise HTTPException(
            status_code=422, detail=[_field_error(location(field), field, message) for field, message in problems]
        )
    return config


def _goal_set_error(message: str) -> HTTPException:
    return HTTPException(status_code=422, detail=[_field_error(["body", "goal_set_id"], "goal_set_id", message)])


def check_goal_set(store: Store, *, algorithm: str, goal_set_id: int | None) -> None:
    """Every algorithm but sparse learns its reward from goal examples: it needs a set with at least one."""
    spec = ALGORITHM_SPECS.get(algorithm)
    needs_goals = spec is None or spec.needs_goals  # (an unknown algorithm is refused by the config's check)
    if goal_set_id is None:
        if not needs_goals:
            return
        raise _goal_set_error(
            f"algorithm {algorithm!r} learns its reward from goal photos: choose a goal set "
            "with at least one example (only 'sparse' runs without one)"
        )
    try:
        store.get_goal_set(goal_set_id=goal_set_id)
    except NotFound:
        raise _goal_set_error(f"goal set {goal_set_id} not found") from None
    if needs_goals and not store.list_goal_examples(goal_set_id=goal_set_id):
        raise _goal_set_error(
            f"goal set {goal_set_id} has no goal photos yet; upload at least one before starting a {algorithm!r} run"
        )


@router.post("", status_code=status.HTTP_201_CREATED, response_model=RunDetail, responses=errors(*WRITE_ERRORS))
def create_run(body: RunCreate, store: StoreDep, settings: SettingsDep, _auth: WriteAuth) -> RunDetail:
    config = validate_run_config(body, settings)
    check_goal_set(store, algorithm=config.algorithm, goal_set_id=body.goal_set_id)
    run = store.create_run(
        env_id=config.env_id,
        algorithm=config.algorithm,
        config=config.to_dict(),
        seed=config.seed,
        goal_set_id=body.goal_set_id,
        total_steps=config.total_steps,
        name=body.name.strip(),
    )
    return run_detail(store, run)


@router.get("", response_model=list[RunOut])
def list_runs(store: StoreDep, _auth: ReadAuth) -> list[RunOut]:
    return [run_out(store, run) for run in store.list_runs()]


@router.get("/{run_id}", response_model=RunDetail, responses=errors(404))
def get_run(run_id: RunId, store: StoreDep, _auth: ReadAuth) -> RunDetail:
    return run_detail(store, store.get_run(run_id=run_id))


@router.post("/{run_id}/stop", response_model=RunDetail, responses=errors(404, 409, *WRITE_ERRORS))
def stop_run(run_id: RunId, store: StoreDep, _auth: WriteAuth) -> RunDetail:
    """A queued run stops at once; an active one when its learner next beats (409 if already over)."""
    return run_detail(store, store.request_stop(run_id=run_id))


@router.post("/{run_id}/resume", response_model=RunDetail, responses=errors(404, 409, *WRITE_ERRORS))
def resume_run(run_id: RunId, store: StoreDep, _auth: WriteAuth) -> RunDetail:
    """Queue a stopped or failed run again; the learner resumes from its last checkpoint (409 otherwise)."""
    return run_detail(store, store.resume_run(run_id=run_id))


@router.get(
    "/{run_id}/rollout/latest",
    response_class=Response,
    responses={
        200: {"content": {"image/gif": {}}, "description": "The latest evaluation rollout animation."},
        **errors(404),
    },
)
def latest_rollout(run_id: RunId, store: StoreDep, _auth: ReadAuth) -> Response:
    store.get_run(run_id=run_id)
    rollout = store.latest_rollout(run_id=run_id)
    if rollout is None:
        raise HTTPException(status_code=404, detail=f"run {run_id} has no rollout yet")
    return Response(
        content=store.rollout_data(rollout_id=rollout.id),
        media_type=rollout.media_type,
        headers={"Cache-Control": "no-cache", "X-Rollout-Id": str(rollout.id), "X-Env-Step": str(rollout.env_step)},
    )
