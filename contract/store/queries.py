"""Queries: the images the learner asks about, and the labellers' answers. Answers are numbered (answer_seq) in
commit order through the answer counter, so a learner reads each one exactly once with `new_answers` (which also
marks them used: they can no longer be undone). Answering is one statement on PostgreSQL and three Core statements
under the write lock on SQLite; skipping and undoing are compare-and-sets, all retried by base.retry_lost_races.
"""

from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import bindparam, func, insert, select, text, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm.attributes import set_committed_value

from contract.store.base import LostRace, StoreBase, compare_and_set, found, retry_lost_races
from contract.store.errors import Conflict, InvalidInput, NotFound
from contract.store.models import (
    INT64_MAX,
    AnswerCounter,
    Event,
    Query,
    QueryStatus,
    Run,
    RunStatus,
    UTCDateTime,
    utcnow,
)


@dataclass(frozen=True)
class AnsweredQuery:
    """An answer as the learner consumes it."""

    query_id: int
    answer_seq: int
    success: bool
    model_png: bytes
    env_step: int


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


class QueryStore(StoreBase):
    """The learner's questions and the labellers' answers."""

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
        return self._get(Query, query_id, "query")

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

    def mark_query_shown(self, *, query_id: int) -> None:
        """A page was served the question to show: its shown_at is stamped the first time only (the person's
        answering time counts from it; by the web server's clock, as answered_at is)."""
        with self.writing() as session:
            session.execute(
                update(Query).where(Query.id == query_id, Query.shown_at.is_(None)).values(shown_at=utcnow())
            )

    def answer_times(self, *, run_id: int) -> list[tuple[datetime | None, datetime]]:
        """(shown_at, answered_at) of each answered question of the run, oldest first (shown_at None: no page
        was served it, as with an automated labeller's answers)."""
        with self.reading() as session:
            rows = session.execute(
                select(Query.shown_at, Query.answered_at)
                .where(Query.run_id == run_id, Query.status == QueryStatus.ANSWERED, Query.answered_at.is_not(None))
                .order_by(Query.id)
            ).all()
        return [(shown_at, answered_at) for shown_at, answered_at in rows]

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
        return self._column_of(column, query_id, "query")

    def answer_query(self, *, query_id: int, success: bool, labeler: str = "") -> Query:
        """Record an answer. The same answer again is a no-op; a different one raises Conflict and the
        first stays. Skipped queries can still be answered."""
        return retry_lost_races(  # another answer or an undo got there first (IntegrityError or LostRace): look again
            lambda: self._answer_query_once(query_id=query_id, success=success, labeler=labeler),
            conflict="could not record the answer: too many concurrent answers, try again", also=(IntegrityError,),
        )  # fmt: skip

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
        raise LostRace  # undone since it was written or (PostgreSQL) since the statement's snapshot: look again

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
        def attempt() -> Query:
            with self.writing() as session:
                query = self._query_row(session, query_id)
                if query.status == QueryStatus.ANSWERED:
                    raise Conflict(f"query {query_id} was already answered; the answer is kept")
                if query.status == QueryStatus.SKIPPED:
                    return query
                compare_and_set(
                    session, query, Query.status == QueryStatus.PENDING,
                    status=QueryStatus.SKIPPED, labeler=labeler[:200] or None, answered_at=utcnow(),
                )  # fmt: skip
                session.add(Event(run_id=query.run_id, message=f"query {query_id} skipped"))
                return query

        return retry_lost_races(attempt, conflict=f"query {query_id} changed while skipping it; try again")

    def undo_answer(self, *, query_id: int) -> Query:
        """Put an answered or skipped query back to pending, while the learner has not used it."""

        def attempt() -> Query:
            with self.writing() as session:
                query = self._query_row(session, query_id)
                if query.status == QueryStatus.PENDING:
                    raise Conflict(f"query {query_id} has no answer to undo")
                if query.used_at is not None:
                    raise Conflict(f"query {query_id}: the learner has already used this answer")
                previous = "skip" if query.status == QueryStatus.SKIPPED else ("yes" if query.answer else "no")
                compare_and_set(
                    session, query, (Query.status == query.status) & Query.used_at.is_(None),
                    status=QueryStatus.PENDING, answer=None, labeler=None, answered_at=None, answer_seq=None,
                )  # fmt: skip
                session.add(Event(run_id=query.run_id, message=f"answer {previous!r} to query {query_id} undone"))
                return query

        return retry_lost_races(attempt, conflict=f"query {query_id} changed while undoing its answer; try again")

    @staticmethod
    def _query_row(session: Any, query_id: int) -> Query:
        return found(session.get(Query, query_id, populate_existing=True), f"query {query_id}")

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
