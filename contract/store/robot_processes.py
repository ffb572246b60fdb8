"""Robot processes: the one process per robot (`raq robot ENV`, or `raq actor --run ID` for one run) that opens the
robot's camera and moves its arm. Its row is the robot's, one per robot whatever the host: a second process for a
robot whose row another stamped within ROBOT_PROCESS_LIVE_SECONDS is refused (RobotServed, naming that one). It stamps
its row (report_robot_process) every ROBOT_REPORT_SECONDS with its
state and, when it has one, a new camera frame; a page that asks for the camera's frame marks the robot watched
(watch_robot), and the process then publishes a frame every FRAME_WATCHED_SECONDS instead of every
FRAME_IDLE_SECONDS. The web server reads frames from here (robot_process_of, robot_process_frame) and never opens
a camera itself. Times and ages are the database's clock, never a host's.
"""

from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import delete, insert, or_, select, update

from contract.store.actor_link import LEARNER_LIVE_SECONDS, _age, _as_datetime
from contract.store.base import StoreBase
from contract.store.errors import Conflict
from contract.store.models import RobotControl, RobotProcess, Run, RunStatus
from contract.store.robots import _checked_frame, _checked_state

ROBOT_REPORT_SECONDS = 1.0
"""How often a robot process stamps its row."""
ROBOT_PROCESS_LIVE_SECONDS = 5.0
"""A robot process that stamped its row within this many seconds is up."""
WATCHED_SECONDS = 5.0
"""A robot whose frame a page asked for within this many seconds is watched."""
FRAME_WATCHED_SECONDS = 0.2
"""How often a robot process publishes a frame while a page watches."""
FRAME_IDLE_SECONDS = 2.0
"""How often it publishes one otherwise (so that the first request has a recent frame)."""


class RobotServed(Conflict):
    """Another live process serves the robot: this one must neither open its camera for the pages nor move it."""


@dataclass(frozen=True)
class RobotProcessStatus:
    """A robot process as the pages and the learners see it."""

    robot: str
    env_id: str
    holder: str
    state: str
    age_seconds: float
    """Seconds since its last stamp."""
    frame_age_seconds: float | None
    """Seconds since its newest frame (None: none yet)."""
    watched: bool
    """A page asked for a frame within WATCHED_SECONDS."""


