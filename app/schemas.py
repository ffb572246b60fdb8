"""Request and response bodies of the REST API."""

import math
from datetime import datetime
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

from contract.config import TrainConfig
from contract.effort import ANSWER_CAP_SECONDS, RESET_CAP_SECONDS
from contract.learner_pace import BEHIND_SECONDS, BEHIND_SHARE
from contract.store import INT32_MAX, Run, RunPhase, RunStatus, seconds_since
from contract.store.robots import EVALUATION_EPISODES_MAX, ROBOT_LIVE_SECONDS


def _storable_text(value: str) -> str:
    """JSON may escape lone UTF-16 surrogates ("\\ud800") and NUL ("\\u0000"), which databases cannot store as
    text (SQLite's encoder fails on the first, PostgreSQL on both)."""
    if "\x00" in value or any("\ud800" <= char <= "\udfff" for char in value):
        raise ValueError("must be valid Unicode text without NUL characters or lone surrogates")
    return value


Text = Annotated[str, AfterValidator(_storable_text)]


class InputModel(BaseModel):
    """A request body: unknown fields are refused (422 naming them), floats must be finite, and every value must
    have its field's JSON type (strict: a count is a JSON integer, so true, "5" or 5.0 is 422; a boolean is true or
    false, so 0 or "yes" is 422)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


class ErrorOut(BaseModel):
    """Every 4xx and 5xx body: a message, or for 422 a list of {loc, msg, type} naming each bad field."""

    detail: str | list[dict[str, Any]]


ERROR_DESCRIPTIONS: dict[int, str] = {
    400: "A malformed request: an invalid Content-Length, a body that cannot be parsed, an upload that is not a "
    "usable image, a blank name",
    401: "RAQ_API_TOKEN is set and the request carries neither the bearer token nor a login session",
    403: "Sent by a page of another web site: a change (CSRF, DNS rebinding), or an expensive read (a preview, an "
    "image, an export) such a page asked for",
    404: "Not found",
    409: "Conflicts with the current state",
    413: "The request body is larger than this route accepts (refused before it is read)",
    429: "Too many attempts; retry after the Retry-After header's seconds",
}


def errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI `responses` for these error status codes, each with the ErrorOut body."""
    return {code: {"model": ErrorOut, "description": ERROR_DESCRIPTIONS[code]} for code in codes}


WRITE_ERRORS = (400, 401, 403, 413)


class _RowWith:
    """An ORM row seen with a few more attributes (they win over the row's own)."""

    def __init__(self, row: Any, extra: dict[str, Any]) -> None:
        self._row = row
        self.__dict__.update(extra)

    def __getattr__(self, name: str) -> Any:
        if name == "_row":
            raise AttributeError(name)
        return getattr(self._row, name)


def row_with(row: Any, **extra: Any) -> Any:
    """The row plus values that are not its columns (counts, latest metrics), for model_validate."""
    return _RowWith(row, extra)


class RowOut(BaseModel):
    """A response read from an ORM row: Schema.model_validate(row, from_attributes=True), the row's attributes by
    field name. Values the store does not hold come in with row_with(row, name=value); what follows from the row
    alone (URLs, notes) is the schema's `derived`, in the fields' own places (so the JSON keeps its key order)."""

    model_config = ConfigDict(from_attributes=True)

    @classmethod
    def derived(cls, row: Any) -> dict[str, Any]:
        return {}

    @model_validator(mode="before")
    @classmethod
    def _with_derived(cls, data: Any) -> Any:
        if isinstance(data, dict):
            return data
        extra = cls.derived(data)
        return row_with(data, **extra) if extra else data


class HealthOut(BaseModel):
    status: str
    database: str


# ---------------------------------------------------------------- goal sets
class GoalSetCreate(InputModel):
    name: Text = Field(min_length=1, max_length=200, examples=["pusher puck on target"])
    image_size: int = Field(
        default=48, ge=8, le=512,
        description="Side of the model's square view in pixels; a run with this set takes its image_size from here.",
    )  # fmt: skip
    env_id: Text | None = Field(
        default=None, max_length=200, examples=["VisualPusher-v0"],
        description="The task the photos show. A run of another task with this set is refused unless confirmed.",
    )  # fmt: skip


