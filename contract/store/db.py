"""Engines and sessions. SQLite gets WAL, a busy timeout and foreign keys on every connection."""

import sqlite3
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from pathlib import Path
from typing import TypeVar

from sqlalchemy import Connection, Engine, create_engine, event, exc
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

SQLITE_BUSY_TIMEOUT_MS = 30_000
POOL_SIZE = 40
"""Connections each process keeps open: as many as the server's worker threads (anyio's 40), so that a burst of
requests does not open (PostgreSQL: fork a backend for) and close overflow connections one request each."""
IDLE_PING_S = 1.0
"""A pooled PostgreSQL connection that has been idle this long is pinged before use (a restarted or failed-over
server has dropped it, and the pool then opens a new one); one in steady use is not. SQLAlchemy's pool_pre_ping
pinged on every checkout: one more round trip per request, +20 ms on the answers' p99 under bench/load.py."""
SQLITE_LOCK_POLL_S = (0.0005, 0.005)
"""A writer waiting for another process's write lock retries after 0.5 ms, doubling up to 5 ms."""
POOL_WAIT_S = 10.0
"""The longest a caller waits for a free pooled connection."""
POSTGRESQL_LINK_ARGS = {
    "connect_timeout": 3,  # seconds to make a connection
    "keepalives": 1, "keepalives_idle": 2, "keepalives_interval": 1, "keepalives_count": 3,
    "tcp_user_timeout": 3000,  # ms that sent data may stay unacknowledged: a pulled cable ends the connection
    "options": "-c statement_timeout=60000",  # ms: no statement runs for longer on the server
}
"""libpq's settings for every PostgreSQL connection: a dead link ends in seconds instead of TCP's minutes (code
that moves a robot also bounds each call itself: contract/store/bounded.py)."""


T = TypeVar("T")


def retry(
    attempt: Callable[[], T],
    *,
    again: Callable[[Exception], bool],
    tries: int | None = None,
    seconds: float | None = None,
    pauses: tuple[float, float] = (0.0, 0.0),
    gave_up: Callable[[], Exception] | None = None,
) -> T:
    """attempt() until it returns: the one retry loop of the store (a busy SQLite lock here, a lost compare-and-set
    in contract.store.base). An exception that `again` accepts calls it once more, after a pause of pauses[0] s
    doubling up to pauses[1] s, at most `tries` calls or for `seconds` s; then gave_up()'s exception is raised in
    its place (without gave_up: the last one itself). Any other exception passes at once."""
    deadline = None if seconds is None else time.monotonic() + seconds
    pause, tried = pauses[0], 0
    while True:
        try:
            return attempt()
        except Exception as error:
            tried += 1
            if not again(error):
                raise
            if tried == tries or (deadline is not None and time.monotonic() > deadline):
                if gave_up is None:
                    raise
                raise gave_up() from None
        if pause:
            time.sleep(pause)
            pause = min(2 * pause, pauses[1])


def _sqlite_busy(error: Exception) -> bool:
    return isinstance(error, sqlite3.OperationalError) and error.sqlite_errorname.startswith(
        ("SQLITE_BUSY", "SQLITE_LOCKED")  # or an extended code
    )


def _begin_immediate(dbapi_connection: sqlite3.Connection) -> None:
    """BEGIN IMMEDIATE, retried every few ms while another connection writes, up to the busy timeout.

    SQLite's own busy handler sleeps 1, 2, 5, ... 50, 100, 100 ms between tries: a writer that met one
    lock holder waits up to 100 ms after the lock is free, which made the answers' p99 latency 200+ ms while
    learners wrote. Polling at most every 5 ms costs microseconds per try.
    """
    dbapi_connection.execute("PRAGMA busy_timeout=0")
    try:
        retry(
            lambda: dbapi_connection.execute("BEGIN IMMEDIATE"),
            again=_sqlite_busy, seconds=SQLITE_BUSY_TIMEOUT_MS / 1000, pauses=SQLITE_LOCK_POLL_S,
        )  # fmt: skip
    finally:
        dbapi_connection.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")


def _configure_sqlite(engine: Engine) -> None:
    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection, _record) -> None:  # type: ignore[no-untyped-def]
        # Let SQLAlchemy's "begin" event below issue BEGIN itself (pysqlite's own is unreliable). A connection
        # checked in after an autocommitting session gets isolation_level "" back from SQLAlchemy; harmless, since
        # the "begin" event starts every transaction before its first statement, so pysqlite never adds its own.
        dbapi_connection.isolation_level = None
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute(f"PRAGMA busy_timeout={SQLITE_BUSY_TIMEOUT_MS}")
        cursor.execute("PRAGMA foreign_keys=ON")
        cursor.execute("PRAGMA synchronous=NORMAL")
        cursor.close()

    @event.listens_for(engine, "begin")
    def _on_begin(connection) -> None:  # type: ignore[no-untyped-def]
        # Writers take the lock up front (BEGIN IMMEDIATE) so that they wait for it; a deferred transaction
        # that reads first and writes later fails at once with "database is locked".
        options = connection.get_execution_options()
        if options.get("isolation_level") == "AUTOCOMMIT":
            return  # Database.autocommitting: each statement is its own transaction, SQLite's implicit one
        if options.get("sqlite_immediate"):
            _begin_immediate(connection.connection.driver_connection)
        else:
            connection.exec_driver_sql("BEGIN")


