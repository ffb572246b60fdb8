"""goal_sets.env_id: the task a goal set was made for ("Start a run with this set" opens it; a run of another
task is refused unless confirmed)

Revision ID: 0006_goal_set_env
Revises: 0005_answer_counter
Create Date: 2026-11-27 09:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0006_goal_set_env"
down_revision: str | None = "0005_answer_counter"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # Plain ADD COLUMN (see 0003): sets made before this know no task (NULL) and fit any run.
    op.add_column("goal_sets", sa.Column("env_id", sa.String(length=200), nullable=True))


def downgrade() -> None:
    op.drop_column("goal_sets", "env_id")