class GoalExampleOut(RowOut):
    id: int
    goal_set_id: int
    filename: str
    source: str
    original_media_type: str
    width: int
    height: int
    created_at: datetime
    original_url: str
    model_url: str
    display_url: str
    crop_note: str | None = Field(
        description="How a photo that is not square was centre-cropped for the model (None when it is square)."
    )

    @classmethod
    def derived(cls, example: Any) -> dict[str, Any]:
        base = f"/api/goal-examples/{example.id}/image"
        crop_note = None
        if example.width != example.height:
            side = min(example.width, example.height)
            cut = "width" if example.width > example.height else "height"
            kept = round(100 * side / max(example.width, example.height))
            crop_note = (
                f"not square: the model sees the middle {side}×{side} of the {example.width}×{example.height} photo "
                f"({kept}% of its {cut}; the {'left and right' if cut == 'width' else 'top and bottom'} edges cut off)"
            )
        return {
            "original_url": f"{base}?kind=original",
            "model_url": f"{base}?kind=model",
            "display_url": f"{base}?kind=display",
            "crop_note": crop_note,
        }


class GoalSetOut(RowOut):  # model_validate(row_with(goal_set, example_count=n))
    id: int
    name: str
    image_size: int
    env_id: str | None = Field(description="The task the photos show (None: made before sets knew their task).")
    created_at: datetime
    example_count: int


class GoalSetDetail(GoalSetOut):
    examples: list[GoalExampleOut]


# ---------------------------------------------------------------- goals from the robot's camera
class CameraOut(BaseModel):
    env_id: str = Field(description="A robot env whose camera this server can show (module:EnvId).")
    frame_url: str = Field(description="Its current frame as PNG (GET; refreshed at most every 0.2 s).")
    robot: str | None = Field(
        description="The robot's own process that publishes its frames and drives it ('host/env id'); None: none is "
        "up (start `raq robot ENV_ID` on the robot's host)."
    )
    robot_state: str | None = Field(description="What that process does now (waiting for a learner, driving run N).")


class CamerasOut(BaseModel):
    cameras: list[CameraOut]


class CaptureCreate(InputModel):
    env_id: Text = Field(
        min_length=1, max_length=200, examples=["robot.standin:PusherStandIn-v0"],
        description="The robot env whose camera's current frame becomes a goal photo (one of GET /api/cameras).",
    )  # fmt: skip


class PhotoWarningOut(BaseModel):
    kind: str = Field(description="aspect, size, colour or contrast.")
    message: str = Field(description="The difference in plain words.")


class ImageSizeOut(BaseModel):
    width: int
    height: int


class CameraFrameInfo(ImageSizeOut):
    env_id: str
    source: str = Field(description="'camera' (read by this server) or 'run N' (the frame run N's actor published).")
    frame_url: str


class PhotoInfo(ImageSizeOut):
    filename: str


class PhotoCheckOut(BaseModel):
    warnings: list[PhotoWarningOut] = Field(
        description="How the photo differs from the camera's current frame; empty when they look alike or there is "
        "no camera to compare with."
    )
    camera: CameraFrameInfo | None = Field(description="The frame compared with (None: the set's task has no camera).")
    photo: PhotoInfo


class UploadedGoalExampleOut(GoalExampleOut):
    warnings: list[PhotoWarningOut] = Field(
        default=[], description="How the photo differs from its set's robot camera (advisory: the photo is stored)."
    )


# ---------------------------------------------------------------- runs
class RunCreate(InputModel):
    """A new run. `env_id`, `algorithm` and `seed` may be given here or inside `config`; here wins."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "env_id": "VisualPusher-v0",
                    "algorithm": "vice_raq",
                    "goal_set_id": 1,
                    "seed": 0,
                    "config": {"query_every": 2000, "query_budget": 20, "total_steps": 100000},
                }
            ]
        }
    )

    name: Text = Field(default="", max_length=200)
    env_id: Text | None = Field(default=None, max_length=200)
    algorithm: Text | None = Field(default=None, max_length=50)
    seed: int | None = None
    goal_set_id: int | None = Field(default=None, ge=1, le=INT32_MAX)
    priority: int = Field(
        default=0, ge=-100, le=100,
        description="Learners take the queued run of the highest priority first; the demo has -10. A lower-priority "
        "run yields to a higher-priority one that waits, at its next checkpoint.",
    )  # fmt: skip
    config: dict[str, Any] = Field(
        default_factory=dict,
        description="TrainConfig fields to override; an unknown one is refused (422). image_size comes from the goal "
        "set when there is one (another value is refused).",
    )
    confirm_env_mismatch: bool = Field(
        default=False,
        description="Start it although the goal set was made for another task (otherwise that is refused, 409).",
    )


class RunContinue(InputModel):
    """Train a finished run further: to this new total of env steps, from its last checkpoint."""

    total_steps: int = Field(gt=0, le=1_000_000_000, description="The new total; more than the run's total now.")


class RunUpdate(InputModel):
    """Change a run's priority, or archive it (a stopped, failed or finished run) / take it out of the archive."""

    priority: int | None = Field(default=None, ge=-100, le=100)
    archived: bool | None = None


