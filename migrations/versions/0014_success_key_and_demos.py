"""success key and demos: how many times a person pressed the success key, and episodes to drive by hand

Revision ID: 0014_success_key_and_demos
Revises: 0013_takeover
Create Date: 2026-12-07 03:00:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0014_success_key_and_demos"
down_revision: str | None = "0013_takeover"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("robot_controls") as batch:
        batch.add_column(sa.Column("success_marks", sa.Integer(), server_default="0", nullable=False))
        batch.add_column(sa.Column("demo_pending", sa.Integer(), server_default="0", nullable=False))


def downgrade() -> None:
    with op.batch_alter_table("robot_controls") as batch:
        batch.drop_column("demo_pending")
        batch.drop_column("success_marks")
