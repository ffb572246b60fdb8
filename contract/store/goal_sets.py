"""Goal sets: the photos of what success looks like, each kept three ways (the original upload, the model's
square view at the set's image_size, a larger display copy). The learner reads a set's model views with
`goal_images`; the server adds, lists and deletes sets and examples. Binary columns are deferred: the *_image
methods read them one at a time.
"""

from dataclasses import dataclass

from sqlalchemy import delete, func, select
from sqlalchemy.exc import IntegrityError

from contract.store.base import StoreBase, found
from contract.store.errors import Conflict, InvalidInput, NotFound
from contract.store.models import (
    GoalExample,
    GoalSet,
)


@dataclass(frozen=True)
class GoalImage:
    """A goal example's pixels at model resolution, as the learner reads them."""

    id: int
    model_png: bytes
    original: bytes


class GoalSetStore(StoreBase):
    """Goal sets and their example photos."""

    def create_goal_set(self, *, name: str, image_size: int = 48, env_id: str | None = None) -> GoalSet:
        """env_id: the task the photos show (None: any task)."""
        name = name.strip()
        if not name:
            raise InvalidInput("a goal set needs a name")
        if not 8 <= image_size <= 512:
            raise InvalidInput("image_size must be between 8 and 512")
        env_id = (env_id or "").strip() or None
        try:
            with self.writing() as session:
                goal_set = GoalSet(name=name, image_size=image_size, env_id=env_id)
                session.add(goal_set)
                session.flush()
                return goal_set
        except IntegrityError as error:
            raise Conflict(f"a goal set named {name!r} exists already") from error

    def list_goal_sets(self) -> list[tuple[GoalSet, int]]:
        """Goal sets with their example counts."""
        with self.reading() as session:
            counts = (
                select(GoalExample.goal_set_id, func.count().label("n")).group_by(GoalExample.goal_set_id).subquery()
            )
            rows = session.execute(
                select(GoalSet, func.coalesce(counts.c.n, 0))
                .outerjoin(counts, counts.c.goal_set_id == GoalSet.id)
                .order_by(GoalSet.id)
            ).all()
            return [(goal_set, int(count)) for goal_set, count in rows]

    def get_goal_set(self, *, goal_set_id: int) -> GoalSet:
        return self._get(GoalSet, goal_set_id, "goal set")

    def find_goal_set(self, *, name: str) -> GoalSet | None:
        with self.reading() as session:
            return session.scalars(select(GoalSet).where(GoalSet.name == name)).first()

    def delete_goal_set(self, *, goal_set_id: int) -> None:
        with self.writing() as session:
            session.delete(found(session.get(GoalSet, goal_set_id), f"goal set {goal_set_id}"))

    def add_goal_example(
        self,
        *,
        goal_set_id: int,
        filename: str,
        original: bytes,
        original_media_type: str,
        width: int,
        height: int,
        model_png: bytes,
        display_png: bytes,
        source: str = "upload",
    ) -> GoalExample:
        with self.writing() as session:
            found(session.get(GoalSet, goal_set_id), f"goal set {goal_set_id}")
            example = GoalExample(
                goal_set_id=goal_set_id,
                filename=filename[:255],
                source=source,
                original_media_type=original_media_type,
                width=width,
                height=height,
                original=original,
                model_png=model_png,
                display_png=display_png,
            )
            session.add(example)
            session.flush()
            return example

    def list_goal_examples(self, *, goal_set_id: int) -> list[GoalExample]:
        with self.reading() as session:
            return list(
                session.scalars(
                    select(GoalExample).where(GoalExample.goal_set_id == goal_set_id).order_by(GoalExample.id)
                )
            )

    def get_goal_example(self, *, example_id: int) -> GoalExample:
        return self._get(GoalExample, example_id, "goal example")

    def goal_example_image(self, *, example_id: int, kind: str) -> bytes:
        """kind: 'original', 'model' or 'display'."""
        column = {
            "original": GoalExample.original,
            "model": GoalExample.model_png,
            "display": GoalExample.display_png,
        }.get(kind)
        if column is None:
            raise InvalidInput("image kind must be original, model or display")
        return self._column_of(column, example_id, "goal example")

    def goal_images(self, *, goal_set_id: int) -> list[GoalImage]:
        with self.reading() as session:
            rows = session.execute(
                select(GoalExample.id, GoalExample.model_png, GoalExample.original)
                .where(GoalExample.goal_set_id == goal_set_id)
                .order_by(GoalExample.id)
            ).all()
            return [GoalImage(id=row[0], model_png=row[1], original=row[2]) for row in rows]

    def delete_goal_example(self, *, example_id: int) -> None:
        with self.writing() as session:
            deleted = session.execute(delete(GoalExample).where(GoalExample.id == example_id)).rowcount
            if not deleted:
                raise NotFound(f"goal example {example_id} not found")
