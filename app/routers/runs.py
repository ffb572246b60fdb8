"""Runs: create (validated with TrainConfig), list, read, change priority / archive, delete, stop, resume, and the
latest rollout animation."""

import contextlib
import dataclasses
import functools
import shutil
import typing
from typing import Annotated, Any

import pydantic
from fastapi import APIRouter, HTTPException, Query, Response, status

from app.deps import QueryBool, ReadAuth, RunId, SameSiteRead, SettingsDep, StoreDep, WriteAuth
from app.previews import preview_problem
from app.schemas import (
    WRITE_ERRORS,
    RunContinue,
    RunCreate,
    RunDetail,
    RunOut,
    RunUpdate,
    SweepCreate,
    errors,
)
from app.views import list_run_outs, run_detail, run_out
from contract.algorithms import ALGORITHM_SPECS
from contract.checkpoint_location import is_remote, run_folder
from contract.config import TrainConfig, host_memory_bytes
from contract.settings import Settings
from contract.store import NotFound, Run, Store

router = APIRouter(prefix="/api/runs", tags=["runs"], responses=errors(401))

TOP_LEVEL_FIELDS = ("env_id", "algorithm", "seed")
_config_adapter = pydantic.TypeAdapter(TrainConfig)
# The paths of one run: its id is digits, so /api/runs/sweep is the sweep's own path (a PATCH there is 405), never
# a run whose id fails to parse.
ONE_RUN = "/{run_id:int}"


@functools.cache
def _strict_field_adapters() -> dict[str, pydantic.TypeAdapter[Any]]:
    """Each TrainConfig field's type, to check a given value strictly: its JSON type, before the bounds."""
    hints = typing.get_type_hints(TrainConfig)
    return {field.name: pydantic.TypeAdapter(hints[field.name]) for field in dataclasses.fields(TrainConfig)}


def _type_problems(values: dict[str, Any]) -> list[tuple[str, str]]:
    """(field, message) for every value that is not its field's JSON type: a count given as true or "5", a
    switch given as 0 (pydantic's lax mode would take them as 1, 5 and false)."""
    problems = []
    adapters = _strict_field_adapters()
    for name, value in values.items():
        try:
            adapters[name].validate_python(value, strict=True)
        except pydantic.ValidationError as error:
            problems.append((name, error.errors(include_url=False)[0]["msg"]))
    return problems


def _field_error(location: list[str | int], field: str, message: str) -> dict[str, Any]:
    return {"loc": location, "msg": f"{field}: {message}", "type": "value_error"}


