"""Robots: the controls between a person and the actor that drives a run's robot in real time. One row per run
(robot_controls, made on first use) holds the person's Stop robot / Resume, Ready (the scene is reset) and
Evaluate now (episodes with the policy's mean action), a take-over (the person's newest action while they drive the
arm by hand), and the actor's call for a reset, its state and its newest camera frame. The actor reports every
control period (report_actor) and gets the controls back in the same round trip; the pages read them with
robot_status and robot_runs. Times are the database's clock, never a host's.
"""

from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import select, update
from sqlalchemy.dialects.postgresql import insert as postgresql_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.orm import Session

from contract.store.base import StoreBase, found
from contract.store.errors import Conflict, InvalidInput
from contract.store.models import Event, RobotControl, Run, RunStatus, SceneReset, TakeoverSpan

ROBOT_SEEN_SECONDS = 30.0
"""robot_runs lists the active runs whose actor reported within this many seconds."""
ROBOT_LIVE_SECONDS = 2.0
"""An actor that reported within this many seconds is live (it reports every 0.05 s): a silent one shows within the
actor's default watchdog time (TrainConfig.watchdog_seconds)."""
ACTOR_STATE_MAX = 100
"""The longest actor state kept (a longer one is cut to this many characters)."""
FRAME_MAX_BYTES = 8 * 1024 * 1024
"""The largest camera frame the store keeps (a PNG; the actor sends its newest one with each report)."""
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EVALUATION_EPISODES_MAX = 20
"""The most episodes one Evaluate now asks for."""
TAKEOVER_GAP_SECONDS = 1.0
"""A person's action within this many seconds of their previous one continues the same take-over (its time counts
whole); a later one begins another."""


@dataclass(frozen=True)
class RobotStatus:
    """A run's robot controls and what its actor last said."""

    run_id: int
    stop_requested: bool
    reset_needed: bool
    reset_count: int
    actor_state: str | None
    actor_seen_at: datetime | None
    frame_at: datetime | None
    evaluation_pending: int
    """Episodes of Evaluate now that the actor has not begun."""
    evaluation_round: int
    """How many times Evaluate now was pressed (the round of the newest request)."""
    takeover_action: list[float] | None
    """The person's newest action while they drive the arm by hand (None: the policy drives)."""
    takeover_seq: int
    """How many actions the person has sent: a new one is fresh for one control period from when the actor saw it."""
    actor_spaces: dict[str, Any] | None
    """The actor's action bounds, observation shape and control rate, as it announced them."""
    success_marks: int
    """How many times a person pressed the success key (the episode's last frames are a success)."""
    demo_pending: int
    """Episodes of Record demos not begun yet: each is driven by hand, the policy idle."""


_STATUS_COLUMNS = (
    RobotControl.run_id,
    RobotControl.stop_requested,
    RobotControl.reset_needed,
    RobotControl.reset_count,
    RobotControl.actor_state,
    RobotControl.actor_seen_at,
    RobotControl.frame_at,
    RobotControl.evaluation_pending,
    RobotControl.evaluation_round,
    RobotControl.takeover_action,
    RobotControl.takeover_seq,
    RobotControl.actor_spaces,
    RobotControl.success_marks,
    RobotControl.demo_pending,
)


def _status(row: Any) -> RobotStatus:
    (
        run_id, stop_requested, reset_needed, reset_count, actor_state, actor_seen_at, frame_at, pending, round_,
        takeover_action, takeover_seq, actor_spaces, success_marks, demo_pending,
    ) = row  # fmt: skip
    return RobotStatus(
        run_id=run_id, stop_requested=bool(stop_requested), reset_needed=bool(reset_needed),
        reset_count=int(reset_count), actor_state=actor_state, actor_seen_at=actor_seen_at, frame_at=frame_at,
        evaluation_pending=int(pending), evaluation_round=int(round_), takeover_action=takeover_action,
        takeover_seq=int(takeover_seq or 0), actor_spaces=actor_spaces, success_marks=int(success_marks or 0),
        demo_pending=int(demo_pending or 0),
    )  # fmt: skip


def _no_controls(run_id: int) -> RobotStatus:
    """A run whose robot nobody has touched yet: not stopped, no reset waiting, no actor seen."""
    return RobotStatus(
        run_id=run_id, stop_requested=False, reset_needed=False, reset_count=0, actor_state=None,
        actor_seen_at=None, frame_at=None, evaluation_pending=0, evaluation_round=0, takeover_action=None,
        takeover_seq=0, actor_spaces=None, success_marks=0, demo_pending=0,
    )  # fmt: skip


