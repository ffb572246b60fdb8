"""The link between a learner and an actor on another host (the robot's): what they share goes through the
database, and the policy's weights through the checkpoint store (object storage).

The learner opens the link (open_actor_link: the step its run starts at), stamps it four times a second
(learner_keepalive) and publishes each new policy's version (publish_actor_policy) after writing its weights;
the actor announces its action and observation spaces and its control rate (announce_actor), posts its steps in
order (post_actor_messages) and reads the link's state (actor_link); the learner takes the steps in id order
(take_actor_messages). The messages are the robot's steps as they happened, kept until a checkpoint of the run holds
them (forget_actor_messages): a learner that takes the run over trains on every step taken after its checkpoint
(up to newest_actor_message before its actor starts). Ages are measured on the database's clock, never a host's.

Each of the learner's writes carries the claim it holds the run with (Run.claim) and is skipped when the run has
been claimed again since: a learner that stalled past the staleness limit and wakes after another took its run
over never closes, stamps or publishes on the new learner's link, nor forgets the steps its checkpoint lacks.
"""

from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import delete, func, insert, select

from contract.store.base import StoreBase, found
from contract.store.models import ActorMessage, RobotControl, Run, RunStatus
from contract.store.robots import RobotStore

LEARNER_LIVE_SECONDS = 1.0
"""A learner whose keep-alive (every 0.25 s) is younger than this has its link open now (runs_awaiting_actor)."""
TAKE_MAX = 256
"""The most actor messages one take_actor_messages returns."""


@dataclass(frozen=True)
class ActorLink:
    """The learner's side of the link as the actor reads it, and the actor's announcement as the learner reads it."""

    start_step: int | None
    """The step the run is at when its learner opened the link (None: no learner has it open)."""
    learner_closed: bool
    policy_version: int
    learner_seen_at: datetime | None
    learner_age_seconds: float | None
    """Seconds since the learner's last keep-alive, by the database's clock (None: never)."""
    actor_spaces: dict[str, Any] | None
    actor_age_seconds: float | None
    """Seconds since the actor's last report, by the database's clock (None: never)."""


@dataclass(frozen=True)
class ActorLinkMessage:
    """One message of the actor, as stored."""

    id: int
    kind: str
    payload: dict[str, Any]
    observation_png: bytes | None
    display_png: bytes | None