class RolloutOut(RowOut):
    id: int
    env_step: int
    kind: str
    media_type: str
    frame_count: int
    episode_return: float | None
    success: float | None
    created_at: datetime
    url: str

    @classmethod
    def derived(cls, rollout: Any) -> dict[str, Any]:
        return {"url": f"/api/runs/{rollout.run_id}/rollout/latest?v={rollout.id}"}


class QueryCountsOut(BaseModel):
    asked: int = 0
    pending: int = 0
    answered: int = 0
    yes: int = 0
    skipped: int = 0


class RunOut(RowOut):
    # model_validate(row_with(run, queries=…, success_rate=…, steps_per_second=…, eta_seconds=…, waiting_reason=…,
    # asks_queries=…)): the run's query counts, its latest metrics, why it waits, whether its algorithm asks.
    id: int
    name: str
    env_id: str
    algorithm: str
    seed: int
    goal_set_id: int | None
    status: str
    status_reason: str
    waiting_reason: str | None = Field(
        default=None, description="For a queued run: why it waits ('learner busy with #1; after #4')."
    )
    priority: int
    archived: bool
    stop_requested: bool
    worker: str | None
    step: int
    total_steps: int
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    heartbeat_at: datetime | None
    heartbeat_age_seconds: float | None
    success_rate: float | None = Field(description="Latest eval/success_rate.")
    steps_per_second: float | None = Field(description="Latest perf/steps_per_second.")
    eta_seconds: float | None = Field(
        description="Latest perf/eta_seconds (from the training phase's speed; none during the warm-up), while active."
    )
    phase: str | None = Field(default=None, description="What the learner is doing: " + ", ".join(RunPhase.ALL))
    next_query_step: int | None = Field(
        default=None, description="The step of the next question (None: the algorithm asks none, or budget spent)."
    )
    next_query_seconds: float | None = Field(default=None, description="About when, at the current speed.")
    queries: QueryCountsOut

    @classmethod
    def derived(cls, run: Any) -> dict[str, Any]:
        active = run.status in RunStatus.ACTIVE
        speed = run.steps_per_second if active else None  # a stopped run has no speed
        asks_queries = getattr(run, "asks_queries", False)
        next_step = next_query_step(run, asked=run.queries.get("asked", 0)) if asks_queries else None
        next_seconds = None
        if next_step is not None and speed:
            next_seconds = max(0.0, (next_step - run.step) / speed)
        return {
            "heartbeat_age_seconds": seconds_since(run.heartbeat_at),
            "steps_per_second": speed,
            "eta_seconds": run.eta_seconds if active else None,
            "phase": run.phase if active else None,
            "next_query_step": next_step,
            "next_query_seconds": next_seconds,
        }


def next_query_step(run: Run, *, asked: int) -> int | None:
    """The step after which the learner asks next (QueryConfig.next_query_step, the learner's own rule), while the
    run has not ended and that step is within its steps."""
    if run.status not in (RunStatus.QUEUED, *RunStatus.ACTIVE):
        return None
    try:
        queries = TrainConfig.from_dict(run.config_values()).queries
    except (TypeError, ValueError):  # (a config no learner could train asks nothing)
        return None
    following = queries.next_query_step(run.step, asked=asked)
    return following if following is not None and (not run.total_steps or following <= run.total_steps) else None


class EffortOut(BaseModel):
    """What the run has cost the person so far (contract.effort)."""

    model_config = ConfigDict(from_attributes=True)

    answers: int = Field(description="Answers given.")
    answer_seconds: float = Field(
        description="Time spent answering: from a page first showing each question to its answer, each capped at "
        f"{ANSWER_CAP_SECONDS:g} s (an answer given through the API without a page counts none)."
    )
    resets: int = Field(description="Scene resets done (Ready pressed).")
    reset_wait_seconds: float = Field(description="How long the robot waited for those resets, in all.")
    takeovers: int = Field(description="Times the person drove the robot by hand.")
    takeover_seconds: float = Field(description="How long they drove it by hand, in all.")
    person_minutes: float = Field(
        description=f"The person's minutes in all: answering, each reset's wait capped at {RESET_CAP_SECONDS:g} s, "
        "and driving by hand."
    )


