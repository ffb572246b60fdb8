"""robot_controls: a person's Evaluate now (episodes asked for, rounds) and the link between a learner and an
actor on another host (the learner's keep-alive, its newest policy's version, the step the run starts at, its
close, the actor's action and observation spaces); actor_messages: the remote actor's steps, in order

Revision ID: 0009_evaluation_and_actor_link
Revises: 0008_robot_controls
Create Date: 2026-12-02 04:30:00
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0009_evaluation_and_actor_link"
down_revision: str | None = "0008_robot_controls"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def robot_columns() -> tuple[sa.Column, ...]:
    return (
        sa.Column("evaluation_pending", sa.Integer(), server_default="0", nullable=False),
        sa.Column("evaluation_round", sa.Integer(), server_default="0", nullable=False),
        sa.Column("learner_seen_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("policy_version", sa.Integer(), server_default="0", nullable=False),
        sa.Column("start_step", sa.BigInteger(), nullable=True),
        sa.Column("learner_closed", sa.Boolean(), server_default=sa.false(), nullable=False),
        sa.Column("actor_spaces", sa.JSON(), nullable=True),
    )


def upgrade() -> None:
    with op.batch_alter_table("robot_controls") as batch:
        for column in robot_columns():
            batch.add_column(column)
    op.create_table(
        "actor_messages",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("kind", sa.String(length=20), nullable=False),
        sa.Column("payload", sa.JSON(), nullable=False),
        sa.Column("observation_png", sa.LargeBinary(), nullable=True),
        sa.Column("display_png", sa.LargeBinary(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["run_id"], ["runs.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index("ix_actor_messages_run_id_id", "actor_messages", ["run_id", "id"])


def downgrade() -> None:
    op.drop_index("ix_actor_messages_run_id_id", table_name="actor_messages")
    op.drop_table("actor_messages")
    with op.batch_alter_table("robot_controls") as batch:
        for column in reversed(robot_columns()):
            batch.drop_column(column.name)