class ActorLinkStore(RobotStore, StoreBase):
    """Learner and remote actor: the link's state in robot_controls, the actor's messages in actor_messages."""

    def open_actor_link(self, *, run_id: int, claim: int, start_step: int | None) -> ActorLink:
        """The learner takes the link (the messages an earlier learner's checkpoint does not hold are kept for it);
        `start_step` (None: not yet) tells the actor where the run is. NotFound for an unknown run."""
        values = {"start_step": start_step, "learner_closed": False, "learner_seen_at": self._db_now()}
        self._write_link(run_id=run_id, claim=claim, values=values)
        return self.actor_link(run_id=run_id)

    def start_actor_link(self, *, run_id: int, claim: int, start_step: int) -> bool:
        """The learner has read its checkpoint: the actor may begin its first episode at `start_step`."""
        return self._write_link(run_id=run_id, claim=claim, values={"start_step": int(start_step)})

    def learner_keepalive(self, *, run_id: int, claim: int) -> bool:
        """The learner is alive (it calls this every quarter of a second)."""
        return self._write_link(run_id=run_id, claim=claim, values={"learner_seen_at": self._db_now()})

    def publish_actor_policy(self, *, run_id: int, claim: int) -> int | None:
        """A new policy is in the checkpoint store: its version (one more than the last); None when the run's
        claim has moved on (nothing is published)."""
        values = {"policy_version": RobotControl.policy_version + 1}
        with self.writing() as session:
            if not self._claimed_by(session, run_id=run_id, claim=claim):
                return None
            self._update_or_create(session, run_id=run_id, values=values)
            return int(session.scalar(select(RobotControl.policy_version).where(RobotControl.run_id == run_id)))

    def close_actor_link(self, *, run_id: int, claim: int) -> bool:
        """The learner lets go of the actor: it holds the arm and waits for the next learner."""
        return self._write_link(run_id=run_id, claim=claim, values={"learner_closed": True, "start_step": None})

    def _write_link(self, *, run_id: int, claim: int, values: dict[str, Any]) -> bool:
        """The learner's side of the link, written while `claim` is the run's (False: skipped)."""
        with self.writing() as session:
            if not self._claimed_by(session, run_id=run_id, claim=claim):
                return False
            self._update_or_create(session, run_id=run_id, values=values)
        return True

    @staticmethod
    def _claimed_by(session: Any, *, run_id: int, claim: int) -> bool:
        """`claim` is the run's current one; NotFound for an unknown run."""
        current = found(session.scalar(select(Run.claim).where(Run.id == run_id)), f"run {run_id}")
        return int(current) == int(claim)

    def runs_awaiting_actor(self, *, env_id: str, run_id: int | None = None) -> list[int]:
        """The active runs of `env_id` (or run `run_id` alone) whose learner has the link open now (not closed, a
        keep-alive within LEARNER_LIVE_SECONDS), by id: the runs a robot process may drive."""
        query = (
            select(Run.id)
            .join(RobotControl, RobotControl.run_id == Run.id)
            .where(
                Run.env_id == env_id, Run.status.in_(RunStatus.ACTIVE), RobotControl.learner_closed.is_(False),
                RobotControl.learner_seen_at >= self._db_now(LEARNER_LIVE_SECONDS),
            )
            .order_by(Run.id)
        )  # fmt: skip
        if run_id is not None:
            query = query.where(Run.id == run_id)
        with self.reading() as session:
            return [int(found_id) for found_id in session.scalars(query)]

    def announce_actor(self, *, run_id: int, spaces: dict[str, Any]) -> None:
        """The actor is up: its action and observation spaces and its control rate, as JSON."""
        with self.writing() as session:
            self._update_or_create(session, run_id=run_id, values={"actor_spaces": spaces})

    def actor_link(self, *, run_id: int) -> ActorLink:
        """The link's state (the defaults before anyone used it); NotFound for an unknown run."""
        with self.reading() as session:
            row = session.execute(
                select(
                    RobotControl.start_step, RobotControl.learner_closed, RobotControl.policy_version,
                    RobotControl.learner_seen_at, RobotControl.actor_spaces, RobotControl.actor_seen_at,
                    self._db_now(),
                ).where(RobotControl.run_id == run_id)
            ).one_or_none()  # fmt: skip
            if row is None:
                found(session.scalar(select(Run.id).where(Run.id == run_id)), f"run {run_id}")
                return ActorLink(None, False, 0, None, None, None, None)
        start_step, closed, version, learner_seen_at, spaces, actor_seen_at, db_now = row
        db_now = _as_datetime(db_now)
        return ActorLink(
            start_step=start_step, learner_closed=bool(closed), policy_version=int(version),
            learner_seen_at=learner_seen_at, learner_age_seconds=_age(db_now, learner_seen_at),
            actor_spaces=spaces, actor_age_seconds=_age(db_now, actor_seen_at),
        )  # fmt: skip

    def post_actor_messages(
        self, *, run_id: int, messages: list[tuple[str, dict[str, Any], bytes | None, bytes | None]]
    ) -> None:
        """The actor's messages (kind, payload, observation PNG, display PNG), in order, in one transaction."""
        if not messages:
            return
        rows = [
            {"run_id": run_id, "kind": kind, "payload": payload, "observation_png": observation,
             "display_png": display, "created_at": self._db_now()}
            for kind, payload, observation, display in messages
        ]  # fmt: skip
        with self.writing() as session:
            session.execute(insert(ActorMessage).values(rows))

    def take_actor_messages(self, *, run_id: int, after_id: int, limit: int = TAKE_MAX) -> list[ActorLinkMessage]:
        """The actor's messages after `after_id`, oldest first. Taking deletes none: forget_actor_messages does, once
        a checkpoint holds them."""
        with self.reading() as session:
            rows = session.execute(
                select(
                    ActorMessage.id, ActorMessage.kind, ActorMessage.payload, ActorMessage.observation_png,
                    ActorMessage.display_png,
                )
                .where(ActorMessage.run_id == run_id, ActorMessage.id > after_id)
                .order_by(ActorMessage.id)
                .limit(limit)
            ).all()  # fmt: skip
        return [
            ActorLinkMessage(id=row[0], kind=row[1], payload=row[2], observation_png=row[3], display_png=row[4])
            for row in rows
        ]

    def newest_actor_message(self, *, run_id: int) -> int:
        """The id of the run's newest actor message (0: none)."""
        with self.reading() as session:
            newest = session.scalar(select(func.max(ActorMessage.id)).where(ActorMessage.run_id == run_id))
        return int(newest or 0)

    def forget_actor_messages(self, *, run_id: int, claim: int, checkpointed_id: int) -> int:
        """A checkpoint of the run holds the actor's messages up to `checkpointed_id`: those before it are deleted
        (how many; none when the run's claim has moved on). The row `checkpointed_id` itself is kept: SQLite numbers
        a new row one past the highest left, so an emptied table would number the next message below the
        checkpoint's."""
        with self.writing() as session:
            if not self._claimed_by(session, run_id=run_id, claim=claim):
                return 0
            deleted = session.execute(
                delete(ActorMessage).where(ActorMessage.run_id == run_id, ActorMessage.id < checkpointed_id)
            )
        return int(deleted.rowcount or 0)


def _as_datetime(value: Any) -> datetime:
    """The database's now() as a datetime: SQLite's strftime text or PostgreSQL's timestamptz."""
    if isinstance(value, datetime):
        return value
    return datetime.fromisoformat(str(value)[:26]).replace(tzinfo=UTC)


def _age(now: datetime, moment: datetime | None) -> float | None:
    return None if moment is None else (now - moment).total_seconds()
