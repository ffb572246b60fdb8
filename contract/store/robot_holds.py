"""Robot holds: at most one actor drives a robot, and only for the run's current claim and while no Stop is pending.

A robot is named by the lab, the same from every host and container (`robot_name`: its env id). The actor that
drives it takes its row (take_robot) before the first move, for the claim its learner holds the run with, and renews
the row while it holds the robot (renew_robot, from its control thread); before each move it checks that it still
holds it and that no Stop is pending for its run (may_move_robot), and arms the robot's env for a moment on that
answer alone. A learner that takes a run over increases the run's claim (Store.claim_next_run): from then on the old
actor's renewals and checks fail, and it sends nothing more. Another run of the same robot takes the row only once
it is released or HOLD_LAPSES_SECONDS old, so the old actor has stopped (its check allows a move only within
MOVE_WITHIN_SECONDS of its last renewal). While a robot's own process serves the robot (contract/store/
robot_processes.py), only that process takes, renews or moves it: one paused until another took the robot over finds
its hold gone when it continues, and lets go. Times are the database's clock, never a host's.
"""

import os
import socket
from dataclasses import dataclass

from sqlalchemy import ColumnElement, delete, exists, insert, or_, select, update
from sqlalchemy.exc import IntegrityError

from contract.store.base import StoreBase
from contract.store.models import RobotControl, RobotHold, RobotProcess, Run, RunStatus

CLAIMED_RUN_SECONDS = 60.0
"""A claimed run of an env whose learner beat within this many seconds is about to drive (or drives) its robot."""
HOLD_LAPSES_SECONDS = 3.0
"""A robot's hold not renewed for this long is free for another run's actor."""
MOVE_WITHIN_SECONDS = 1.0
"""An actor moves the robot only while its hold was renewed within this many seconds (well before the hold lapses)."""


def robot_name(env_id: str) -> str:
    """The robot an env id drives: the env id itself, whichever host asks (two arms of one kind are registered as
    two env ids)."""
    return env_id


def holder_name() -> str:
    """This process as a holder: "<pid>@<host>"."""
    return f"{os.getpid()}@{socket.gethostname()}"


@dataclass(frozen=True)
class RobotMove:
    """The answer to may_move_robot."""

    held: bool
    """The asker holds the robot for its run's current claim, renewed within MOVE_WITHIN_SECONDS."""
    stop_pending: bool
    """A person pressed Stop robot for the run that holds it, and nobody has pressed Resume since."""

    @property
    def allowed(self) -> bool:
        return self.held and not self.stop_pending


@dataclass(frozen=True)
class RobotTake:
    """The answer to take_robot."""

    taken: bool
    busy_with: int | None = None
    """The run whose actor holds the robot (None: taken, or the claim is stale)."""
    stale_claim: bool = False
    """The run has been claimed again since: this actor must never drive it."""


def not_served_by_another(robot: str, holder: str) -> ColumnElement[bool]:
    """No robot process other than `holder` serves `robot` (its row names another process)."""
    return ~exists().where(RobotProcess.robot == robot, RobotProcess.holder != holder)


