"""The store: every read and write the learner and the server make, as keyword-only methods.

Both processes open their own `Store` on the same database URL; they share nothing else. Rows come
back detached (expire_on_commit=False); binary columns are deferred and read with the *_image methods.
"""

import math
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import bindparam, delete, func, insert, or_, select, text, type_coerce, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm.attributes import set_committed_value

from contract.store.db import Database
from contract.store.errors import Conflict, InvalidInput, NotFound
from contract.store.models import (
    INT64_MAX,
    AnswerCounter,
    Event,
    GoalExample,
    GoalSet,
    LoginFailure,
    LoginSession,
    Metric,
    Query,
    QueryStatus,
    Rollout,
    Run,
    RunPhase,
    RunStatus,
    UTCDateTime,
    utcnow,
)


@dataclass(frozen=True)
class GoalImage:
    """A goal example's pixels at model resolution, as the learner reads them."""

    id: int
    model_png: bytes
    original: bytes


@dataclass(frozen=True)
class AnsweredQuery:
    """An answer as the learner consumes it."""

    query_id: int
    answer_seq: int
    success: bool
    model_png: bytes
    env_step: int


# PostgreSQL advisory lock class (the first of two keys; the second is the client address's hash) under which one
# login try per address is checked and counted.
LOGIN_LOCK = 0x52_41_51_02
# The order learners take queued runs in: highest priority first, then the oldest.
_CLAIM_ORDER = (Run.priority.desc(), Run.id)


# The next answer number (models.AnswerCounter), as an upsert: the counter row stays locked until the answer
# commits, so numbers rise in commit order. It also heals: never below the highest number given (a row missing,
# or answers numbered by an older server process while this one migrated). {greatest}: the dialect's two-argument
# maximum; {condition}: when to take a number at all.
_NEXT_ANSWER_SEQ_SQL = """
    INSERT INTO answer_counter (id, value)
    SELECT 1, (SELECT COALESCE(MAX(answer_seq), 0) + 1 FROM queries) WHERE {condition}
    ON CONFLICT (id) DO UPDATE SET value = {greatest}(answer_counter.value + 1, excluded.value)
    RETURNING value
"""
_UNANSWERED = "EXISTS (SELECT 1 FROM queries WHERE id = :query_id AND status <> :answered)"
_NEXT_ANSWER_SEQ_IF_UNANSWERED = _NEXT_ANSWER_SEQ_SQL.format(condition=_UNANSWERED, greatest="GREATEST")
# (PostgreSQL, in _ANSWER_IN_ONE_STATEMENT below)
_TAKE_ANSWER_SEQ_IF_UNANSWERED = text(_NEXT_ANSWER_SEQ_SQL.format(condition=_UNANSWERED, greatest="MAX"))  # SQLite
_QUERY_COLUMNS = [column for column in Query.__table__.columns if column.key not in ("model_png", "display_png")]
_SET_ANSWER = (  # SQLite, under the write lock, once _TAKE_ANSWER_SEQ_IF_UNANSWERED took a number (bind names that
    # are not column names: update() reserves those)
    update(Query.__table__)
    .where(Query.__table__.c.id == bindparam("query_id"))
    .values(
        status=bindparam("answered"), answer=bindparam("new_answer"), labeler=bindparam("new_labeler"),
        answered_at=bindparam("now", type_=UTCDateTime()), answer_seq=bindparam("seq"),
    )
    .returning(*_QUERY_COLUMNS)
)  # fmt: skip
_ANSWER_COUNTER_VALUE = select(AnswerCounter.value).where(AnswerCounter.id == 1).scalar_subquery()
# An answer on PostgreSQL as one statement in its own transaction (autocommit): take the next number, set the
# answer if the query is not answered yet, log the event. The counter's row lock is held from taking the number to the
# commit inside the server, never while this process waits for a thread or the GIL (with a lock taken and the
# answer written in separate round trips, 11% of the answers waited > 10 ms for it under bench/load.py and the
# waits queued up into a 120-160 ms p99). A query answered meanwhile (the EXISTS sees the statement's snapshot)
# costs a number: the learners' cursors only need numbers to rise in commit order, not to be contiguous.
_ANSWER_IN_ONE_STATEMENT = (
    text(
        f"""
        WITH next_seq AS ({_NEXT_ANSWER_SEQ_IF_UNANSWERED}), answered AS (
            UPDATE queries SET status = :answered, answer = :answer, labeler = :labeler, answered_at = :now,
                answer_seq = next_seq.value
            FROM next_seq
            WHERE queries.id = :query_id AND queries.status <> :answered
            RETURNING {", ".join(f"queries.{column.name}" for column in _QUERY_COLUMNS)}
        ), logged AS (
            INSERT INTO events (run_id, level, message, created_at) SELECT run_id, 'info', :message, :now FROM answered
        )
        SELECT * FROM answered
        """
    )
    .bindparams(bindparam("now", type_=UTCDateTime()))
    .columns(*_QUERY_COLUMNS)
)


class _LostRace(Exception):
    """A compare-and-set UPDATE found the row changed since it was read."""