def _ping_idle_connections(engine: Engine) -> None:
    @event.listens_for(engine, "checkin")
    def _on_checkin(_dbapi_connection, record) -> None:  # type: ignore[no-untyped-def]
        record.info["returned_at"] = time.monotonic()

    @event.listens_for(engine, "checkout")
    def _on_checkout(dbapi_connection, record, _proxy) -> None:  # type: ignore[no-untyped-def]
        returned_at = record.info.get("returned_at")  # (None: opened just now)
        if returned_at is None or time.monotonic() - returned_at < IDLE_PING_S:
            return
        try:
            engine.dialect.do_ping(dbapi_connection)
        except engine.dialect.loaded_dbapi.Error as error:  # the pool drops it and checks out another
            raise exc.DisconnectionError(f"a pooled connection idle for {IDLE_PING_S} s is gone") from error


def make_engine(url: str) -> Engine:
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        on_disk = parsed.database not in (None, "", ":memory:")
        if on_disk:
            Path(parsed.database).parent.mkdir(parents=True, exist_ok=True)
        # (in memory: one connection per thread, no pool to size)
        pool = {"pool_size": POOL_SIZE, "max_overflow": 0} if on_disk else {}
        engine = create_engine(url, connect_args={"timeout": SQLITE_BUSY_TIMEOUT_MS / 1000}, **pool)
        _configure_sqlite(engine)
        return engine
    engine = create_engine(url, pool_size=POOL_SIZE, max_overflow=0, pool_timeout=POOL_WAIT_S,
                           connect_args=POSTGRESQL_LINK_ARGS)  # fmt: skip
    _ping_idle_connections(engine)
    return engine


class Database:
    """An engine plus two session factories: reads (deferred) and writes (exclusive from the start)."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.engine = make_engine(url)
        # SQLite has one writer at a time, and a connection waiting for the write lock polls with SQLite's busy
        # handler, sleeping up to 100 ms between tries: under 50 concurrent requests the answers' p99 was 200+
        # ms although each write holds the lock ~1 ms. Writers of this process queue on a lock instead and
        # start the moment the previous one commits; against other processes (learners) _begin_immediate polls.
        self._write_turn: AbstractContextManager = (
            threading.RLock() if self.engine.dialect.name == "sqlite" else nullcontext()
        )
        autocommit = self.engine.execution_options(isolation_level="AUTOCOMMIT")
        # PostgreSQL reads without BEGIN and ROLLBACK: under READ COMMITTED each statement sees what was committed
        # when it started, in a transaction or not, so a read-only session loses nothing and saves two round trips.
        postgresql = self.engine.dialect.name == "postgresql"
        self._read = sessionmaker(autocommit if postgresql else self.engine, expire_on_commit=False)
        self._immediate = self.engine.execution_options(sqlite_immediate=True)
        self._write = sessionmaker(self._immediate, expire_on_commit=False)
        self._autocommit = sessionmaker(autocommit, expire_on_commit=False)

    @contextmanager
    def reading(self) -> Iterator[Session]:
        with self._read() as session:
            yield session

    @contextmanager
    def writing(self) -> Iterator[Session]:
        with self._write_turn, self._write() as session, session.begin():
            yield session

    @contextmanager
    def writing_statements(self) -> Iterator[Connection]:
        """A write transaction for Core statements only (no ORM session, no unit of work): on SQLite the write
        lock is then held for the statements themselves, tens of microseconds each, instead of the milliseconds
        of Python an ORM session spends between them (where a busy server's threads also wait for the GIL)."""
        with self._write_turn, self._immediate.begin() as connection:
            yield connection

    @contextmanager
    def autocommitting(self) -> Iterator[Session]:
        """Each statement in its own transaction, committed by the database before it answers: its locks are
        held only while the database runs it, never while this process waits for anything. PostgreSQL: one round
        trip instead of three. SQLite: the write lock is held inside one sqlite3 call instead of from BEGIN
        IMMEDIATE through Python to COMMIT; a learner at nice 10 descheduled in that window held it for up to
        165 ms while the server's answers waited (measured under bench/load.py). Writers of this process still
        take their turn first; against other processes SQLite's busy handler waits."""
        with self._write_turn, self._autocommit() as session:
            yield session

    def dispose(self) -> None:
        self.engine.dispose()