def validate_run_config(body: RunCreate, settings: Settings) -> TrainConfig:
    """The body's settings as a TrainConfig, or HTTP 422 whose detail names every bad field: a value out of its
    bounds, more memory than this host has, or an env id that is not registered or allowed."""
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
    mistyped = _type_problems(values)
    if mistyped:
        raise HTTPException(
            status_code=422, detail=[_field_error(location(name), name, message) for name, message in mistyped]
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
    # the run's own size against this host's memory; the GPU it names is for a learner to have, not this server
    problems = config.resource_errors(memory_bytes=host_memory_bytes())
    env_problem = preview_problem(config.env_id, config.image_size, settings)  # the New run form's preview
    if env_problem:
        problems.append(("env_id", env_problem))
    if problems:
        raise HTTPException(
            status_code=422, detail=[_field_error(location(field), field, message) for field, message in problems]
        )
    return config


def _goal_set_error(message: str) -> HTTPException:
    return HTTPException(status_code=422, detail=[_field_error(["body", "goal_set_id"], "goal_set_id", message)])


def image_size_from_goal_set(store: Store, body: RunCreate) -> RunCreate:
    """The goal set is where the model's image size is set (its photos are prepared at that size): a run with a
    set takes its image_size from it; another image_size in the config is refused (422)."""
    if body.goal_set_id is None:
        return body
    try:
        goal_set = store.get_goal_set(goal_set_id=body.goal_set_id)
    except NotFound:
        return body  # check_goal_set says so
    given = body.config.get("image_size")
    if given is not None and given != goal_set.image_size:
        raise HTTPException(status_code=422, detail=[_field_error(
            ["body", "config", "image_size"], "image_size",
            f"the goal set {goal_set.name!r} prepares its photos at {goal_set.image_size}×{goal_set.image_size} px, "
            f"so its runs see {goal_set.image_size} px images; leave image_size out, or use a goal set of {given} px",
        )])  # fmt: skip
    return body.model_copy(update={"config": {**body.config, "image_size": goal_set.image_size}})


def check_goal_set_env(store: Store, *, env_id: str, goal_set_id: int | None, confirmed: bool) -> None:
    """A goal set shows one task: a run of another with it is refused (409) unless confirm_env_mismatch."""
    if goal_set_id is None or confirmed:
        return
    goal_set = store.get_goal_set(goal_set_id=goal_set_id)
    if goal_set.env_id and goal_set.env_id != env_id:
        raise HTTPException(
            status_code=409,
            detail=f"the goal set {goal_set.name!r} was made for {goal_set.env_id}, not {env_id}: its photos show "
            f"another task. Pick a goal set of {env_id}, or start it anyway (confirm_env_mismatch: true).",
        )


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


@router.post("", status_code=status.HTTP_201_CREATED, response_model=RunDetail, responses=errors(409, *WRITE_ERRORS))
def create_run(body: RunCreate, store: StoreDep, settings: SettingsDep, _auth: WriteAuth) -> RunDetail:
    """A run with a goal set takes its image_size from the set; a goal set made for another task is refused (409)
    unless `confirm_env_mismatch` is true."""
    config = validate_run_config(image_size_from_goal_set(store, body), settings)
    check_goal_set(store, algorithm=config.algorithm, goal_set_id=body.goal_set_id)
    check_goal_set_env(store, env_id=config.env_id, goal_set_id=body.goal_set_id, confirmed=body.confirm_env_mismatch)
    run = _create(store, config, goal_set_id=body.goal_set_id, priority=body.priority, name=body.name.strip())
    return run_detail(store, run)


def _create(store: Store, config: TrainConfig, *, goal_set_id: int | None, priority: int, name: str) -> Run:
    """A queued run of a checked config; its own columns (env, algorithm, seed, steps) from the config."""
    return store.create_run(
        env_id=config.env_id, algorithm=config.algorithm, config=config.to_dict(), seed=config.seed,
        goal_set_id=goal_set_id, total_steps=config.total_steps, name=name, priority=priority,
    )  # fmt: skip


@router.post(
    "/sweep", status_code=status.HTTP_201_CREATED, response_model=list[RunOut], responses=errors(409, *WRITE_ERRORS)
)
def create_sweep(body: SweepCreate, store: StoreDep, settings: SettingsDep, _auth: WriteAuth) -> list[RunOut]:
    """Start methods × seeds in one action: every combination is checked first (422 names the first bad one and
    nothing is created), then one run each, named "<name> · <algorithm> · seed <n>"."""
    algorithms, seeds = list(dict.fromkeys(body.algorithms)), list(dict.fromkeys(body.seeds))
    checked = []
    for algorithm in algorithms:
        for seed in seeds:
            single = RunCreate(
                env_id=body.env_id, algorithm=algorithm, seed=seed, goal_set_id=body.goal_set_id,
                priority=body.priority, config=body.config,
            )  # fmt: skip
            config = validate_run_config(image_size_from_goal_set(store, single), settings)
            check_goal_set(store, algorithm=config.algorithm, goal_set_id=body.goal_set_id)
            check_goal_set_env(
                store, env_id=config.env_id, goal_set_id=body.goal_set_id, confirmed=body.confirm_env_mismatch
            )
            checked.append(config)
    prefix = body.name.strip() or f"sweep {body.env_id}"
    runs = []
    for config in checked:
        name = f"{prefix} · {config.algorithm} · seed {config.seed}"[:200]
        runs.append(_create(store, config, goal_set_id=body.goal_set_id, priority=body.priority, name=name))
    waiting = store.queue_report()
    return [run_out(store, run, waiting) for run in runs]


@router.get("", response_model=list[RunOut])
def list_runs(
    store: StoreDep,
    _auth: ReadAuth,
    archived: Annotated[
        QueryBool | None,
        Query(description="false (default): leave archived runs out; true: only them; omit with all=true"),
    ] = False,
    all_runs: Annotated[QueryBool, Query(alias="all", description="every run, archived or not")] = False,
) -> list[RunOut]:
    return list_run_outs(store, archived=None if all_runs else archived)


@router.patch(ONE_RUN, response_model=RunDetail, responses=errors(404, 409, *WRITE_ERRORS))
def update_run(run_id: RunId, body: RunUpdate, store: StoreDep, _auth: WriteAuth) -> RunDetail:
    """Change the priority (any time: a queued run moves in the queue, a running one yields at its next checkpoint
    when a higher-priority run waits) or archive a run that is not queued or running (409)."""
    return run_detail(store, store.update_run(run_id=run_id, priority=body.priority, archived=body.archived))


@router.delete(ONE_RUN, status_code=status.HTTP_204_NO_CONTENT, responses=errors(404, 409, *WRITE_ERRORS))
def delete_run(run_id: RunId, store: StoreDep, settings: SettingsDep, _auth: WriteAuth) -> Response:
    """Delete a run with everything it owns: queries (with their images), metrics, events, rollouts and its
    checkpoint files. A run a learner holds (starting, training) must be stopped first (409)."""
    store.delete_run(run_id=run_id)
    # the run's checkpoint folder (contract/checkpoint_location.py: <RAQ_CHECKPOINT_URL>/run-<id>/)
    folder = run_folder(settings.resolved_checkpoint_url, run_id)
    if not is_remote(folder):
        shutil.rmtree(folder, ignore_errors=True)
    else:
        import fsspec  # checkpoints in object storage (pip install '.[objectstore]')

        fs, key = fsspec.core.url_to_fs(folder)
        with contextlib.suppress(FileNotFoundError):
            fs.rm(key, recursive=True)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get(ONE_RUN, response_model=RunDetail, responses=errors(404))
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


@router.post("/{run_id}/continue", response_model=RunDetail, responses=errors(400, 404, 409, *WRITE_ERRORS))
def continue_run(run_id: RunId, body: RunContinue, store: StoreDep, _auth: WriteAuth) -> RunDetail:
    """Train a finished (or stopped, or failed) run further, to a new total of env steps larger than its total
    now: queued again, a learner goes on from its last checkpoint (409 while it is queued or active, 400 for a
    total that is not larger)."""
    return run_detail(store, store.continue_run(run_id=run_id, total_steps=body.total_steps))


@router.get(
    "/{run_id}/rollout/latest",
    response_class=Response,
    responses={
        200: {"content": {"image/gif": {}}, "description": "The latest evaluation rollout animation."},
        **errors(403, 404),
    },
)
def latest_rollout(run_id: RunId, store: StoreDep, _auth: ReadAuth, _same_site: SameSiteRead) -> Response:
    store.get_run(run_id=run_id)
    rollout = store.latest_rollout(run_id=run_id)
    if rollout is None:
        raise HTTPException(status_code=404, detail=f"run {run_id} has no rollout yet")
    return Response(
        content=store.rollout_data(rollout_id=rollout.id),
        media_type=rollout.media_type,
        headers={"Cache-Control": "no-cache", "X-Rollout-Id": str(rollout.id), "X-Env-Step": str(rollout.env_step)},
    )