def _checked_state(state: str) -> str:
    if not isinstance(state, str):
        raise InvalidInput(f"the actor's state must be text, not {type(state).__name__}")
    if "\x00" in state or any("\ud800" <= char <= "\udfff" for char in state):
        raise InvalidInput("the actor's state must be valid Unicode text without NUL characters or lone surrogates")
    return state[:ACTOR_STATE_MAX]


def _checked_frame(frame_png: bytes | None) -> bytes | None:
    if frame_png is None:
        return None
    if not isinstance(frame_png, bytes | bytearray | memoryview):
        raise InvalidInput(f"a camera frame must be PNG bytes, not {type(frame_png).__name__}")
    frame = bytes(frame_png)
    if not frame.startswith(PNG_SIGNATURE):
        raise InvalidInput("a camera frame must be a PNG image (it does not start with the PNG signature)")
    if len(frame) > FRAME_MAX_BYTES:
        raise InvalidInput(f"a camera frame of {len(frame):,} bytes is larger than {FRAME_MAX_BYTES:,} bytes")
    return frame


def _checked_action(action: list[float], dims: int) -> None:
    if not isinstance(action, list | tuple) or len(action) != dims:
        raise InvalidInput(f"a take-over's action has {dims} numbers, one per action dimension")
    for value in action:
        if isinstance(value, bool) or not isinstance(value, int | float) or not -1.0 <= float(value) <= 1.0:
            raise InvalidInput(f"a take-over's action holds numbers in [-1, 1], not {value!r}")


