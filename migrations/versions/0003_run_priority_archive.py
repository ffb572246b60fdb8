"""runs: priority, queued_at, archived, phase (runs side by side, archive, the run's phase)

Revision ID: 0003_run_priority
Revises: 0002
Create Date: 2026-11-26 04:20:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003_run_priority"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


# Plain ALTER TABLE … ADD / DROP COLUMN, never a batch "move and copy": on SQLite that drops the old runs table,
# and with foreign keys on the drop cascades to every query, answer, metric, event and rollout of every run.


def upgrade() -> None:
    op.add_column("runs", sa.Column("priority", sa.Integer(), nullable=False, server_default="0"))
    op.add_column("runs", sa.Column("queued_at", sa.DateTime(timezone=True), nullable=True))
    op.add_column("runs", sa.Column("archived", sa.Boolean(), nullable=False, server_default=sa.false()))
    op.add_column("runs", sa.Column("phase", sa.String(length=30), nullable=True))


def downgrade() -> None:
    for column in ("phase", "archived", "queued_at", "priority"):
        op.drop_column("runs", column)