class LearnerPaceOut(BaseModel):
    """Whether a real-time run's learner keeps up with its robot (contract.learner_pace)."""

    model_config = ConfigDict(from_attributes=True)

    updates_per_robot_step: float = Field(description="SAC updates per robot step over the latest log interval.")
    updates_per_step: int = Field(description="What the run asks for.")
    behind_seconds: float = Field(
        description=f"How long the learner has stayed below {BEHIND_SHARE:g} of updates_per_step (0: it is not)."
    )
    behind: bool = Field(description=f"Behind for at least {BEHIND_SECONDS:g} s: it cannot keep up.")
    message: str = Field(description="When behind: that it cannot keep up, for how long, and the cause.")
    cause: str = Field(description='When behind, the run\'s own figures: "84 px and 32 filters on this CPU give …".')
    suggestion: str = Field(description="When behind: the preset that fits, or another learner.")
    suggested_fields: dict[str, Any] = Field(description="The config fields the suggestion sets.")


class RunDetail(RunOut):  # as RunOut, with config=run.config_values() and latest_rollout=the rollout row (or None)
    config: dict[str, Any]
    latest_rollout: RolloutOut | None
    effort: EffortOut = Field(description="What the run has cost the person so far.")
    learner_pace: LearnerPaceOut | None = Field(
        description="A real-time run's learner against its robot: SAC updates per robot step, and when it cannot "
        "keep up, why and what fits; None for a run in lockstep or still in its warm-up."
    )
    robot: "RobotStatusOut | None" = Field(
        default=None,
        description="A real-time run's robot controls and what its actor last said (`live` false once it has been "
        "silent the actor's watchdog time); None while no actor has reported for the run.",
    )


# ---------------------------------------------------------------- queries
class QueryOut(RowOut):
    id: int
    run_id: int
    env_step: int
    score: float = Field(description="The classifier's logit f_psi that made the learner ask.")
    probability: float = Field(description="sigmoid(score): the classifier's belief that this is a success.")
    strategy: str
    info: dict[str, Any]
    ground_truth_success: float | None
    status: str
    answer: bool | None
    labeler: str | None
    answered_at: datetime | None
    used_by_learner: bool
    created_at: datetime
    model_image_url: str
    display_image_url: str

    @classmethod
    def derived(cls, query: Any) -> dict[str, Any]:
        base = f"/api/queries/{query.id}/image"
        return {
            "probability": _sigmoid(query.score),
            "info": query.info or {},
            "used_by_learner": query.used_at is not None,
            "model_image_url": f"{base}?resolution=model",
            "display_image_url": f"{base}?resolution=display",
        }


def _sigmoid(value: float) -> float:
    if value >= 0:
        return 1.0 / (1.0 + math.exp(-value))
    exp = math.exp(value)
    return exp / (1.0 + exp)


class AnswerIn(InputModel):
    success: bool = Field(description="True: this image shows success.")
    labeler: Text = Field(default="", max_length=200, description="Who answered (a name, or 'oracle').")


class SkipIn(InputModel):
    labeler: Text = Field(default="", max_length=200)


class QueueItem(BaseModel):
    """The next pending query with what a person needs to judge it."""

    query: QueryOut | None
    pending: int = Field(description="Pending queries (of the run, or of all runs).")
    pending_all_runs: int = Field(
        description="Pending queries of the live runs (queued, starting, training): the badge's count."
    )
    run: RunOut | None
    goal_examples: list[GoalExampleOut]


# ---------------------------------------------------------------- metrics and events
class MetricsOut(BaseModel):
    run_id: int
    last_step: int = Field(description="Largest step returned (or since_step); pass it back as since_step.")
    # [step, value] pairs as two-item lists: OpenAPI 3.1 has no tuple schema FastAPI emits validly.
    series: dict[str, list[Annotated[list[int | float], Field(min_length=2, max_length=2)]]] = Field(
        description="name -> [[step, value], …], by step."
    )


class EventOut(RowOut):
    id: int
    run_id: int | None
    level: str
    message: str
    created_at: datetime


# ---------------------------------------------------------------- sweeps and comparison
class SweepCreate(InputModel):
    """Methods × seeds in one action: one run per (algorithm, seed), all with the same env, goal set and config."""

    name: Text = Field(default="", max_length=150)
    env_id: Text = Field(max_length=200)
    algorithms: list[Text] = Field(min_length=1, max_length=5, description="Keys of the algorithm table.")
    seeds: list[Annotated[int, Field(ge=0, le=INT32_MAX)]] = Field(min_length=1, max_length=10)
    goal_set_id: int | None = Field(default=None, ge=1, le=INT32_MAX)
    priority: int = Field(default=0, ge=-100, le=100)
    config: dict[str, Any] = Field(default_factory=dict)
    confirm_env_mismatch: bool = Field(
        default=False,
        description="Start it although the goal set was made for another task (otherwise that is refused, 409).",
    )


