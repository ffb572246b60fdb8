"""What a run records as it learns: named metrics by env step (written in one autocommitted statement; NaNs
left out), events (the run's log; run_id None for the whole tool) and rollout animations (the newest few kept per
run). A resume from an older checkpoint deletes the metrics recorded after it.
"""

import math
from collections.abc import Iterable

from sqlalchemy import delete, insert, select

from contract.store.base import StoreBase
from contract.store.models import (
    Event,
    Metric,
    Rollout,
    utcnow,
)


class MetricStore(StoreBase):
    """What a run records as it learns: metrics, events and rollout animations."""

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
        return self._column_of(Rollout.data, rollout_id, "rollout")

    def delete_metrics_after(self, *, run_id: int, step: int) -> int:
        """Delete the run's metrics recorded at steps after `step` (a resume from an older checkpoint
        records them again); returns how many were deleted."""
        with self.writing() as session:
            result = session.execute(delete(Metric).where(Metric.run_id == run_id, Metric.step > step))
            return int(result.rowcount or 0)
