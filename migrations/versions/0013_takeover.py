"""takeover: a person's newest action for the run's robot, and the stretches of time they drove it

Revision ID: 0013_takeover
Revises: 0012_robot_processes
Create Date: 2026-12-07 02:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0013_takeover"
down_revision: str | None = "0012_robot_processes"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("robot_controls") as batch:
        batch.add_column(sa.Column("takeover_action", sa.JSON(), nullable=True))
        batch.add_column(sa.Column("takeover_seq", sa.BigInteger(), server_default="0", nullable=False))
    op.create_table(
        "takeover_spans",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("started_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("last_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["run_id"], ["runs.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index("ix_takeover_spans_run_id", "takeover_spans", ["run_id"])


def downgrade() -> None:
    op.drop_index("ix_takeover_spans_run_id", table_name="takeover_spans")
    op.drop_table("takeover_spans")
    with op.batch_alter_table("robot_controls") as batch:
        batch.drop_column("takeover_seq")
        batch.drop_column("takeover_action")