class CompareGroupOut(BaseModel):
    label: str = Field(description="The group: env id and algorithm.")
    run_ids: list[int]
    # [step, mean, min, max, n] at each step every run of the group recorded
    points: list[Annotated[list[float], Field(min_length=5, max_length=5)]]


class CompareOut(BaseModel):
    metric: str
    groups: list[CompareGroupOut]


# ---------------------------------------------------------------- robots
class RobotStatusOut(RowOut):  # model_validate(row_with(robot_status, run_name=run.name), from_attributes=True)
    """A run's robot controls (a person's Stop robot / Resume and Ready) and what its actor last said."""

    run_id: int
    run_name: str
    stop_requested: bool = Field(description="Stop robot was pressed: the actor holds the arm still until Resume.")
    reset_needed: bool = Field(description="The actor waits for a person to reset the scene and press Ready.")
    reset_count: int = Field(description="How many times a person pressed Ready (reset the scene).")
    actor_state: str | None = Field(description="What the actor last said it is doing.")
    actor_seen_at: datetime | None = Field(description="When the actor last reported (the database's clock).")
    actor_age_seconds: float | None
    live: bool = Field(description=f"The actor reported within the last {ROBOT_LIVE_SECONDS:g} s.")
    frame_at: datetime | None = Field(description="When the newest camera frame came.")
    camera_url: str | None = Field(description="The newest camera frame (PNG; the query changes with each frame).")
    evaluation_pending: int = Field(description="Episodes of Evaluate now that the actor has not begun.")
    evaluation_round: int = Field(description="How many times Evaluate now was pressed (the newest request's round).")
    takeover_action: list[float] | None = Field(
        description="The person's newest action while they drive the arm by hand (null: the policy drives)."
    )
    action_dims: int | None = Field(description="The robot's action dimensions (null before its actor announced).")
    control_hz: float | None = Field(description="The robot's control rate (null before its actor announced).")
    asks_for_help: bool = Field(
        description="No asked state has been a success lately (the reward's verdict): a take-over would show the way. "
        "Always false in the answers to drive and hand-back, which skip the verdict."
    )
    success_marks: int = Field(description="How many times a person pressed the success key.")
    demo_pending: int = Field(description="Episodes of Record demos not begun yet (each driven by hand).")

    @classmethod
    def derived(cls, status: Any) -> dict[str, Any]:
        age = seconds_since(status.actor_seen_at)
        camera_url = None
        if status.frame_at is not None:
            camera_url = f"/api/runs/{status.run_id}/robot/camera?v={round(status.frame_at.timestamp() * 1000)}"
        spaces = status.actor_spaces
        return {
            "actor_age_seconds": age,
            "live": age is not None and age <= ROBOT_LIVE_SECONDS,
            "camera_url": camera_url,
            "action_dims": None if spaces is None else len(spaces["action"]["low"]),
            "control_hz": None if spaces is None else float(spaces["control_hz"]),
        }


class DriveIn(InputModel):
    """A person's action for a run's robot while they drive it by hand."""

    action: list[Annotated[float, Field(ge=-1.0, le=1.0)]] = Field(
        min_length=1, max_length=32, description="One number in [-1, 1] per action dimension (the policy's scale)."
    )


RunDetail.model_rebuild()  # (its `robot` is a RobotStatusOut)


class DemosIn(InputModel):
    """Record demos: episodes for the person to drive by hand before the policy acts again."""

    episodes: int = Field(
        ge=1, le=EVALUATION_EPISODES_MAX,
        description="How many episodes; in each the robot moves only while the person holds a drive key.",
    )  # fmt: skip


class EvaluateIn(InputModel):
    """Evaluate now: episodes for the actor to run with the policy's mean action."""

    episodes: int = Field(
        ge=1, le=EVALUATION_EPISODES_MAX,
        description="How many episodes; the last frame of each becomes a question on the answer queue.",
    )  # fmt: skip


# ---------------------------------------------------------------- envs and exports
class TaskSettingsOut(BaseModel):
    fields: dict[str, int | float]
    results_page: str


class EvaluatedPolicyOut(BaseModel):
    step: int
    success_rate: float | None
    """The evaluation's success rate (None for an env that reports no success)."""
    evaluated_return: float | None
    url: str


class EvaluatedPoliciesOut(BaseModel):
    last_eval: EvaluatedPolicyOut | None
    """The policy the latest evaluation ran."""
    best: EvaluatedPolicyOut | None
    """The policy of the highest evaluation success rate so far (then return; an equal score keeps the earlier)."""