class RobotProcessStore(StoreBase):
    def report_robot_process(
        self, *, robot: str, env_id: str, holder: str, state: str, frame_png: bytes | None = None
    ) -> RobotProcessStatus:
        """The robot process is up: its state and, optionally, its newest camera frame (PNG). The row is the
        robot's: a process takes it when it is its own, missing, or not stamped within ROBOT_PROCESS_LIVE_SECONDS;
        RobotServed when another process stamped it within that time. InvalidInput for a frame that is not a PNG."""
        values: dict[str, Any] = {"env_id": env_id, "holder": holder, "state": _checked_state(state),
                                  "seen_at": self._db_now()}  # fmt: skip
        frame = _checked_frame(frame_png)
        if frame is not None:
            values.update(frame_png=frame, frame_at=self._db_now())
        with self.writing() as session:
            ours_or_stale = or_(
                RobotProcess.holder == holder, RobotProcess.seen_at < self._db_now(ROBOT_PROCESS_LIVE_SECONDS)
            )
            taken = session.execute(
                update(RobotProcess).where(RobotProcess.robot == robot, ours_or_stale).values(**values)
            ).rowcount
            if not taken:
                serving = session.scalar(select(RobotProcess.holder).where(RobotProcess.robot == robot))
                if serving is not None:
                    raise RobotServed(
                        f"robot {robot} is served by process {serving}: one process per robot (stop that one first)"
                    )
                session.execute(insert(RobotProcess).values(robot=robot, **values))
        status = self._robot_process(robot=robot)
        assert status is not None
        return status

    def envs_awaiting_robot(self) -> list[str]:
        """The env ids of active runs whose learner has the link open while no actor reports for them and no robot
        process of that env is up: the robots whose own process somebody must start (`raq up` does, on its host)."""
        served = select(RobotProcess.env_id).where(RobotProcess.seen_at >= self._db_now(ROBOT_PROCESS_LIVE_SECONDS))
        query = (
            select(Run.env_id)
            .distinct()
            .join(RobotControl, RobotControl.run_id == Run.id)
            .where(
                Run.status.in_(RunStatus.ACTIVE), RobotControl.learner_closed.is_(False),
                RobotControl.learner_seen_at >= self._db_now(LEARNER_LIVE_SECONDS),
                RobotControl.actor_seen_at.is_(None)
                | (RobotControl.actor_seen_at < self._db_now(ROBOT_PROCESS_LIVE_SECONDS)),
                Run.env_id.not_in(served),
            )
            .order_by(Run.env_id)
        )  # fmt: skip
        with self.reading() as session:
            return list(session.scalars(query))

    def robot_process_ended(self, *, robot: str, holder: str) -> None:
        """The robot process exits: its row goes (when it is still that process's)."""
        with self.writing() as session:
            session.execute(delete(RobotProcess).where(RobotProcess.robot == robot, RobotProcess.holder == holder))

    def robot_process_of(self, *, env_id: str) -> RobotProcessStatus | None:
        """The live robot process of `env_id` (stamped within ROBOT_PROCESS_LIVE_SECONDS; the newest if several
        hosts have one), or None."""
        with self.reading() as session:
            robot = session.scalar(
                select(RobotProcess.robot)
                .where(RobotProcess.env_id == env_id,
                       RobotProcess.seen_at >= self._db_now(ROBOT_PROCESS_LIVE_SECONDS))
                .order_by(RobotProcess.seen_at.desc())
                .limit(1)
            )  # fmt: skip
        return None if robot is None else self._robot_process(robot=robot)

    def robot_processes(self) -> list[RobotProcessStatus]:
        """Every robot process's row, live or not, by robot."""
        with self.reading() as session:
            robots = session.scalars(select(RobotProcess.robot).order_by(RobotProcess.robot)).all()
        return [status for robot in robots if (status := self._robot_process(robot=robot)) is not None]

    def watch_robot(self, *, robot: str) -> None:
        """A page asks for the robot's frames: the process publishes them often for WATCHED_SECONDS."""
        with self.writing() as session:
            session.execute(update(RobotProcess).where(RobotProcess.robot == robot).values(watched_at=self._db_now()))

    def robot_process_frame(self, *, robot: str) -> tuple[bytes, datetime] | None:
        """The robot process's newest camera frame (PNG) and when, or None before its first."""
        with self.reading() as session:
            row = session.execute(
                select(RobotProcess.frame_png, RobotProcess.frame_at).where(RobotProcess.robot == robot)
            ).one_or_none()
        if row is None or row[0] is None or row[1] is None:
            return None
        return bytes(row[0]), row[1]

    def _robot_process(self, *, robot: str) -> RobotProcessStatus | None:
        with self.reading() as session:
            row = session.execute(
                select(
                    RobotProcess.robot, RobotProcess.env_id, RobotProcess.holder, RobotProcess.state,
                    RobotProcess.seen_at, RobotProcess.frame_at, RobotProcess.watched_at, self._db_now(),
                ).where(RobotProcess.robot == robot)
            ).one_or_none()  # fmt: skip
        if row is None:
            return None
        robot, env_id, holder, state, seen_at, frame_at, watched_at, db_now = row
        db_now = _as_datetime(db_now)
        watched_age = _age(db_now, watched_at)
        return RobotProcessStatus(
            robot=robot, env_id=env_id, holder=holder, state=state, age_seconds=_age(db_now, seen_at) or 0.0,
            frame_age_seconds=_age(db_now, frame_at),
            watched=watched_age is not None and watched_age < WATCHED_SECONDS,
        )  # fmt: skip