class RobotStore(StoreBase):
    """The robot controls of runs whose learner drives a robot in real time through an actor."""

    def robot_status(self, *, run_id: int) -> RobotStatus:
        """The run's robot controls (the defaults while nobody has touched them); NotFound for an unknown run."""
        with self.reading() as session:
            row = session.execute(select(*_STATUS_COLUMNS).where(RobotControl.run_id == run_id)).one_or_none()
            if row is not None:
                return _status(row)
            found(session.scalar(select(Run.id).where(Run.id == run_id)), f"run {run_id}")
            return _no_controls(run_id)

    def request_robot_stop(self, *, run_id: int) -> RobotStatus:
        """A person's Stop robot: the actor holds the arm still from its next report until Resume. Pressing it
        again changes nothing."""
        return self._switch_stop(run_id=run_id, stop=True)

    def resume_robot(self, *, run_id: int) -> RobotStatus:
        """A person's Resume after Stop robot: the actor may move the arm again. Without a stop it changes nothing."""
        return self._switch_stop(run_id=run_id, stop=False)

    def request_scene_reset(self, *, run_id: int) -> RobotStatus:
        """The actor's call: a person must reset the scene now (the actor waits until scene_ready). The reset is
        recorded with when it was asked for (once while one waits)."""
        with self.writing() as session:
            status = self._update_or_create(session, run_id=run_id, values={"reset_needed": True})
            waiting = session.scalar(
                select(SceneReset.id).where(SceneReset.run_id == run_id, SceneReset.ready_at.is_(None)).limit(1)
            )
            if waiting is None:
                session.add(SceneReset(run_id=run_id, requested_at=self._db_now()))
            return status

    def scene_ready(self, *, run_id: int) -> RobotStatus:
        """A person's Ready: the scene is reset, the actor may start its episode (reset_count counts these).
        Conflict when no reset is waiting (nothing changes then)."""
        with self.writing() as session:
            status = self._update(
                session, run_id=run_id, values={"reset_needed": False, "reset_count": RobotControl.reset_count + 1},
                condition=RobotControl.reset_needed.is_(True),
            )  # fmt: skip
            if status is None:
                self._controls_row(session, run_id=run_id, create=False)  # NotFound for an unknown run
                raise Conflict("no reset is waiting")
            session.execute(
                update(SceneReset)
                .where(SceneReset.run_id == run_id, SceneReset.ready_at.is_(None))
                .values(ready_at=self._db_now())
            )
            return status

    def scene_reset_times(self, *, run_id: int) -> list[tuple[datetime, datetime | None]]:
        """(requested_at, ready_at) of each scene reset the run's actor asked for, oldest first (ready_at None:
        still waiting)."""
        with self.reading() as session:
            rows = session.execute(
                select(SceneReset.requested_at, SceneReset.ready_at)
                .where(SceneReset.run_id == run_id)
                .order_by(SceneReset.id)
            ).all()
        return [(requested_at, ready_at) for requested_at, ready_at in rows]

    def request_evaluation(self, *, run_id: int, episodes: int) -> RobotStatus:
        """A person's Evaluate now: the actor runs the next `episodes` episodes with the policy's mean action, as
        round evaluation_round + 1; an event says so. InvalidInput unless 1 <= episodes <= EVALUATION_EPISODES_MAX;
        Conflict while an earlier request still has episodes pending, or before an actor has reported (a run in
        lockstep has none); nothing changes then."""
        if isinstance(episodes, bool) or not isinstance(episodes, int) or not 1 <= episodes <= EVALUATION_EPISODES_MAX:
            raise InvalidInput(f"episodes must be a whole number from 1 to {EVALUATION_EPISODES_MAX}, not {episodes!r}")
        values = {"evaluation_pending": episodes, "evaluation_round": RobotControl.evaluation_round + 1}
        with self.writing() as session:
            idle = (RobotControl.evaluation_pending <= 0) & RobotControl.actor_seen_at.is_not(None)
            status = self._update(session, run_id=run_id, values=values, condition=idle)
            if status is None:  # no actor yet (no row, or a row a person made), or one pending still
                current = self._controls_row(session, run_id=run_id, create=False)  # (NotFound for an unknown run)
                if current.actor_seen_at is None:
                    raise Conflict("no actor drives this run's robot: Evaluate now is for runs in real time")
                raise Conflict(
                    f"an evaluation is under way: {current.evaluation_pending} episodes of round "
                    f"{current.evaluation_round} not begun yet"
                )
            count = f"{episodes} episode" + ("s" if episodes > 1 else "")
            message = f"evaluate now: round {status.evaluation_round}, {count} with the policy's mean action"
            session.add(Event(run_id=run_id, message=message))
            return status

    def take_evaluation_episode(self, *, run_id: int) -> int | None:
        """The actor, as an episode begins: one episode of Evaluate now taken (evaluation_pending - 1, in one
        statement, so that no episode is taken twice) and its round; None when none is pending."""
        with self.writing() as session:
            status = self._update(
                session, run_id=run_id, values={"evaluation_pending": RobotControl.evaluation_pending - 1},
                condition=RobotControl.evaluation_pending > 0,
            )  # fmt: skip
        return None if status is None else status.evaluation_round

    def mark_success(self, *, run_id: int) -> RobotStatus:
        """The person's success key: the robot's episode under way (or just ended) ends in a success, so its last
        frames join f_psi's positives; in a demo episode it also ends the episode. An event says so. Conflict before
        an actor has reported."""
        with self.writing() as session:
            status = self._update(
                session, run_id=run_id, values={"success_marks": RobotControl.success_marks + 1},
                condition=RobotControl.actor_seen_at.is_not(None),
            )  # fmt: skip
            if status is None:
                self._controls_row(session, run_id=run_id, create=False)  # (NotFound for an unknown run)
                raise Conflict("no actor drives this run's robot: nothing to mark a success")
            session.add(Event(run_id=run_id, message="a person marked the robot's episode a success"))
            return status

    def request_demos(self, *, run_id: int, episodes: int) -> RobotStatus:
        """Record demos: the actor's next `episodes` episodes are driven by hand (the robot waits for the person's
        keys, the policy idle); an event says so. InvalidInput unless 1 <= episodes <= EVALUATION_EPISODES_MAX;
        Conflict while earlier demos are pending or before an actor has reported."""
        if isinstance(episodes, bool) or not isinstance(episodes, int) or not 1 <= episodes <= EVALUATION_EPISODES_MAX:
            raise InvalidInput(f"episodes must be a whole number from 1 to {EVALUATION_EPISODES_MAX}, not {episodes!r}")
        with self.writing() as session:
            idle = (RobotControl.demo_pending <= 0) & RobotControl.actor_seen_at.is_not(None)
            status = self._update(session, run_id=run_id, values={"demo_pending": episodes}, condition=idle)
            if status is None:
                current = self._controls_row(session, run_id=run_id, create=False)  # (NotFound for an unknown run)
                if current.actor_seen_at is None:
                    raise Conflict("no actor drives this run's robot: demos are for runs in real time")
                raise Conflict(f"demos are under way: {current.demo_pending} episodes not begun yet")
            count = f"{episodes} episode" + ("s" if episodes > 1 else "")
            session.add(Event(run_id=run_id, message=f"record demos: {count} to drive by hand"))
            return status

    def take_demo_episode(self, *, run_id: int) -> bool:
        """The actor, as an episode begins: one episode of Record demos taken (demo_pending - 1, in one statement);
        False when none is pending."""
        with self.writing() as session:
            status = self._update(
                session, run_id=run_id, values={"demo_pending": RobotControl.demo_pending - 1},
                condition=RobotControl.demo_pending > 0,
            )  # fmt: skip
        return status is not None

    def drive_robot(self, *, run_id: int, action: list[float]) -> RobotStatus:
        """A person's action for the run's robot (a take-over: the page sends one every half control period while a
        key is held). The actor sends it instead of the policy's, through the same pace, limits, hold and Stop,
        while it is fresh. Conflict while Stop robot is pending (a Stop ends a take-over) or before an actor has
        announced its action space; InvalidInput for an action of the wrong length or outside [-1, 1] (nothing is
        stored then)."""
        with self.writing() as session:
            current = self._controls_row(session, run_id=run_id, create=False)
            if current.stop_requested:
                raise Conflict(f"run {run_id}'s robot is stopped: press Resume before taking over")
            if current.actor_spaces is None:
                raise Conflict(f"run {run_id} has no actor yet: its robot cannot be driven by hand")
            dims = len(current.actor_spaces["action"]["low"])
            _checked_action(action, dims)
            status = self._update(
                session, run_id=run_id,
                values={"takeover_action": [float(value) for value in action],
                        "takeover_seq": RobotControl.takeover_seq + 1},
                condition=RobotControl.stop_requested.is_(False),
            )  # fmt: skip
            if status is None:  # (stopped meanwhile)
                raise Conflict(f"run {run_id}'s robot is stopped: press Resume before taking over")
            self._extend_takeover(session, run_id=run_id)
            return status

    def hand_back_robot(self, *, run_id: int) -> RobotStatus:
        """The person let go of the keys: the policy drives again from the actor's next step. Without a take-over
        it changes nothing."""
        with self.writing() as session:
            self._controls_row(session, run_id=run_id, create=False)
            status = self._update(session, run_id=run_id, values={"takeover_action": None})
            return status if status is not None else _no_controls(run_id)

    def takeover_times(self, *, run_id: int) -> list[tuple[datetime, datetime]]:
        """(first action, last action) of each take-over of the run, oldest first."""
        with self.reading() as session:
            rows = session.execute(
                select(TakeoverSpan.started_at, TakeoverSpan.last_at)
                .where(TakeoverSpan.run_id == run_id)
                .order_by(TakeoverSpan.id)
            ).all()
        return [(started, last) for started, last in rows]

    def _extend_takeover(self, session: Session, *, run_id: int) -> None:
        """The newest take-over goes on to now, or a new one begins (its previous action was long ago)."""
        extended = session.execute(
            update(TakeoverSpan)
            .where(
                TakeoverSpan.run_id == run_id,
                TakeoverSpan.id == select(TakeoverSpan.id).where(TakeoverSpan.run_id == run_id)
                .order_by(TakeoverSpan.id.desc()).limit(1).scalar_subquery(),
                TakeoverSpan.last_at >= self._db_now(minus_seconds=TAKEOVER_GAP_SECONDS),
            )
            .values(last_at=self._db_now())
        ).rowcount  # fmt: skip
        if not extended:
            session.add(TakeoverSpan(run_id=run_id, started_at=self._db_now(), last_at=self._db_now()))

    def report_actor(self, *, run_id: int, state: str, frame_png: bytes | None = None) -> RobotStatus:
        """The actor, every control period: its state (cut to ACTOR_STATE_MAX characters) and, optionally, its
        newest camera frame (PNG). Stamps actor_seen_at (and frame_at with a frame) and returns the controls in
        the same round trip. InvalidInput for a frame that is not a PNG (nothing is stored then)."""
        values: dict[str, Any] = {"actor_state": _checked_state(state), "actor_seen_at": self._db_now()}
        frame = _checked_frame(frame_png)
        if frame is not None:
            values.update(frame_png=frame, frame_at=self._db_now())
        with self.writing() as session:
            return self._update_or_create(session, run_id=run_id, values=values)

    def camera_frame(self, *, run_id: int) -> tuple[bytes, datetime] | None:
        """The newest camera frame the actor sent (PNG) and when, or None before the first; NotFound for an
        unknown run."""
        with self.reading() as session:
            row = session.execute(
                select(RobotControl.frame_png, RobotControl.frame_at).where(RobotControl.run_id == run_id)
            ).one_or_none()
            if row is None:
                found(session.scalar(select(Run.id).where(Run.id == run_id)), f"run {run_id}")
                return None
        frame, frame_at = row
        if frame is None or frame_at is None:
            return None
        return bytes(frame), frame_at

    def robot_runs(self) -> list[RobotStatus]:
        """The active runs (starting, training) whose actor reported within ROBOT_SEEN_SECONDS, by run id."""
        with self.reading() as session:
            rows = session.execute(
                select(*_STATUS_COLUMNS)
                .join(Run, Run.id == RobotControl.run_id)
                .where(
                    Run.status.in_(RunStatus.ACTIVE),
                    RobotControl.actor_seen_at >= self._db_now(minus_seconds=ROBOT_SEEN_SECONDS),
                )
                .order_by(RobotControl.run_id)
            ).all()
        return [_status(row) for row in rows]

    # ---------------------------------------------------------------- helpers
    def _switch_stop(self, *, run_id: int, stop: bool) -> RobotStatus:
        """Set stop_requested to `stop` (a Stop ends a take-over too); an event says so when it changed."""
        values: dict[str, Any] = {"stop_requested": stop, **({"takeover_action": None} if stop else {})}
        with self.writing() as session:
            status = self._update(
                session, run_id=run_id, values=values, condition=RobotControl.stop_requested.is_(not stop)
            )
            if status is None:  # already so, or no row yet
                current = self._controls_row(session, run_id=run_id, create=False)
                if current.stop_requested == stop:
                    return current
                status = self._update_or_create(session, run_id=run_id, values=values)
            message = "robot stop requested: the arm holds still" if stop else "robot resumed"
            session.add(Event(run_id=run_id, level="warning" if stop else "info", message=message))
            return status

    def _update(
        self, session: Session, *, run_id: int, values: dict[str, Any], condition: Any = None
    ) -> RobotStatus | None:
        """UPDATE the run's controls row (where `condition` holds): its RobotStatus, or None when no row matched."""
        statement = update(RobotControl).where(RobotControl.run_id == run_id)
        if condition is not None:
            statement = statement.where(condition)
        row = session.execute(
            statement.values(updated_at=self._db_now(), **values).returning(*_STATUS_COLUMNS)
        ).one_or_none()
        return None if row is None else _status(row)

    def _update_or_create(self, session: Session, *, run_id: int, values: dict[str, Any]) -> RobotStatus:
        """_update, the row made first when missing (NotFound for an unknown run): one statement once it exists."""
        status = self._update(session, run_id=run_id, values=values)
        if status is None:
            self._controls_row(session, run_id=run_id, create=True)
            status = self._update(session, run_id=run_id, values=values)
            assert status is not None  # the row exists now, under this transaction
        return status

    def _controls_row(self, session: Session, *, run_id: int, create: bool) -> RobotStatus:
        """The run's controls as stored (made with their defaults first when `create` and missing; the defaults
        when not); NotFound for an unknown run. The run is share-locked on PostgreSQL until the commit, so that it
        cannot be deleted between this check and the row's insert."""
        row = session.execute(select(*_STATUS_COLUMNS).where(RobotControl.run_id == run_id)).one_or_none()
        if row is not None:
            return _status(row)
        found(session.scalar(select(Run.id).where(Run.id == run_id).with_for_update(read=True)), f"run {run_id}")
        if not create:
            return _no_controls(run_id)
        make = sqlite_insert if self.engine.dialect.name == "sqlite" else postgresql_insert
        session.execute(
            make(RobotControl)
            .values(run_id=run_id, updated_at=self._db_now())
            .on_conflict_do_nothing(index_elements=[RobotControl.run_id])
        )
        row = session.execute(select(*_STATUS_COLUMNS).where(RobotControl.run_id == run_id)).one()
        return _status(row)