class Store(Database):
    """The one API over the database for the learner, the server and the tools."""

    # ---------------------------------------------------------------- goal sets and examples
    def create_goal_set(self, *, name: str, image_size: int = 48, env_id: str | None = None) -> GoalSet:
        """env_id: the task the photos show (None: any task)."""
        name = name.strip()
        if not name:
            raise InvalidInput("a goal set needs a name")
        if not 8 <= image_size <= 512:
            raise InvalidInput("image_size must be between 8 and 512")
        env_id = (env_id or "").strip() or None
        try:
            with self.writing() as session:
                goal_set = GoalSet(name=name, image_size=image_size, env_id=env_id)
                session.add(goal_set)
                session.flush()
                return goal_set
        except IntegrityError as error:
            raise Conflict(f"a goal set named {name!r} exists already") from error

    def list_goal_sets(self) -> list[tuple[GoalSet, int]]:
        """Goal sets with their example counts."""
        with self.reading() as session:
            counts = (
                select(GoalExample.goal_set_id, func.count().label("n")).group_by(GoalExample.goal_set_id).subquery()
            )
            rows = session.execute(
                select(GoalSet, func.coalesce(counts.c.n, 0))
                .outerjoin(counts, counts.c.goal_set_id == GoalSet.id)
                .order_by(GoalSet.id)
            ).all()
            return [(goal_set, int(count)) for goal_set, count in rows]

    def get_goal_set(self, *, goal_set_id: int) -> GoalSet:
        with self.reading() as session:
            goal_set = session.get(GoalSet, goal_set_id)
            if goal_set is None:
                raise NotFound(f"goal set {goal_set_id} not found")
            return goal_set

    def find_goal_set(self, *, name: str) -> GoalSet | None:
        with self.reading() as session:
            return session.scalars(select(GoalSet).where(GoalSet.name == name)).first()

    def delete_goal_set(self, *, goal_set_id: int) -> None:
        with self.writing() as session:
            goal_set = session.get(GoalSet, goal_set_id)
            if goal_set is None:
                raise NotFound(f"goal set {goal_set_id} not found")
            session.delete(goal_set)

    def add_goal_example(
        self,
        *,
        goal_set_id: int,
        filename: str,
        original: bytes,
        original_media_type: str,
        width: int,
        height: int,
        model_png: bytes,
        display_png: bytes,
        source: str = "upload",
    ) -> GoalExample:
        with self.writing() as session:
            if session.get(GoalSet, goal_set_id) is None:
                raise NotFound(f"goal set {goal_set_id} not found")
            example = GoalExample(
                goal_set_id=goal_set_id,
                filename=filename[:255],
                source=source,
                original_media_type=original_media_type,
                width=width,
                height=height,
                original=original,
                model_png=model_png,
                display_png=display_png,
            )
            session.add(example)
            session.flush()
            return example

    def list_goal_examples(self, *, goal_set_id: int) -> list[GoalExample]:
        with self.reading() as session:
            return list(
                session.scalars(
                    select(GoalExample).where(GoalExample.goal_set_id == goal_set_id).order_by(GoalExample.id)
                )
            )

    def get_goal_example(self, *, example_id: int) -> GoalExample:
        with self.reading() as session:
            example = session.get(GoalExample, example_id)
            if example is None:
                raise NotFound(f"goal example {example_id} not found")
            return example

    def goal_example_image(self, *, example_id: int, kind: str) -> bytes:
        """kind: 'original', 'model' or 'display'."""
        column = {
            "original": GoalExample.original,
            "model": GoalExample.model_png,
            "display": GoalExample.display_png,
        }.get(kind)
        if column is None:
            raise InvalidInput("image kind must be original, model or display")
        with self.reading() as session:
            data = session.scalar(select(column).where(GoalExample.id == example_id))
            if data is None:
                raise NotFound(f"goal example {example_id} not found")
            return data

    def goal_images(self, *, goal_set_id: int) -> list[GoalImage]:
        with self.reading() as session:
            rows = session.execute(
                select(GoalExample.id, GoalExample.model_png, GoalExample.original)
                .where(GoalExample.goal_set_id == goal_set_id)
                .order_by(GoalExample.id)
            ).all()
            return [GoalImage(id=row[0], model_png=row[1], original=row[2]) for row in rows]

    def delete_goal_example(self, *, example_id: int) -> None:
        with self.writing() as session:
            deleted = session.execute(delete(GoalExample).where(GoalExample.id == example_id)).rowcount
            if not deleted:
                raise NotFound(f"goal example {example_id} not found")

    # ---------------------------------------------------------------- runs
    def create_run(
        self,
        *,
        env_id: str,
        algorithm: str,
        config: dict[str, Any],
        seed: int = 0,
        goal_set_id: int | None = None,
        total_steps: int = 0,
        name: str = "",
        priority: int = 0,
    ) -> Run:
        with self.writing() as session:
            if goal_set_id is not None and session.get(GoalSet, goal_set_id) is None:
                raise NotFound(f"goal set {goal_set_id} not found")
            run = Run(
                name=name,
                env_id=env_id,
                algorithm=algorithm,
                config=config,
                seed=seed,
                goal_set_id=goal_set_id,
                total_steps=total_steps,
                status=RunStatus.QUEUED,
                priority=priority,
                queued_at=utcnow(),
            )
            session.add(run)
            session.flush()
            session.add(Event(run_id=run.id, level="info", message="run queued"))
            return run

    def get_run(self, *, run_id: int) -> Run:
        with self.reading() as session:
            run = session.get(Run, run_id)
            if run is None:
                raise NotFound(f"run {run_id} not found")
            return run

    def list_runs(self, *, archived: bool | None = None) -> list[Run]:
        """Newest first; archived=False leaves archived runs out, True lists only them, None all."""
        statement = select(Run)
        if archived is not None:
            statement = statement.where(Run.archived.is_(archived))
        with self.reading() as session:
            return list(session.scalars(statement.order_by(Run.id.desc())))

    def update_run(self, *, run_id: int, priority: int | None = None, archived: bool | None = None) -> Run:
        """Change a run's priority (any time) or archive it (only when no learner holds it or may take it)."""

        def change(run: Run) -> tuple[dict[str, Any], str]:
            values: dict[str, Any] = {}
            notes = []
            if priority is not None and priority != run.priority:
                values["priority"] = priority
                notes.append(f"priority {run.priority} -> {priority}")
            if archived is not None and archived != run.archived:
                if archived and run.status in (RunStatus.QUEUED, *RunStatus.ACTIVE):
                    raise Conflict(f"run {run.id} is {run.status}; stop it before archiving it")
                values["archived"] = archived
                notes.append("archived" if archived else "unarchived")
            return values, ", ".join(notes)

        return self._change_run(run_id=run_id, change=change)

    def delete_run(self, *, run_id: int) -> None:
        """Delete a run with its queries, metrics, events and rollouts (not while a learner holds it)."""
        with self.writing() as session:
            run = session.get(Run, run_id)
            if run is None:
                raise NotFound(f"run {run_id} not found")
            if run.status in RunStatus.ACTIVE:
                raise Conflict(f"run {run_id} is {run.status}; stop it before deleting it")
            for model in (Query, Metric, Event, Rollout):  # explicit: PostgreSQL and SQLite alike, no FK reliance
                session.execute(delete(model).where(model.run_id == run_id))
            deleted = session.execute(delete(Run).where(Run.id == run_id, Run.status.not_in(RunStatus.ACTIVE))).rowcount
            if not deleted:
                raise Conflict(f"run {run_id} was taken by a learner meanwhile; stop it before deleting it")

    def queue_report(self) -> dict[int, str]:
        """Why each queued run waits, in the order learners will take them: the busy learners' runs and the queued
        runs ahead of it ("learner busy with #1; after #4"), or that no learner is running."""
        stale_before = self._db_now(minus_seconds=60)  # the database's clock, as the claim judges staleness
        with self.reading() as session:
            queued = (
                session.execute(
                    select(Run.id)
                    .where(Run.status == RunStatus.QUEUED, Run.archived.is_(False))
                    .order_by(*_CLAIM_ORDER)
                )
                .scalars()
                .all()
            )
            if not queued:
                return {}
            busy = (
                session.execute(
                    select(Run.id)
                    .where(Run.status.in_(RunStatus.ACTIVE), Run.heartbeat_at >= stale_before)
                    .order_by(Run.id)
                )
                .scalars()
                .all()
            )
        reasons = {}
        for position, run_id in enumerate(queued):
            if busy:
                text = "learner busy with " + ", ".join(f"#{other}" for other in busy)
            else:
                text = "waiting for a learner (none is running: start one with raq learn or raq up)"
            ahead = queued[:position]
            if ahead:
                text += "; after " + ", ".join(f"#{other}" for other in ahead[:5]) + (" …" if len(ahead) > 5 else "")
            reasons[run_id] = text
        return reasons

    def higher_priority_waiting(self, *, run_id: int, waited_seconds: float = 10.0) -> Run | None:
        """A queued run of higher priority than `run_id` that has waited at least `waited_seconds` (an idle
        learner, polling every 2 s, would have taken it by then), or None."""
        with self.reading() as session:
            priority = session.scalar(select(Run.priority).where(Run.id == run_id))
            if priority is None:
                return None
            return session.scalars(
                select(Run)
                .where(
                    Run.status == RunStatus.QUEUED,
                    Run.archived.is_(False),
                    Run.priority > priority,
                    Run.queued_at <= utcnow() - timedelta(seconds=waited_seconds),
                )
                .order_by(*_CLAIM_ORDER)
                .limit(1)
            ).first()

    def count_runs(self) -> int:
        with self.reading() as session:
            return int(session.scalar(select(func.count()).select_from(Run)) or 0)

    def claim_next_run(self, *, worker: str, stale_after_seconds: float = 60.0) -> Run | None:
        """Atomically take the oldest queued run, or an active run whose learner stopped beating.

        Staleness is judged by the database's clock, never a host's: heartbeats and claims write the database's
        now, and a heartbeat is stale when it is older than the database's now minus `stale_after_seconds`.
        The UPDATE … WHERE status = <what we saw> makes the claim atomic: of two workers racing for
        the same row, exactly one changes it.
        """
        claimable = or_(
            (Run.status == RunStatus.QUEUED) & Run.archived.is_(False),
            (Run.status.in_(RunStatus.ACTIVE)) & (Run.heartbeat_at < self._db_now(minus_seconds=stale_after_seconds)),
        )
        with self.writing() as session:
            candidates = session.execute(
                select(Run.id, Run.status, Run.heartbeat_at).where(claimable).order_by(*_CLAIM_ORDER).limit(5)
            ).all()
            for run_id, status, heartbeat_at in candidates:
                now = self._db_now()
                claimed = session.execute(
                    update(Run)
                    .where(Run.id == run_id, Run.status == status, Run.heartbeat_at.is_not_distinct_from(heartbeat_at))
                    .values(
                        status=RunStatus.STARTING,
                        status_reason="",
                        phase=RunPhase.SETTING_UP,
                        worker=worker,
                        heartbeat_at=now,
                        started_at=func.coalesce(Run.started_at, now),
                    )
                ).rowcount
                if claimed:
                    resumed = status != RunStatus.QUEUED
                    message = f"claimed by {worker}" + (" (its last learner stopped beating)" if resumed else "")
                    session.add(Event(run_id=run_id, level="info", message=message))
                    return session.get(Run, run_id)
            return None

    def _db_now(self, minus_seconds: float = 0.0) -> Any:
        """The database's current UTC time (minus some seconds) as an SQL expression, in the form the backend
        stores UTCDateTime values: SQLite's text 'YYYY-MM-DD HH:MM:SS.ffffff', PostgreSQL's timestamptz."""
        if self.engine.dialect.name == "sqlite":
            modifiers = [f"-{float(minus_seconds):.6f} seconds"] if minus_seconds else []
            return func.strftime("%Y-%m-%d %H:%M:%f000", "now", *modifiers)
        # statement_timestamp, not now(): now() is when the transaction began, and a login try that waited for
        # another one's lock would stamp its failure, or measure its wait, from before that try was counted
        # (waits of 61 s for a 60 s window under load).
        if minus_seconds:
            return func.statement_timestamp() - timedelta(seconds=minus_seconds)
        return func.statement_timestamp()

    def heartbeat(
        self, *, run_id: int, worker: str, step: int | None = None, status: str | None = None, phase: str | None = None
    ) -> bool:
        """Record that `worker` is alive on the run (and, with `phase`, what it is doing). Returns False when it
        should stop (stop asked, or the run was taken from it)."""
        values: dict[str, Any] = {"heartbeat_at": self._db_now()}
        if phase is not None:
            values["phase"] = phase
        if step is not None:
            values["step"] = step
        if status is not None:
            values["status"] = status
        with self.autocommitting() as session:  # one statement, see Database.autocommitting
            stop_requested = session.scalar(
                update(Run)
                .where(Run.id == run_id, Run.worker == worker, Run.status.in_(RunStatus.ACTIVE))
                .values(**values)
                .returning(Run.stop_requested)
            )
            return stop_requested is not None and not stop_requested

    def set_run_status(self, *, run_id: int, status: str, reason: str = "", worker: str | None = None) -> None:
        """Set a terminal or intermediate status. With `worker`, only while that worker holds the run."""
        if status not in RunStatus.ALL:
            raise InvalidInput(f"unknown run status {status!r}")
        values: dict[str, Any] = {"status": status, "status_reason": reason[:2000]}
        if status == RunStatus.QUEUED:
            values["queued_at"] = utcnow()
        if status not in RunStatus.ACTIVE:
            values["phase"] = None
        if status in (RunStatus.FINISHED, RunStatus.FAILED, RunStatus.STOPPED):
            values["finished_at"] = utcnow()
            values["stop_requested"] = False
        with self.writing() as session:
            statement = update(Run).where(Run.id == run_id)
            if worker is not None:
                statement = statement.where(Run.worker == worker)
            if not session.execute(statement.values(**values)).rowcount:
                raise NotFound(f"run {run_id} not found" + (f" for worker {worker}" if worker else ""))
            level = "error" if status == RunStatus.FAILED else "info"
            message = f"status: {status}" + (f" ({reason})" if reason else "")
            session.add(Event(run_id=run_id, level=level, message=message))

    def request_stop(self, *, run_id: int) -> Run:
        """Stop a run: a queued run stops at once, an active one when its learner next beats."""
        return self._change_run(run_id=run_id, change=self._stop_change)

    def resume_run(self, *, run_id: int) -> Run:
        """Queue a stopped or failed run again; the learner resumes it from its last checkpoint."""
        return self._change_run(run_id=run_id, change=self._resume_change)

    def continue_run(self, *, run_id: int, total_steps: int) -> Run:
        """Train a finished (or stopped, or failed) run further, to a new, larger total of env steps: it is queued
        again and a learner goes on from its last checkpoint."""

        def change(run: Run) -> tuple[dict[str, Any], str]:
            if run.status not in (RunStatus.FINISHED, RunStatus.STOPPED, RunStatus.FAILED):
                raise Conflict(f"run {run.id} is {run.status}; only finished, stopped or failed runs can be continued")
            if total_steps <= max(run.total_steps, run.step):
                raise InvalidInput(
                    f"run {run.id} has {run.total_steps:,} steps in all (at step {run.step:,}): continue it to more"
                )
            values = {**self._queued_again(), "total_steps": total_steps}
            if "total_steps" in (run.config or {}):  # (an older copy in the config JSON says the same)
                values["config"] = {**run.config, "total_steps": total_steps}
            return values, f"continued from step {run.step:,} to {total_steps:,} steps: queued"

        return self._change_run(run_id=run_id, change=change)

    @staticmethod
    def _stop_change(run: Run) -> tuple[dict[str, Any], str]:
        if run.status == RunStatus.QUEUED:
            return {"status": RunStatus.STOPPED, "finished_at": utcnow()}, "stopped before a learner took it"
        if run.status in RunStatus.ACTIVE:
            return {"stop_requested": True}, "stop requested"
        raise Conflict(f"run {run.id} is {run.status}; only queued or active runs can be stopped")

    @staticmethod
    def _resume_change(run: Run) -> tuple[dict[str, Any], str]:
        if run.status == RunStatus.FINISHED:
            raise Conflict(
                f"run {run.id} is finished; continue it to a new total of env steps instead "
                f"(POST /api/runs/{run.id}/continue)"
            )
        if run.status not in (RunStatus.STOPPED, RunStatus.FAILED):
            raise Conflict(f"run {run.id} is {run.status}; only stopped or failed runs can be resumed")
        return Store._queued_again(), "resume requested: queued"

    @staticmethod
    def _queued_again() -> dict[str, Any]:
        return {
            "status": RunStatus.QUEUED, "status_reason": "", "stop_requested": False, "finished_at": None,
            "queued_at": utcnow(), "archived": False,
        }  # fmt: skip

    def _change_run(self, *, run_id: int, change: Any) -> Run:
        """Apply change(run) -> (values, event message) as a compare-and-set on the status it saw."""
        for _attempt in range(5):
            with self.writing() as session:
                run = session.get(Run, run_id, populate_existing=True)
                if run is None:
                    raise NotFound(f"run {run_id} not found")
                values, message = change(run)
                if not values:
                    return run
                changed = session.execute(
                    update(Run)
                    .where(Run.id == run_id, Run.status == run.status)
                    .values(**values)
                    .execution_options(synchronize_session=False)
                ).rowcount
                if not changed:  # its learner changed the status meanwhile: look again
                    continue
                session.add(Event(run_id=run_id, message=message))
                session.flush()
                session.refresh(run)
                return run
        raise Conflict(f"run {run_id} kept changing; try again")

    # ---------------------------------------------------------------- queries
    def post_query(
        self,
        *,
        run_id: int,
        env_step: int,
        model_png: bytes,
        display_png: bytes,
        score: float,
        strategy: str = "argmax",
        info: dict[str, Any] | None = None,
        ground_truth_success: float | None = None,
    ) -> Query:
        values = {
            "run_id": run_id, "env_step": env_step, "model_png": model_png, "display_png": display_png,
            "score": float(score), "strategy": strategy, "info": info or {},
            "ground_truth_success": ground_truth_success, "status": QueryStatus.PENDING,
        }  # fmt: skip
        with self.autocommitting() as session:  # one statement, see Database.autocommitting
            try:
                query = session.scalars(insert(Query).returning(Query), [values]).one()
            except IntegrityError:
                if session.get(Run, run_id) is None:  # the foreign key: the run was never there, or deleted
                    raise NotFound(f"run {run_id} not found") from None
                raise
        for column in ("model_png", "display_png"):  # deferred columns, not in RETURNING: the caller's bytes
            set_committed_value(query, column, values[column])
        return query

    def get_query(self, *, query_id: int) -> Query:
        with self.reading() as session:
            query = session.get(Query, query_id)
            if query is None:
                raise NotFound(f"query {query_id} not found")
            return query

    def list_queries(
        self, *, run_id: int | None = None, status: str | None = None, limit: int = 200, oldest_first: bool = False
    ) -> list[Query]:
        if status is not None and status not in QueryStatus.ALL:
            raise InvalidInput(f"status must be one of {', '.join(QueryStatus.ALL)}")
        statement = select(Query)
        if run_id is not None:
            statement = statement.where(Query.run_id == run_id)
        if status is not None:
            statement = statement.where(Query.status == status)
        statement = statement.order_by(Query.id if oldest_first else Query.id.desc()).limit(limit)
        with self.reading() as session:
            return list(session.scalars(statement))

    def pending_queries(self, *, run_id: int | None = None, limit: int = 200) -> list[Query]:
        return self.list_queries(run_id=run_id, status=QueryStatus.PENDING, limit=limit, oldest_first=True)

    def next_pending_query(self, *, run_id: int | None = None) -> Query | None:
        """The oldest pending query of one run; of all runs, the oldest of the live runs (queued, starting,
        training) first, then the oldest of the others (stopped, finished, failed). One lookup in
        ix_queries_run_status per live run, then one in ix_queries_status_id."""
        pending = select(Query).where(Query.status == QueryStatus.PENDING)
        with self.reading() as session:
            if run_id is not None:
                return session.scalars(pending.where(Query.run_id == run_id).order_by(Query.id).limit(1)).first()
            live = [
                session.scalar(
                    select(Query.id).where(Query.run_id == live_id, Query.status == QueryStatus.PENDING)
                    .order_by(Query.id).limit(1)
                )
                for live_id in self._live_run_ids(session)
            ]  # fmt: skip
            live_ids = [query_id for query_id in live if query_id is not None]
            if live_ids:
                return session.get(Query, min(live_ids))
            return session.scalars(pending.order_by(Query.id).limit(1)).first()

    @staticmethod
    def _live_run_ids(session: Any) -> list[int]:
        return list(session.scalars(select(Run.id).where(Run.status.in_(RunStatus.LIVE))))

    def count_queries(self, *, run_id: int | None = None, status: str | None = None, live_runs: bool = False) -> int:
        """SELECT COUNT(*), answered from the (run_id, status) / (status, id) indexes; live_runs: only the queries
        of runs that are queued, starting or training."""
        statement = select(func.count()).select_from(Query)
        if run_id is not None:
            statement = statement.where(Query.run_id == run_id)
        if status is not None:
            statement = statement.where(Query.status == status)
        if live_runs:
            statement = statement.where(Query.run_id.in_(select(Run.id).where(Run.status.in_(RunStatus.LIVE))))
        with self.reading() as session:
            return int(session.scalar(statement) or 0)

    def query_counts(self, *, run_id: int) -> dict[str, int]:
        """asked, pending, answered, yes, skipped."""
        # By status from the (run_id, status) index alone; "yes" visits only the answered rows.
        with self.reading() as session:
            rows = session.execute(
                select(Query.status, func.count()).where(Query.run_id == run_id).group_by(Query.status)
            ).all()
            yes = session.scalar(
                select(func.count())
                .select_from(Query)
                .where(Query.run_id == run_id, Query.status == QueryStatus.ANSWERED, Query.answer.is_(True))
            )
        counts = {"asked": 0, "pending": 0, "answered": 0, "yes": int(yes or 0), "skipped": 0}
        for status, n in rows:
            counts["asked"] += n
            counts[status] = counts.get(status, 0) + n
        return counts

    def query_image(self, *, query_id: int, resolution: str) -> bytes:
        """resolution: 'model' (what the learner saw) or 'display' (the larger render)."""
        column = {"model": Query.model_png, "display": Query.display_png}.get(resolution)
        if column is None:
            raise InvalidInput("resolution must be model or display")
        with self.reading() as session:
            data = session.scalar(select(column).where(Query.id == query_id))
            if data is None:
                raise NotFound(f"query {query_id} not found")
            return data

    def answer_query(self, *, query_id: int, success: bool, labeler: str = "") -> Query:
        """Record an answer. The same answer again is a no-op; a different one raises Conflict and the
        first stays. Skipped queries can still be answered."""
        for _attempt in range(5):
            try:
                return self._answer_query_once(query_id=query_id, success=success, labeler=labeler)
            except (IntegrityError, _LostRace):  # another answer or an undo got there first: look again
                continue
        raise Conflict("could not record the answer: too many concurrent answers, try again")

    def _answer_query_once(self, *, query_id: int, success: bool, labeler: str) -> Query:
        verdict = "yes" if success else "no"
        values = {
            "query_id": query_id, "answered": QueryStatus.ANSWERED, "answer": success,
            "labeler": labeler[:200] or None, "now": utcnow(),
            "message": (f"query {query_id} answered {verdict}" + (f" by {labeler}" if labeler else ""))[:1000],
        }  # fmt: skip
        if self.engine.dialect.name == "postgresql":
            with self.autocommitting() as session:
                answered = session.scalars(select(Query).from_statement(_ANSWER_IN_ONE_STATEMENT), values).one_or_none()
        else:
            answered = self._answer_sqlite(values)
        if answered is not None:
            return answered
        with self.reading() as session:  # not answered by this call: missing, or answered already
            query = self._query_row(session, query_id)
        if query.status == QueryStatus.ANSWERED:
            self._check_answer_again(query, success)
            return query
        raise _LostRace  # undone since it was written or (PostgreSQL) since the statement's snapshot: look again

    def _answer_sqlite(self, values: dict[str, Any]) -> Query | None:
        """The answer in three Core statements under BEGIN IMMEDIATE: take the next number if the query is not
        answered yet, set the answer, log the event. None: nothing written (no such query, or answered already).
        With the ORM (read the row, compare-and-set, flush the event) the write lock was held for ~4 ms of Python
        per answer, and answers queued behind it: under bench/load.py the p50 halved and the p99 fell from
        47-71 ms to 31-53 ms when the lock was held only for the statements (tens of microseconds each)."""
        with self.writing_statements() as connection:
            seq = connection.execute(_TAKE_ANSWER_SEQ_IF_UNANSWERED, values).scalar()
            if seq is None:
                return None
            row = connection.execute(
                _SET_ANSWER, {**values, "new_answer": values["answer"], "new_labeler": values["labeler"], "seq": seq}
            ).one()
            connection.execute(
                insert(Event), {"run_id": row.run_id, "message": values["message"], "created_at": values["now"]}
            )
        return Query(**row._mapping)

    @staticmethod
    def _check_answer_again(query: Query, success: bool) -> None:
        """An answered query: the same answer again is a no-op (returns), another one raises Conflict."""
        if query.answer == success:
            return
        first = "yes" if query.answer else "no"
        raise Conflict(f"query {query.id} was already answered {first!r}; the first answer is kept")

    def skip_query(self, *, query_id: int, labeler: str = "") -> Query:
        for _attempt in range(5):
            with self.writing() as session:
                query = self._query_row(session, query_id)
                if query.status == QueryStatus.ANSWERED:
                    raise Conflict(f"query {query_id} was already answered; the answer is kept")
                if query.status == QueryStatus.SKIPPED:
                    return query
                try:
                    self._compare_and_set(
                        session, query, Query.status == QueryStatus.PENDING,
                        status=QueryStatus.SKIPPED, labeler=labeler[:200] or None, answered_at=utcnow(),
                    )  # fmt: skip
                except _LostRace:
                    continue
                session.add(Event(run_id=query.run_id, message=f"query {query_id} skipped"))
                return query
        raise Conflict(f"query {query_id} changed while skipping it; try again")

    def undo_answer(self, *, query_id: int) -> Query:
        """Put an answered or skipped query back to pending, while the learner has not used it."""
        for _attempt in range(5):
            with self.writing() as session:
                query = self._query_row(session, query_id)
                if query.status == QueryStatus.PENDING:
                    raise Conflict(f"query {query_id} has no answer to undo")
                if query.used_at is not None:
                    raise Conflict(f"query {query_id}: the learner has already used this answer")
                previous = "skip" if query.status == QueryStatus.SKIPPED else ("yes" if query.answer else "no")
                try:
                    self._compare_and_set(
                        session, query, (Query.status == query.status) & Query.used_at.is_(None),
                        status=QueryStatus.PENDING, answer=None, labeler=None, answered_at=None, answer_seq=None,
                    )  # fmt: skip
                except _LostRace:
                    continue
                session.add(Event(run_id=query.run_id, message=f"answer {previous!r} to query {query_id} undone"))
                return query
        raise Conflict(f"query {query_id} changed while undoing its answer; try again")

    @staticmethod
    def _query_row(session: Any, query_id: int) -> Query:
        query = session.get(Query, query_id, populate_existing=True)
        if query is None:
            raise NotFound(f"query {query_id} not found")
        return query

    @staticmethod
    def _compare_and_set(session: Any, query: Query, condition: Any, **values: Any) -> None:
        """UPDATE the query only while `condition` still holds; raise _LostRace when it no longer does. The
        object takes the values as stored (RETURNING: SQL expressions included) without another SELECT."""
        row = session.execute(
            update(Query)
            .where(Query.id == query.id, condition)
            .values(**values)
            .returning(*(getattr(Query, name) for name in values))
            .execution_options(synchronize_session=False)
        ).one_or_none()
        if row is None:
            raise _LostRace
        for name, value in zip(values, row, strict=True):
            set_committed_value(query, name, value)

    def new_answers(self, *, run_id: int, since_seq: int = 0) -> list[AnsweredQuery]:
        """Answers to the run's queries with answer_seq > since_seq, oldest first. Marks them used in the same
        statement (UPDATE … RETURNING), so an answer the learner has read can no longer be undone, and an
        answer undone first is not returned."""
        with self.autocommitting() as session:  # one statement, see Database.autocommitting
            rows = session.execute(
                update(Query)
                .where(
                    Query.run_id == run_id,
                    Query.status == QueryStatus.ANSWERED,
                    Query.answer_seq > since_seq,
                    # No number above the counter as this statement's snapshot saw it: a row this UPDATE waits for
                    # is re-read at its newest version (PostgreSQL), which may carry a number taken after an
                    # answer the snapshot cannot see yet (undone and answered again meanwhile); returning it would
                    # move the learner's cursor past that answer for good.
                    Query.answer_seq <= func.coalesce(_ANSWER_COUNTER_VALUE, INT64_MAX),
                )  # fmt: skip
                .values(used_at=func.coalesce(Query.used_at, utcnow()))
                .returning(Query.id, Query.answer_seq, Query.answer, Query.model_png, Query.env_step)
                .execution_options(synchronize_session=False)
            ).all()
            return [
                AnsweredQuery(
                    query_id=row[0], answer_seq=row[1], success=bool(row[2]), model_png=row[3], env_step=row[4]
                )
                for row in sorted(rows, key=lambda row: row[1])
            ]

    # ---------------------------------------------------------------- metrics, events, rollouts
    def record_metrics(self, *, run_id: int, step: int, values: dict[str, float]) -> int:
        """Store one value per name at `step`. Non-finite values (a NaN loss) are left out, since SQL
        has no NaN; returns how many were stored."""
        now = utcnow()
        finite = {name: float(value) for name, value in values.items() if math.isfinite(float(value))}
        if finite:
            rows = [
                {"run_id": run_id, "step": step, "name": name, "value": value, "created_at": now}
                for name, value in finite.items()
            ]
            with self.autocommitting() as session:  # one statement, see Database.autocommitting
                session.execute(insert(Metric).values(rows))
        return len(finite)

    def metrics(self, *, run_id: int, since_step: int = -1, names: Iterable[str] | None = None) -> list[Metric]:
        statement = select(Metric).where(Metric.run_id == run_id, Metric.step > since_step)
        if names is not None:
            statement = statement.where(Metric.name.in_(list(names)))
        with self.reading() as session:
            return list(session.scalars(statement.order_by(Metric.step, Metric.id)))

    def latest_metric(self, *, run_id: int, name: str) -> float | None:
        with self.reading() as session:
            return session.scalar(
                select(Metric.value)
                .where(Metric.run_id == run_id, Metric.name == name)
                .order_by(Metric.step.desc(), Metric.id.desc())
                .limit(1)
            )

    def record_event(self, *, run_id: int | None, message: str, level: str = "info") -> None:
        with self.autocommitting() as session:  # one statement, see Database.autocommitting
            session.execute(insert(Event).values(run_id=run_id, level=level, message=message))

    def events(self, *, run_id: int | None = None, since_id: int = 0, limit: int = 200) -> list[Event]:
        statement = select(Event).where(Event.id > since_id)
        if run_id is not None:
            statement = statement.where(Event.run_id == run_id)
        with self.reading() as session:
            return list(session.scalars(statement.order_by(Event.id.desc()).limit(limit)))

    def record_rollout(
        self,
        *,
        run_id: int,
        env_step: int,
        data: bytes,
        frame_count: int,
        media_type: str = "image/gif",
        kind: str = "eval",
        episode_return: float | None = None,
        success: float | None = None,
        keep: int = 3,
    ) -> Rollout:
        """Store a rollout animation; only the newest `keep` of the run's rollouts are kept."""
        with self.writing() as session:
            rollout = Rollout(
                run_id=run_id,
                env_step=env_step,
                kind=kind,
                media_type=media_type,
                data=data,
                frame_count=frame_count,
                episode_return=episode_return,
                success=success,
            )
            session.add(rollout)
            session.flush()
            old_ids = session.scalars(
                select(Rollout.id).where(Rollout.run_id == run_id).order_by(Rollout.id.desc()).offset(keep)
            ).all()
            if old_ids:
                session.execute(delete(Rollout).where(Rollout.id.in_(old_ids)))
            return rollout

    def latest_rollout(self, *, run_id: int) -> Rollout | None:
        with self.reading() as session:
            return session.scalars(
                select(Rollout).where(Rollout.run_id == run_id).order_by(Rollout.id.desc()).limit(1)
            ).first()

    def rollout_data(self, *, rollout_id: int) -> bytes:
        with self.reading() as session:
            data = session.scalar(select(Rollout.data).where(Rollout.id == rollout_id))
            if data is None:
                raise NotFound(f"rollout {rollout_id} not found")
            return data

    def delete_metrics_after(self, *, run_id: int, step: int) -> int:
        """Delete the run's metrics recorded at steps after `step` (a resume from an older checkpoint
        records them again); returns how many were deleted."""
        with self.writing() as session:
            result = session.execute(delete(Metric).where(Metric.run_id == run_id, Metric.step > step))
            return int(result.rowcount or 0)

    # ---------------------------------------------------------------- login rate limit
    LOGIN_WINDOW_SECONDS = 60.0

    def login_attempt(self, *, client: str, per_minute: int) -> int | None:
        """A login try from `client`: None when it may try now (the try is then counted as a failure in the same
        transaction, undone by `login_succeeded`), else the seconds until it may. At most `per_minute` failures in
        any 60 s, by the database's clock, across every server process and host; tries from one address are
        checked and counted one at a time, so a burst of parallel guesses cannot all pass the check."""
        window, client = self.LOGIN_WINDOW_SECONDS, client[:200]
        with self.writing() as session:  # SQLite: one writer at a time already
            if self.engine.dialect.name == "postgresql":  # one try per address at a time, until the commit
                session.execute(select(func.pg_advisory_xact_lock(LOGIN_LOCK, func.hashtext(client))))
            session.execute(delete(LoginFailure).where(LoginFailure.failed_at <= self._db_now(window)))
            recent = session.scalars(
                select(LoginFailure.failed_at).where(LoginFailure.client == client).order_by(LoginFailure.failed_at)
            ).all()
            if len(recent) < per_minute:
                session.execute(insert(LoginFailure).values(client=client, failed_at=self._db_now()))
                return None
            now = session.scalar(select(type_coerce(self._db_now(), UTCDateTime)))
        frees_a_try = recent[len(recent) - per_minute]  # once this one is older than the window, one more try
        return max(1, math.ceil((frees_a_try - now).total_seconds() + window))

    def login_succeeded(self, *, client: str) -> None:
        """The try `login_attempt` counted was the right token: it is not a failure (the address's latest)."""
        with self.writing() as session:
            latest = (
                select(LoginFailure.id)
                .where(LoginFailure.client == client[:200])
                .order_by(LoginFailure.id.desc())
                .limit(1)
                .scalar_subquery()
            )
            session.execute(delete(LoginFailure).where(LoginFailure.id == latest))

    # ---------------------------------------------------------------- login sessions
    def create_session(
        self, *, secret_hash: str, token_fingerprint: str, max_age_seconds: float, client: str = ""
    ) -> None:
        """Record a login: the caller keeps the secret (in the cookie), the store only its hash. Expired
        sessions are deleted on the way."""
        now = utcnow()
        with self.writing() as session:
            session.execute(delete(LoginSession).where(LoginSession.expires_at <= now))
            session.add(
                LoginSession(
                    secret_hash=secret_hash,
                    token_fingerprint=token_fingerprint,
                    client=client[:200],
                    created_at=now,
                    expires_at=now + timedelta(seconds=max_age_seconds),
                )
            )

    def session_is_active(self, *, secret_hash: str, token_fingerprint: str) -> bool:
        """True while the session exists, has not expired and was made under the current API token."""
        with self.reading() as session:
            found = session.scalar(
                select(LoginSession.id).where(
                    LoginSession.secret_hash == secret_hash,
                    LoginSession.token_fingerprint == token_fingerprint,
                    LoginSession.expires_at > utcnow(),
                )
            )
            return found is not None

    def end_session(self, *, secret_hash: str) -> bool:
        with self.writing() as session:
            deleted = session.execute(delete(LoginSession).where(LoginSession.secret_hash == secret_hash)).rowcount
            return bool(deleted)

    def end_all_sessions(self) -> int:
        """Log every browser out; returns how many sessions there were."""
        with self.writing() as session:
            return int(session.execute(delete(LoginSession)).rowcount or 0)

    def count_sessions(self) -> int:
        with self.reading() as session:
            return int(
                session.scalar(select(func.count()).select_from(LoginSession).where(LoginSession.expires_at > utcnow()))
                or 0
            )

    # ---------------------------------------------------------------- helpers
    def ping(self) -> bool:
        with self.reading() as session:
            return session.scalar(select(1)) == 1


def seconds_since(moment: datetime | None) -> float | None:
    if moment is None:
        return None
    return (datetime.now(UTC) - moment).total_seconds()
