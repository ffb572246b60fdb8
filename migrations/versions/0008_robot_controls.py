"""robot_controls: a person's Stop robot / Resume and Ready for the actor that drives a run's robot in real time,
and the actor's call for a scene reset, its state and its newest camera frame (one row per run)

Revision ID: 0008_robot_controls
Revises: 0007_run_ids_never_reused
Create Date: 2026-11-28 09:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0008_robot_controls"
down_revision: str | None = "0007_run_ids_never_reused"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "robot_controls",
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("stop_requested", sa.Boolean(), server_default=sa.false(), nullable=False),
        sa.Column("reset_needed", sa.Boolean(), server_default=sa.false(), nullable=False),
        sa.Column("reset_count", sa.Integer(), server_default="0", nullable=False),
        sa.Column("actor_state", sa.String(length=100), nullable=True),
        sa.Column("actor_seen_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("frame_png", sa.LargeBinary(), nullable=True),
        sa.Column("frame_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["run_id"], ["runs.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("run_id"),
    )


def downgrade() -> None:
    op.drop_table("robot_controls")