class RobotHoldStore(StoreBase):
    def run_claim(self, *, run_id: int) -> int:
        """The run's current claim."""
        return int(self._column_of(Run.claim, run_id, "run"))

    def take_robot(self, *, robot: str, run_id: int, claim: int, holder: str) -> RobotTake:
        """Hold `robot` for the run at `claim`: when nobody holds it, `holder` does already, or the hold is
        HOLD_LAPSES_SECONDS old. Else the run that holds it."""
        with self.writing() as session:
            if session.scalar(select(Run.claim).where(Run.id == run_id)) != claim:
                return RobotTake(taken=False, stale_claim=True)
            values = {"run_id": run_id, "claim": claim, "holder": holder, "renewed_at": self._db_now()}
            taken = session.execute(
                update(RobotHold)
                .where(
                    RobotHold.robot == robot,
                    or_(RobotHold.holder == holder, RobotHold.renewed_at < self._db_now(HOLD_LAPSES_SECONDS)),
                    not_served_by_another(robot, holder),
                )
                .values(**values)
            ).rowcount
            if taken:
                return RobotTake(taken=True)
            busy_with = session.scalar(select(RobotHold.run_id).where(RobotHold.robot == robot))
            if busy_with is not None:
                return RobotTake(taken=False, busy_with=int(busy_with))
            if session.scalar(select(not_served_by_another(robot, holder))) is False:
                return RobotTake(taken=False)  # (another robot process serves it: this one is ending)
        try:
            with self.writing() as session:
                session.execute(insert(RobotHold).values(robot=robot, **values))
        except IntegrityError:  # (another actor made the row first: it holds the robot)
            return self.take_robot(robot=robot, run_id=run_id, claim=claim, holder=holder)
        return RobotTake(taken=True)

    def renew_robot(self, *, robot: str, holder: str) -> bool:
        """Renew the hold `holder` has on `robot`, while its claim is the run's current one. False: it holds the
        robot no longer (released, taken over, its run claimed again, or another robot process serves the robot)."""
        current = select(Run.claim).where(Run.id == RobotHold.run_id).scalar_subquery()
        with self.autocommitting() as session:
            renewed = session.execute(
                update(RobotHold)
                .where(
                    RobotHold.robot == robot, RobotHold.holder == holder, RobotHold.claim == current,
                    not_served_by_another(robot, holder),
                )
                .values(renewed_at=self._db_now())
            ).rowcount  # fmt: skip
        return bool(renewed)

    def may_move_robot(self, *, robot: str, holder: str) -> RobotMove:
        """Whether `holder` may move `robot` now, in one read: it holds it for the run's current claim, renewed
        within MOVE_WITHIN_SECONDS, and no Stop is pending for that run."""
        with self.reading() as session:
            row = session.execute(
                select(RobotControl.stop_requested)
                .select_from(RobotHold)
                .join(Run, Run.id == RobotHold.run_id)
                .outerjoin(RobotControl, RobotControl.run_id == RobotHold.run_id)
                .where(
                    RobotHold.robot == robot, RobotHold.holder == holder, RobotHold.claim == Run.claim,
                    RobotHold.renewed_at >= self._db_now(MOVE_WITHIN_SECONDS), not_served_by_another(robot, holder),
                )
            ).first()  # fmt: skip
        if row is None:
            return RobotMove(held=False, stop_pending=False)
        return RobotMove(held=True, stop_pending=bool(row[0]))

    def release_robot(self, *, robot: str, holder: str) -> None:
        """`holder` lets go of `robot` (nothing when it holds it no longer)."""
        with self.writing() as session:
            session.execute(delete(RobotHold).where(RobotHold.robot == robot, RobotHold.holder == holder))

    def robot_holder(self, *, robot: str) -> int | None:
        """The run whose actor holds `robot` now (renewed within HOLD_LAPSES_SECONDS), or None."""
        with self.reading() as session:
            run_id = session.scalar(
                select(RobotHold.run_id).where(
                    RobotHold.robot == robot, RobotHold.renewed_at >= self._db_now(HOLD_LAPSES_SECONDS)
                )
            )
        return None if run_id is None else int(run_id)

    def claimed_run_of(self, *, env_id: str) -> int | None:
        """The run of `env_id` that a live learner holds (starting or training, a heartbeat within
        CLAIMED_RUN_SECONDS), lowest id first: its actor drives the robot or is about to, so no other process may
        keep the robot's camera open. None when there is none."""
        with self.reading() as session:
            run_id = session.scalar(
                select(Run.id)
                .where(
                    Run.env_id == env_id, Run.status.in_(RunStatus.ACTIVE),
                    Run.heartbeat_at >= self._db_now(CLAIMED_RUN_SECONDS),
                )
                .order_by(Run.id)
                .limit(1)
            )  # fmt: skip
        return None if run_id is None else int(run_id)
