"""SQLAlchemy 2 typed models: goal sets, runs, queries, metrics, events and rollouts.

Images live in the database (LargeBinary, deferred so that listing rows never loads them), so that
several hosts can share one PostgreSQL. Checkpoints, which hold the replay buffer, live on disk.
"""

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
    TypeDecorator,
)
from sqlalchemy import false as sa_false
from sqlalchemy.orm import DeclarativeBase, Mapped, deferred, mapped_column


def utcnow() -> datetime:
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """Timezone-aware UTC datetimes on every backend (SQLite stores naive values)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is not None and dialect.name == "sqlite":
            value = value.astimezone(UTC).replace(tzinfo=None)
        return value

    def process_result_value(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is None:
            value = value.replace(tzinfo=UTC)
        return value


class Base(DeclarativeBase):
    pass


# The largest value an Integer / BigInteger column holds on every backend (PostgreSQL's INTEGER is 32-bit,
# SQLite's INTEGER and BigInteger are 64-bit). The API refuses ids and numbers beyond their column's range.
INT32_MAX = 2**31 - 1
INT64_MAX = 2**63 - 1


class RunStatus:
    QUEUED = "queued"
    STARTING = "starting"
    TRAINING = "training"
    STOPPED = "stopped"
    FINISHED = "finished"
    FAILED = "failed"
    ACTIVE = (STARTING, TRAINING)
    # Runs that will still use their answers: held by a learner or waiting for one (the answer queue puts their
    # questions first, and the badge counts only theirs).
    LIVE = (QUEUED, STARTING, TRAINING)
    ALL = (QUEUED, STARTING, TRAINING, STOPPED, FINISHED, FAILED)


class RunPhase:
    """What the learner of an active run is doing now (sent with its heartbeats; shown on the pages)."""

    SETTING_UP = "setting up"
    WARM_UP = "warm-up"
    TRAINING = "training"
    EVALUATING = "evaluating"
    ALL = (SETTING_UP, WARM_UP, TRAINING, EVALUATING)


class QueryStatus:
    PENDING = "pending"
    ANSWERED = "answered"
    SKIPPED = "skipped"
    ALL = (PENDING, ANSWERED, SKIPPED)


class GoalSet(Base):
    __tablename__ = "goal_sets"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    image_size: Mapped[int] = mapped_column(Integer, default=48)
    # The task the set was made for ("Start a run with this set" opens it); None: made before sets knew theirs.
    env_id: Mapped[str | None] = mapped_column(String(200))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class GoalExample(Base):
    __tablename__ = "goal_examples"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    goal_set_id: Mapped[int] = mapped_column(ForeignKey("goal_sets.id", ondelete="CASCADE"), index=True)
    filename: Mapped[str] = mapped_column(String(255))
    source: Mapped[str] = mapped_column(String(50), default="upload")
    original_media_type: Mapped[str] = mapped_column(String(50))
    width: Mapped[int] = mapped_column(Integer)
    height: Mapped[int] = mapped_column(Integer)
    original: Mapped[bytes] = deferred(mapped_column(LargeBinary, nullable=False))
    model_png: Mapped[bytes] = deferred(mapped_column(LargeBinary, nullable=False))
    display_png: Mapped[bytes] = deferred(mapped_column(LargeBinary, nullable=False))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


COLUMN_CONFIG_FIELDS = ("env_id", "algorithm", "seed", "total_steps")
"""Config fields a run keeps in its own columns and not in its config JSON: each is stored once."""


class Run(Base):
    __tablename__ = "runs"
    # a deleted run's id is never given again (migration 0007; PostgreSQL's sequences never go back anyway)
    __table_args__ = {"sqlite_autoincrement": True}

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(200), default="")
    env_id: Mapped[str] = mapped_column(String(200))
    algorithm: Mapped[str] = mapped_column(String(50))
    config: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    """The run's config fields other than COLUMN_CONFIG_FIELDS (config_values() has them all)."""
    seed: Mapped[int] = mapped_column(Integer, default=0)
    goal_set_id: Mapped[int | None] = mapped_column(ForeignKey("goal_sets.id", ondelete="SET NULL"))
    status: Mapped[str] = mapped_column(String(20), default=RunStatus.QUEUED, index=True)
    status_reason: Mapped[str] = mapped_column(Text, default="")
    stop_requested: Mapped[bool] = mapped_column(Boolean, default=False)
    # Learners take the queued run of the highest priority first (then the oldest); a run a person starts has 0,
    # the demo -10. A lower-priority run yields to a higher-priority one that waits, at its next checkpoint.
    priority: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    # When the run was last queued (created, resumed, requeued): how long a queued run has waited.
    queued_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    # Archived runs are hidden from the runs page (unless asked for) and never claimed.
    archived: Mapped[bool] = mapped_column(Boolean, default=False, server_default=sa_false())
    # RunPhase of an active run, as its learner last said (None before a learner took it)
    phase: Mapped[str | None] = mapped_column(String(30))
    worker: Mapped[str | None] = mapped_column(String(200))
    heartbeat_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    # how many times a learner has claimed the run: a takeover increases it, and an actor acts only for the current
    claim: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    step: Mapped[int] = mapped_column(BigInteger, default=0)
    total_steps: Mapped[int] = mapped_column(BigInteger, default=0)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime)

    def config_values(self) -> dict[str, Any]:
        """The run's whole configuration, as TrainConfig.from_dict takes it: the config JSON with the env id,
        algorithm, seed and total steps of the run's columns (which win over any older copy in the JSON)."""
        values = {key: value for key, value in (self.config or {}).items() if key not in COLUMN_CONFIG_FIELDS}
        values.update(env_id=self.env_id, algorithm=self.algorithm, seed=self.seed)
        if self.total_steps:
            values["total_steps"] = self.total_steps
        return values


