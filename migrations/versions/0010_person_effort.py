"""queries.shown_at: when a page was first served the question; scene_resets: each scene reset an actor asked a
person for, with when it asked and when the person pressed Ready (what a run cost the person)

Revision ID: 0010_person_effort
Revises: 0009_evaluation_and_actor_link
Create Date: 2026-12-04 10:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0010_person_effort"
down_revision: str | None = "0009_evaluation_and_actor_link"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("queries") as batch:
        batch.add_column(sa.Column("shown_at", sa.DateTime(timezone=True), nullable=True))
    op.create_table(
        "scene_resets",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("requested_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("ready_at", sa.DateTime(timezone=True), nullable=True),
        sa.ForeignKeyConstraint(["run_id"], ["runs.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index("ix_scene_resets_run_id", "scene_resets", ["run_id"])


def downgrade() -> None:
    op.drop_index("ix_scene_resets_run_id", table_name="scene_resets")
    op.drop_table("scene_resets")
    with op.batch_alter_table("queries") as batch:
        batch.drop_column("shown_at")
