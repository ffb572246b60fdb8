"""Runs: a run's life from queued to finished. The server creates, lists, changes (priority, archive), stops,
resumes, continues and deletes runs and reports why queued ones wait; learners claim the next run (by priority, then
age), beat on it and set its status. Staleness is judged by the database's clock, never a host's. Changes that
depend on the status they saw go through base.compare_and_set, retried by base.retry_lost_races.
"""

from datetime import timedelta
from typing import Any

from sqlalchemy import delete, func, or_, select, update

from contract.config import cuda_devices_needed, device_need
from contract.store.base import StoreBase, compare_and_set, found, retry_lost_races
from contract.store.errors import Conflict, InvalidInput, NotFound
from contract.store.models import (
    COLUMN_CONFIG_FIELDS,
    Event,
    GoalSet,
    Metric,
    Query,
    Rollout,
    Run,
    RunPhase,
    RunStatus,
    utcnow,
)

# The order learners take queued runs in: highest priority first, then the oldest.
_CLAIM_ORDER = (Run.priority.desc(), Run.id)
# How many claimable runs a learner looks through, in that order, for one it can execute (and is not raced to).
_CLAIM_CANDIDATES = 50


def _device_of(config: dict[str, Any] | None) -> str:
    """The torch device a run's stored config names ("cpu" when it names none)."""
    device = (config or {}).get("device", "cpu")
    return device if isinstance(device, str) else "cpu"


class RunStore(StoreBase):
    """Runs: their life cycle from queued to finished, the learners' claims and heartbeats."""

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
            if goal_set_id is not None:
                found(session.get(GoalSet, goal_set_id), f"goal set {goal_set_id}")
            run = Run(
                name=name,
                env_id=env_id,
                algorithm=algorithm,
                config={key: value for key, value in config.items() if key not in COLUMN_CONFIG_FIELDS},
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
        return self._get(Run, run_id, "run")

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
            run = found(session.get(Run, run_id), f"run {run_id}")
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
            devices = dict(
                session.execute(
                    select(Run.id, Run.config)
                    .where(Run.status == RunStatus.QUEUED, Run.archived.is_(False))
                    .order_by(*_CLAIM_ORDER)
                ).all()
            )
            queued = list(devices)  # in the claim order (dicts keep it)
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
            need = device_need(_device_of(devices.get(run_id)))
            if need:  # learners without the GPU skip it (claim_next_run)
                text = f"waiting for {need}: learners without one skip it"
                if busy:
                    text += " (busy: " + ", ".join(f"#{other}" for other in busy) + ")"
            elif busy:
                text = "learner busy with " + ", ".join(f"#{other}" for other in busy)
            else:
                text = "waiting for a learner (none is running: start one with raq learn or raq up)"
            ahead = queued[:position]
            if ahead:
                text += "; after " + ", ".join(f"#{other}" for other in ahead[:5]) + (" …" if len(ahead) > 5 else "")
            reasons[run_id] = text
        return reasons

    def higher_priority_waiting(
        self, *, run_id: int, waited_seconds: float = 10.0, cuda_devices: int = 0
    ) -> Run | None:
        """A queued run of higher priority than `run_id` that has waited at least `waited_seconds` (an idle
        learner, polling every 2 s, would have taken it by then) and that a learner with `cuda_devices` GPUs can
        execute (it would not take another after yielding), or None."""
        with self.reading() as session:
            priority = session.scalar(select(Run.priority).where(Run.id == run_id))
            if priority is None:
                return None
            waiting = session.scalars(
                select(Run)
                .where(
                    Run.status == RunStatus.QUEUED,
                    Run.archived.is_(False),
                    Run.priority > priority,
                    Run.queued_at <= utcnow() - timedelta(seconds=waited_seconds),
                )
                .order_by(*_CLAIM_ORDER)
                .limit(_CLAIM_CANDIDATES)
            ).all()
            return next((run for run in waiting if cuda_devices_needed(_device_of(run.config)) <= cuda_devices), None)

    def count_runs(self) -> int:
        with self.reading() as session:
            return int(session.scalar(select(func.count()).select_from(Run)) or 0)

    def claim_next_run(self, *, worker: str, stale_after_seconds: float = 60.0, cuda_devices: int = 0) -> Run | None:
        """Atomically take the oldest queued run, or an active run whose learner stopped beating, of those the
        learner can execute: a run whose device is "cuda:N" only when the learner has at least N + 1 CUDA GPUs
        (`cuda_devices`); the others wait for such a learner (queue_report says so).

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
                select(Run.id, Run.status, Run.heartbeat_at, Run.config)
                .where(claimable)
                .order_by(*_CLAIM_ORDER)
                .limit(_CLAIM_CANDIDATES)
            ).all()
            for run_id, status, heartbeat_at, config in candidates:
                if cuda_devices_needed(_device_of(config)) > cuda_devices:
                    continue  # a learner with the GPU it names takes it
                now = self._db_now()
                claimed = session.execute(
                    update(Run)
                    .where(Run.id == run_id, Run.status == status, Run.heartbeat_at.is_not_distinct_from(heartbeat_at))
                    .values(
                        status=RunStatus.STARTING,
                        status_reason="",
                        phase=RunPhase.SETTING_UP,
                        worker=worker,
                        claim=Run.claim + 1,
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
        return RunStore._queued_again(), "resume requested: queued"

    @staticmethod
    def _queued_again() -> dict[str, Any]:
        return {
            "status": RunStatus.QUEUED, "status_reason": "", "stop_requested": False, "finished_at": None,
            "queued_at": utcnow(), "archived": False,
        }  # fmt: skip

    def _change_run(self, *, run_id: int, change: Any) -> Run:
        """Apply change(run) -> (values, event message) as a compare-and-set on the status it saw."""

        def attempt() -> Run:
            with self.writing() as session:
                run = found(session.get(Run, run_id, populate_existing=True), f"run {run_id}")
                values, message = change(run)
                if not values:
                    return run
                # LostRace when its learner changed the status meanwhile: look again
                compare_and_set(session, run, Run.status == run.status, **values)
                session.add(Event(run_id=run_id, message=message))
                session.flush()
                session.refresh(run)
                return run

        return retry_lost_races(attempt, conflict=f"run {run_id} kept changing; try again")
