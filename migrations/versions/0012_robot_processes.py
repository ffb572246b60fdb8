"""robot_processes: the one process per robot that owns its camera and arm, and its newest frame

Revision ID: 0012_robot_processes
Revises: 0011_robot_holds
Create Date: 2026-12-06 12:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0012_robot_processes"
down_revision: str | None = "0011_robot_holds"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "robot_processes",
        sa.Column("robot", sa.String(length=300), nullable=False),
        sa.Column("env_id", sa.String(length=300), nullable=False),
        sa.Column("holder", sa.String(length=300), nullable=False),
        sa.Column("state", sa.String(length=100), nullable=False),
        sa.Column("seen_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("frame_png", sa.LargeBinary(), nullable=True),
        sa.Column("frame_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("watched_at", sa.DateTime(timezone=True), nullable=True),
        sa.PrimaryKeyConstraint("robot"),
    )
    op.create_index("ix_robot_processes_env_id", "robot_processes", ["env_id"])


def downgrade() -> None:
    op.drop_index("ix_robot_processes_env_id", table_name="robot_processes")
    op.drop_table("robot_processes")