class Query(Base):
    __tablename__ = "queries"
    # (run_id, status) and (status, id): the oldest pending query, of one run or of all, is one index lookup
    # (SQLite appends the rowid, i.e. id, to every index), and pending counts are index-only.
    __table_args__ = (Index("ix_queries_run_status", "run_id", "status"), Index("ix_queries_status_id", "status", "id"))

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    env_step: Mapped[int] = mapped_column(BigInteger)
    score: Mapped[float] = mapped_column(Float)
    strategy: Mapped[str] = mapped_column(String(50), default="argmax")
    info: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    ground_truth_success: Mapped[float | None] = mapped_column(Float)
    model_png: Mapped[bytes] = deferred(mapped_column(LargeBinary, nullable=False))
    display_png: Mapped[bytes] = deferred(mapped_column(LargeBinary, nullable=False))
    status: Mapped[str] = mapped_column(String(20), default=QueryStatus.PENDING)
    answer: Mapped[bool | None] = mapped_column(Boolean)
    labeler: Mapped[str | None] = mapped_column(String(200))
    answered_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    # When a page was first served the question (GET /api/queries/next): the person's answering time counts from it.
    shown_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    # Increases with every answer in the whole store: the learner asks for answers "since" a value of it.
    answer_seq: Mapped[int | None] = mapped_column(BigInteger, unique=True)
    # Set when the learner has taken the answer into its classifier; after that it cannot be undone.
    used_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class Metric(Base):
    __tablename__ = "metrics"
    __table_args__ = (Index("ix_metrics_run_name_step", "run_id", "name", "step"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    step: Mapped[int] = mapped_column(BigInteger)
    name: Mapped[str] = mapped_column(String(100))
    value: Mapped[float] = mapped_column(Float)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class Event(Base):
    __tablename__ = "events"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int | None] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    level: Mapped[str] = mapped_column(String(20), default="info")
    message: Mapped[str] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class Rollout(Base):
    __tablename__ = "rollouts"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    env_step: Mapped[int] = mapped_column(BigInteger)
    kind: Mapped[str] = mapped_column(String(20), default="eval")
    media_type: Mapped[str] = mapped_column(String(50), default="image/gif")
    frame_count: Mapped[int] = mapped_column(Integer)
    episode_return: Mapped[float | None] = mapped_column(Float)
    success: Mapped[float | None] = mapped_column(Float)
    data: Mapped[bytes] = deferred(mapped_column(LargeBinary, nullable=False))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class AnswerCounter(Base):
    """The last answer number given (one row, id 1). An answer takes the next number by updating this row, whose
    lock it holds until it commits: numbers follow commit order, so a learner reading answers "since" a number
    never passes one still being written."""

    __tablename__ = "answer_counter"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    value: Mapped[int] = mapped_column(BigInteger)


class LoginFailure(Base):
    """A wrong token at /login, by client address. The login rate limit counts these rows (by the database's
    clock), so every server process and host shares one limit; rows older than the limit's window are deleted as
    new ones come."""

    __tablename__ = "login_failures"
    __table_args__ = (Index("ix_login_failures_client_failed_at", "client", "failed_at"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    client: Mapped[str] = mapped_column(String(200))
    failed_at: Mapped[datetime] = mapped_column(UTCDateTime, index=True)


class LoginSession(Base):
    """A browser's login: the cookie holds a random secret, this row only its SHA-256. Deleting the row (logout,
    `raq sessions --end-all`) ends the session; so does changing RAQ_API_TOKEN (the row keeps a keyed hash of the
    token it was made under)."""

    __tablename__ = "login_sessions"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    secret_hash: Mapped[str] = mapped_column(String(64), unique=True)
    token_fingerprint: Mapped[str] = mapped_column(String(64))
    client: Mapped[str] = mapped_column(String(200), default="")
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    expires_at: Mapped[datetime] = mapped_column(UTCDateTime, index=True)


class SceneReset(Base):
    """One scene reset the actor asked a person for: when it asked, and when the person pressed Ready."""

    __tablename__ = "scene_resets"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    requested_at: Mapped[datetime] = mapped_column(UTCDateTime)
    ready_at: Mapped[datetime | None] = mapped_column(UTCDateTime)


class RobotControl(Base):
    """Between a person and the actor that drives a run's robot in real time (one row per run, made on first use):
    the person's Stop robot / Resume and Ready (the scene is reset), the actor's call for a reset, its state and its
    newest camera frame. Times are the database's clock."""

    __tablename__ = "robot_controls"

    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), primary_key=True)
    stop_requested: Mapped[bool] = mapped_column(Boolean, default=False, server_default=sa_false())
    reset_needed: Mapped[bool] = mapped_column(Boolean, default=False, server_default=sa_false())
    # how many times a person pressed Ready (the scene was reset)
    reset_count: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    actor_state: Mapped[str | None] = mapped_column(String(100))
    actor_seen_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    frame_png: Mapped[bytes | None] = deferred(mapped_column(LargeBinary))
    frame_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    # Evaluate now: episodes a person asked for that the actor has not begun, and how many times they asked
    evaluation_pending: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    evaluation_round: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    # a take-over: the person's newest action (None: the policy drives) and how many they sent in all (each new one
    # is fresh for the actor for one control period from when it saw it)
    takeover_action: Mapped[list[float] | None] = mapped_column(JSON)
    takeover_seq: Mapped[int] = mapped_column(BigInteger, default=0, server_default="0")
    # the person's success key (how many times pressed) and Record demos (episodes driven by hand not begun yet)
    success_marks: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    demo_pending: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    # the link to an actor on another host: the learner's keep-alive, its newest policy in the checkpoint store,
    # the step its run starts at (None: not open), its close; the actor's action and observation spaces
    learner_seen_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    policy_version: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    start_step: Mapped[int | None] = mapped_column(BigInteger)
    learner_closed: Mapped[bool] = mapped_column(Boolean, default=False, server_default=sa_false())
    actor_spaces: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class TakeoverSpan(Base):
    """A stretch of time a person drove a run's robot by hand: from their first action to their last, the gaps
    between actions shorter than TAKEOVER_GAP_SECONDS (contract/store/robots.py). Times are the database's clock."""

    __tablename__ = "takeover_spans"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"), index=True)
    started_at: Mapped[datetime] = mapped_column(UTCDateTime)
    last_at: Mapped[datetime] = mapped_column(UTCDateTime)


class RobotHold(Base):
    """Which run's actor drives a robot (an env id on its host): one row per robot, renewed by that actor while it
    holds the robot, for the run's claim it was taken with. Times are the database's clock."""

    __tablename__ = "robot_holds"

    robot: Mapped[str] = mapped_column(String(300), primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    claim: Mapped[int] = mapped_column(Integer)
    holder: Mapped[str] = mapped_column(String(300))
    """The actor process that holds it ("pid@host")."""
    renewed_at: Mapped[datetime] = mapped_column(UTCDateTime)


class RobotProcess(Base):
    """A robot's own process (`raq robot ENV`): the one process that opens the robot's camera and moves its arm. It
    stamps its row every second, publishes camera frames for the pages (often while one watches), and drives the
    run that holds the robot. Times are the database's clock."""

    __tablename__ = "robot_processes"

    robot: Mapped[str] = mapped_column(String(300), primary_key=True)
    env_id: Mapped[str] = mapped_column(String(300), index=True)
    holder: Mapped[str] = mapped_column(String(300))
    """The process ("pid@host")."""
    state: Mapped[str] = mapped_column(String(100))
    seen_at: Mapped[datetime] = mapped_column(UTCDateTime)
    frame_png: Mapped[bytes | None] = deferred(mapped_column(LargeBinary))
    frame_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    watched_at: Mapped[datetime | None] = mapped_column(UTCDateTime)
    """When a page last asked for a frame (the process then publishes one every FRAME_WATCHED_SECONDS)."""


class ActorMessage(Base):
    """A remote actor's message to its learner (a step, an episode's first observation, a state), in id order;
    kept until a checkpoint of the run holds it (a learner that takes the run over trains on the later ones)."""

    __tablename__ = "actor_messages"
    __table_args__ = (Index("ix_actor_messages_run_id_id", "run_id", "id"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    run_id: Mapped[int] = mapped_column(ForeignKey("runs.id", ondelete="CASCADE"))
    kind: Mapped[str] = mapped_column(String(20))
    payload: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    observation_png: Mapped[bytes | None] = mapped_column(LargeBinary)
    display_png: Mapped[bytes | None] = mapped_column(LargeBinary)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
