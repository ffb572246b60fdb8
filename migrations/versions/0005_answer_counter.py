"""answer_counter: the last answer number given, one row whose lock orders the answers

Revision ID: 0005_answer_counter
Revises: 0004_login_failures
Create Date: 2026-11-26 18:10:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0005_answer_counter"
down_revision: str | None = "0004_login_failures"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "answer_counter",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("value", sa.BigInteger(), nullable=False),
        sa.PrimaryKeyConstraint("id"),
    )
    # Numbers go on from the answers already given.
    op.execute("INSERT INTO answer_counter (id, value) SELECT 1, COALESCE(MAX(answer_seq), 0) FROM queries")


def downgrade() -> None:
    op.drop_table("answer_counter")
