"""runs.id AUTOINCREMENT on SQLite: a deleted run's id is never given to a new run

Without AUTOINCREMENT SQLite gives a new row the largest id + 1, so deleting the newest run (#4) made the next
run #4 again. PostgreSQL's sequences never go back: nothing to do there.

Revision ID: 0007_run_ids_never_reused
Revises: 0006_goal_set_env
Create Date: 2026-11-27 09:10:00
"""

import contextlib
from collections.abc import Sequence

from alembic import op

revision: str = "0007_run_ids_never_reused"
down_revision: str | None = "0006_goal_set_env"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

PRIMARY_KEY = "PRIMARY KEY (id), "
ID_COLUMN = "id INTEGER NOT NULL, "


def upgrade() -> None:
    bind = op.get_bind()
    if bind.dialect.name != "sqlite":
        return
    (create,) = bind.exec_driver_sql("SELECT sql FROM sqlite_master WHERE type = 'table' AND name = 'runs'").one()
    if "AUTOINCREMENT" in create.upper():
        return
    indexes = [
        row[0]
        for row in bind.exec_driver_sql(
            "SELECT sql FROM sqlite_master WHERE type = 'index' AND tbl_name = 'runs' AND sql IS NOT NULL"
        )
    ]
    assert create.count(ID_COLUMN) == 1 and create.count(PRIMARY_KEY) == 1, create
    rebuilt = (
        create.replace("CREATE TABLE runs (", "CREATE TABLE runs_rebuilt (", 1)
        .replace(ID_COLUMN, "id INTEGER NOT NULL PRIMARY KEY AUTOINCREMENT, ", 1)
        .replace(PRIMARY_KEY, "", 1)
    )
    columns = ", ".join(row[1] for row in bind.exec_driver_sql("PRAGMA table_info(runs)"))
    # SQLite's way to change a table (https://sqlite.org/lang_altertable.html#otheralter): foreign keys off, which
    # only takes effect outside a transaction, so that dropping the old runs table cascades to no query, metric,
    # event or rollout; build the new one, copy, drop, rename, check the references, commit.
    bind.exec_driver_sql("COMMIT")  # what the migrations before this one did
    bind.exec_driver_sql("PRAGMA foreign_keys=OFF")
    try:
        bind.exec_driver_sql("BEGIN IMMEDIATE")
        bind.exec_driver_sql(rebuilt)
        bind.exec_driver_sql(f"INSERT INTO runs_rebuilt ({columns}) SELECT {columns} FROM runs")  # sets the sequence
        bind.exec_driver_sql("DROP TABLE runs")
        bind.exec_driver_sql("ALTER TABLE runs_rebuilt RENAME TO runs")
        for index in indexes:
            bind.exec_driver_sql(index)
        broken = bind.exec_driver_sql("PRAGMA foreign_key_check").all()
        if broken:
            raise RuntimeError(f"rebuilding the runs table broke references: {broken[:5]}")
        bind.exec_driver_sql("COMMIT")
    except BaseException:
        with contextlib.suppress(Exception):
            bind.exec_driver_sql("ROLLBACK")
        raise
    finally:
        bind.exec_driver_sql("PRAGMA foreign_keys=ON")
        bind.exec_driver_sql("BEGIN")  # alembic records the new revision in this one and commits it


def downgrade() -> None:
    pass  # ids that are never given twice harm nothing: the table stays as it is
