"""Logins: the rate limit on login tries (failures per client address in a 60 s window by the database's clock,
counted one try at a time per address across processes and hosts) and the browsers' login sessions (only a hash of
each session secret is stored, bound to the API token it was made under).
"""

import math
from datetime import timedelta

from sqlalchemy import delete, func, insert, select, type_coerce

from contract.store.base import StoreBase
from contract.store.models import (
    LoginFailure,
    LoginSession,
    UTCDateTime,
    utcnow,
)

# PostgreSQL advisory lock class (the first of two keys; the second is the client address's hash) under which one
# login try per address is checked and counted.
LOGIN_LOCK = 0x52_41_51_02


class AuthStore(StoreBase):
    """The login rate limit and the browsers' login sessions."""

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

    def login_wait(self, *, client: str, per_minute: int) -> int | None:
        """The seconds until `client` may try again when it has used up its `per_minute` failures (as
        `login_attempt` counts them), else None. Reads only: a request carrying the right token is refused while
        its address is limited (so a guess that happens to be right does not pass), without counting anything."""
        window, client = self.LOGIN_WINDOW_SECONDS, client[:200]
        with self.reading() as session:
            recent = session.scalars(
                select(LoginFailure.failed_at)
                .where(LoginFailure.client == client, LoginFailure.failed_at > self._db_now(window))
                .order_by(LoginFailure.failed_at)
            ).all()
            if len(recent) < per_minute:
                return None
            now = session.scalar(select(type_coerce(self._db_now(), UTCDateTime)))
        frees_a_try = recent[len(recent) - per_minute]
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
