"""runs.claim: how many times a learner claimed the run; robot_holds: which run's actor drives each robot

Revision ID: 0011_robot_holds
Revises: 0010_person_effort
Create Date: 2026-12-05 12:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0011_robot_holds"
down_revision: str | None = "0010_person_effort"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


# Plain ALTER TABLE on runs, never a batch copy: on SQLite that drops runs and cascades to every answer.


def upgrade() -> None:
    op.add_column("runs", sa.Column("claim", sa.Integer(), nullable=False, server_default="0"))
    op.create_table(
        "robot_holds",
        sa.Column("robot", sa.String(length=300), nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("claim", sa.Integer(), nullable=False),
        sa.Column("holder", sa.String(length=300), nullable=False),
        sa.Column("renewed_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["run_id"], ["runs.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("robot"),
    )


def downgrade() -> None:
    op.drop_table("robot_holds")
    op.drop_column("runs", "claim")
