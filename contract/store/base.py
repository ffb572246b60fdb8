"""What the store's aggregates share: `StoreBase` (the Database plus the database's clock and a ping), and the one
compare-and-set with its retry. A write that read a row and decides from what it saw updates it with
`compare_and_set` (UPDATE … WHERE <what was seen still holds> RETURNING), which raises `LostRace` when another
writer changed the row first; `retry_lost_races` then runs the whole read-decide-write again, a few times, before
giving up with a Conflict. Runs (stop, resume, priority, archive) and queries (answer, skip, undo) both go through it.
"""

from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any, TypeVar

from sqlalchemy import func, select, update
from sqlalchemy.orm.attributes import set_committed_value

from contract.store.db import Database, retry
from contract.store.errors import Conflict, NotFound

T = TypeVar("T")
RACE_TRIES = 5
"""How many times a read-decide-write that lost a race is tried in all before it gives up (Conflict)."""


class LostRace(Exception):
    """A compare-and-set UPDATE found the row changed since it was read."""


def compare_and_set(session: Any, row: Any, condition: Any, **values: Any) -> None:
    """UPDATE the row only while `condition` still holds; raise LostRace when it no longer does. The object takes
    the values as stored (RETURNING: SQL expressions included) without another SELECT."""
    model = type(row)
    returned = session.execute(
        update(model)
        .where(model.id == row.id, condition)
        .values(**values)
        .returning(*(getattr(model, name) for name in values))
        .execution_options(synchronize_session=False)
    ).one_or_none()
    if returned is None:
        raise LostRace
    for name, value in zip(values, returned, strict=True):
        set_committed_value(row, name, value)


def retry_lost_races(attempt: Callable[[], T], *, conflict: str, also: tuple[type[Exception], ...] = ()) -> T:
    """attempt() again while it raises LostRace (or one of `also`), RACE_TRIES times in all; then Conflict(conflict)."""
    races = (LostRace, *also)
    return retry(
        attempt, again=lambda error: isinstance(error, races), tries=RACE_TRIES, gave_up=lambda: Conflict(conflict)
    )


def found(row: T | None, what: str) -> T:
    """The row, or NotFound("<what> not found") when there is none."""
    if row is None:
        raise NotFound(f"{what} not found")
    return row


class StoreBase(Database):
    """The Database every aggregate's store class builds on."""

    def _get(self, model: type[T], row_id: int, what: str) -> T:
        """The row of `model` with this id, or NotFound("<what> <id> not found")."""
        with self.reading() as session:
            return found(session.get(model, row_id), f"{what} {row_id}")

    def _column_of(self, column: Any, row_id: int, what: str) -> Any:
        """One column (a deferred binary one) of the row with this id, or NotFound("<what> <id> not found")."""
        with self.reading() as session:
            return found(session.scalar(select(column).where(column.class_.id == row_id)), f"{what} {row_id}")

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

    def ping(self) -> bool:
        with self.reading() as session:
            return session.scalar(select(1)) == 1


def seconds_since(moment: datetime | None) -> float | None:
    if moment is None:
        return None
    return (datetime.now(UTC) - moment).total_seconds()
