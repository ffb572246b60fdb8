"""The store both processes use: runs, claims, queries, answers, metrics, on a real SQLite file."""

import multiprocessing as mp
import sqlite3
import time
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from conftest import answer_at_once
from sqlalchemy import inspect, text

from app.migrate import downgrade, upgrade
from contract.store import Conflict, InvalidInput, NotFound, QueryStatus, RunStatus, Store

PNG = b"\x89PNG\r\n\x1a\nfake-but-opaque-bytes"


def make_run(store: Store, **overrides) -> int:
    values = {"env_id": "VisualPusher-v0", "algorithm": "vice_raq", "config": {"query_every": 100}, "seed": 3}
    values.update(overrides)
    return store.create_run(**values).id


def post(store: Store, run_id: int, env_step: int = 10, truth: float | None = 1.0) -> int:
    return store.post_query(
        run_id=run_id, env_step=env_step, model_png=PNG, display_png=PNG + b"big", score=2.5,
        info={"success": truth}, ground_truth_success=truth,
    ).id  # fmt: skip


def test_sqlite_connections_use_wal_busy_timeout_and_foreign_keys(store: Store) -> None:
    with store.engine.connect() as connection:
        assert connection.execute(text("PRAGMA journal_mode")).scalar() == "wal"
        assert connection.execute(text("PRAGMA busy_timeout")).scalar() == 30000
        assert connection.execute(text("PRAGMA foreign_keys")).scalar() == 1


def test_store_imports_neither_torch_nor_fastapi() -> None:
    code = "import sys, contract.store; print('torch' in sys.modules, 'fastapi' in sys.modules)"
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False"]


def test_goal_sets_keep_the_original_and_two_copies(store: Store) -> None:
    goal_set = store.create_goal_set(name="mug on coaster", image_size=48)
    example = store.add_goal_example(
        goal_set_id=goal_set.id, filename="a.jpg", original=b"jpeg-bytes", original_media_type="image/jpeg",
        width=640, height=480, model_png=b"model", display_png=b"display",
    )  # fmt: skip
    assert store.goal_example_image(example_id=example.id, kind="original") == b"jpeg-bytes"
    assert store.goal_example_image(example_id=example.id, kind="model") == b"model"
    assert store.goal_example_image(example_id=example.id, kind="display") == b"display"
    assert [image.model_png for image in store.goal_images(goal_set_id=goal_set.id)] == [b"model"]
    assert store.list_goal_sets()[0][1] == 1
    with pytest.raises(Conflict):
        store.create_goal_set(name="mug on coaster")
    with pytest.raises(InvalidInput):
        store.goal_example_image(example_id=example.id, kind="../../etc/passwd")
    store.delete_goal_set(goal_set_id=goal_set.id)  # cascades to its examples (foreign keys are on)
    with pytest.raises(NotFound):
        store.get_goal_example(example_id=example.id)


def test_run_lifecycle_claim_heartbeat_stop_resume(store: Store) -> None:
    run_id = make_run(store, total_steps=5000)
    run = store.get_run(run_id=run_id)
    assert (run.status, run.config, run.seed, run.total_steps) == (RunStatus.QUEUED, {"query_every": 100}, 3, 5000)

    claimed = store.claim_next_run(worker="w1")
    assert claimed is not None and claimed.id == run_id and claimed.status == RunStatus.STARTING
    assert store.claim_next_run(worker="w2") is None  # fresh heartbeat: nobody else can take it
    assert store.heartbeat(run_id=run_id, worker="w1", step=250, status=RunStatus.TRAINING) is True
    assert store.heartbeat(run_id=run_id, worker="w2", step=999) is False  # not w2's run
    assert store.get_run(run_id=run_id).step == 250

    store.request_stop(run_id=run_id)
    assert store.heartbeat(run_id=run_id, worker="w1", step=300) is False  # the learner is told to stop
    store.set_run_status(run_id=run_id, status=RunStatus.STOPPED, worker="w1")
    with pytest.raises(Conflict):
        store.request_stop(run_id=run_id)
    store.resume_run(run_id=run_id)
    assert store.get_run(run_id=run_id).status == RunStatus.QUEUED
    messages = [event.message for event in store.events(run_id=run_id)]
    assert "stop requested" in messages and "resume requested: queued" in messages


def test_a_run_whose_learner_stopped_beating_is_reclaimed(store: Store) -> None:
    run_id = make_run(store)
    assert store.claim_next_run(worker="dead").id == run_id
    assert store.claim_next_run(worker="alive", stale_after_seconds=60) is None
    reclaimed = store.claim_next_run(worker="alive", stale_after_seconds=0)
    assert reclaimed is not None and reclaimed.worker == "alive"
    assert store.heartbeat(run_id=run_id, worker="dead") is False  # the old learner lost it


def test_failed_run_keeps_its_reason(store: Store) -> None:
    run_id = make_run(store)
    store.claim_next_run(worker="w")
    store.set_run_status(run_id=run_id, status=RunStatus.FAILED, reason="ValueError: bad env", worker="w")
    run = store.get_run(run_id=run_id)
    assert (run.status, run.status_reason) == ("failed", "ValueError: bad env")
    assert store.events(run_id=run_id)[0].level == "error"


def test_answers_are_idempotent_and_a_different_second_answer_is_refused(store: Store) -> None:
    run_id = make_run(store)
    query_id = post(store, run_id)
    assert [q.id for q in store.pending_queries(run_id=run_id)] == [query_id]
    store.answer_query(query_id=query_id, success=True, labeler="alice")
    store.answer_query(query_id=query_id, success=True, labeler="alice")  # same answer again: fine
    with pytest.raises(Conflict, match="first answer is kept"):
        store.answer_query(query_id=query_id, success=False, labeler="bob")
    query = store.get_query(query_id=query_id)
    assert (query.status, query.answer, query.labeler) == (QueryStatus.ANSWERED, True, "alice")
    with pytest.raises(NotFound):
        store.answer_query(query_id=query_id + 100, success=True)
    assert store.query_image(query_id=query_id, resolution="display") == PNG + b"big"
    assert store.query_counts(run_id=run_id) == {"asked": 1, "pending": 0, "answered": 1, "yes": 1, "skipped": 0}


def test_new_answers_since_a_point_and_undo_only_before_the_learner_used_them(store: Store) -> None:
    run_id = make_run(store)
    first, second, third = (post(store, run_id, env_step=step) for step in (100, 200, 300))
    store.answer_query(query_id=second, success=False)  # answered out of order
    store.answer_query(query_id=first, success=True)
    store.skip_query(query_id=third)
    answers = store.new_answers(run_id=run_id, since_seq=0)
    assert [(a.query_id, a.success) for a in answers] == [(second, False), (first, True)]
    assert store.new_answers(run_id=run_id, since_seq=answers[-1].answer_seq) == []
    with pytest.raises(Conflict, match="already used"):
        store.undo_answer(query_id=first)
    store.undo_answer(query_id=third)  # a skip the learner never sees can be undone
    assert store.get_query(query_id=third).status == QueryStatus.PENDING
    store.answer_query(query_id=third, success=True)
    assert [a.query_id for a in store.new_answers(run_id=run_id, since_seq=answers[-1].answer_seq)] == [third]


def test_metrics_since_a_step_and_rollouts_keep_the_newest(store: Store) -> None:
    run_id = make_run(store)
    for step in (1000, 2000, 3000):
        store.record_metrics(run_id=run_id, step=step, values={"eval/success_rate": step / 4000, "critic/loss": 1.0})
    assert [m.step for m in store.metrics(run_id=run_id, since_step=1000, names=["eval/success_rate"])] == [2000, 3000]
    assert store.latest_metric(run_id=run_id, name="eval/success_rate") == 0.75
    assert store.record_metrics(run_id=run_id, step=4000, values={"critic/loss": float("nan"), "alpha": 0.1}) == 1
    assert store.latest_metric(run_id=run_id, name="critic/loss") == 1.0  # the NaN was left out, not stored
    for step in range(5):
        store.record_rollout(run_id=run_id, env_step=step, data=b"GIF%d" % step, frame_count=3, keep=2)
    latest = store.latest_rollout(run_id=run_id)
    assert latest.env_step == 4 and store.rollout_data(rollout_id=latest.id) == b"GIF4"


def test_migrations_upgrade_a_fresh_database_and_downgrade_back(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'fresh.sqlite3'}"
    upgrade(url)
    store = Store(url)
    tables = set(inspect(store.engine).get_table_names())
    assert {"goal_sets", "goal_examples", "runs", "queries", "metrics", "events", "rollouts"} <= tables
    store.dispose()
    downgrade(url, "base")
    store = Store(url)
    assert set(inspect(store.engine).get_table_names()) <= {"alembic_version"}
    store.dispose()
    upgrade(url)  # and up again


def test_migrating_a_database_with_runs_keeps_every_answer_metric_and_event(tmp_path: Path) -> None:
    """Each migration up from 0001 and back down keeps what the runs own (a batch 'move and copy' of the runs
    table dropped it through the foreign keys' ON DELETE CASCADE: every query, answer and metric was lost)."""
    url = f"sqlite:///{tmp_path / 'old.sqlite3'}"
    upgrade(url, "0001")
    engine = sa.create_engine(url)
    with engine.begin() as connection:
        connection.execute(sa.text("PRAGMA foreign_keys=ON"))
        connection.execute(sa.text(
            "INSERT INTO runs (id, name, env_id, algorithm, config, seed, status, status_reason, stop_requested, "
            "step, total_steps, created_at) VALUES (1, 'r', 'VisualPusher-v0', 'vice_raq', '{}', 0, 'stopped', '', 0, "
            "500, 1000, '2026-01-01 00:00:00.000000')"
        ))  # fmt: skip
        connection.execute(sa.text(
            "INSERT INTO queries (run_id, env_step, model_png, display_png, score, strategy, info, status, answer, "
            "created_at) VALUES (1, 100, x'00', x'00', 1.5, 'argmax', '{}', 'answered', 1, "
            "'2026-01-01 00:00:00.000000')"
        ))  # fmt: skip
        connection.execute(sa.text(
            "INSERT INTO metrics (run_id, step, name, value, created_at) VALUES (1, 100, 'eval/return', 1, "
            "'2026-01-01 00:00:00.000000')"
        ))  # fmt: skip
        connection.execute(sa.text(
            "INSERT INTO events (run_id, level, message, created_at) VALUES (1, 'info', 'e', "
            "'2026-01-01 00:00:00.000000')"
        ))  # fmt: skip
    engine.dispose()

    def owned() -> tuple[int, ...]:
        with sa.create_engine(url).connect() as connection:
            return tuple(
                connection.execute(sa.text(f"SELECT count(*) FROM {table}")).scalar_one()
                for table in ("runs", "queries", "metrics", "events")
            )

    assert owned() == (1, 1, 1, 1)
    upgrade(url)
    assert owned() == (1, 1, 1, 1)
    store = Store(url)
    assert store.get_query(query_id=1).answer is True and store.get_run(run_id=1).step == 500
    store.dispose()
    downgrade(url, "0001")
    assert owned() == (1, 1, 1, 1)
    upgrade(url)
    assert owned() == (1, 1, 1, 1)


# ---------------------------------------------------------------- several processes on one SQLite file
def _claim_all(url: str, worker: str, barrier, results) -> None:  # type: ignore[no-untyped-def]
    store = Store(url)
    barrier.wait()
    claimed = []
    while (run := store.claim_next_run(worker=worker)) is not None:
        claimed.append(run.id)
    results.put((worker, claimed))


def test_two_worker_processes_racing_never_take_the_same_run(database_url: str, store: Store) -> None:
    run_ids = [make_run(store) for _ in range(30)]
    context = mp.get_context("spawn")
    barrier, results = context.Barrier(2), context.Queue()
    workers = [context.Process(target=_claim_all, args=(database_url, name, barrier, results)) for name in ("a", "b")]
    for worker in workers:
        worker.start()
    claims = dict(results.get(timeout=60) for _ in workers)
    for worker in workers:
        worker.join(timeout=30)
        assert worker.exitcode == 0
    assert sorted(claims["a"] + claims["b"]) == run_ids  # every run taken once
    assert not set(claims["a"]) & set(claims["b"])
    assert {store.get_run(run_id=run_id).worker for run_id in claims["a"]} <= {"a"}


def _race_for_one(url: str, worker: str, barrier, results) -> None:  # type: ignore[no-untyped-def]
    store = Store(url)
    for _round in range(10):
        barrier.wait()
        run = store.claim_next_run(worker=worker)
        results.put(run.id if run else None)
        barrier.wait()


def test_exactly_one_of_two_racing_workers_wins_a_single_run(database_url: str, store: Store) -> None:
    context = mp.get_context("spawn")
    barrier, results = context.Barrier(3), context.Queue()
    workers = [
        context.Process(target=_race_for_one, args=(database_url, name, barrier, results)) for name in ("a", "b")
    ]
    for worker in workers:
        worker.start()
    for _round in range(10):
        run_id = make_run(store)
        barrier.wait()  # both workers claim now
        outcomes = [results.get(timeout=30) for _ in workers]
        assert sorted(outcomes, key=lambda x: x is None) == [run_id, None]
        barrier.wait()
    for worker in workers:
        worker.join(timeout=30)


def _write_a_lot(url: str, run_id: int, label: str, count: int, errors) -> None:  # type: ignore[no-untyped-def]
    store = Store(url)
    try:
        for index in range(count):
            store.record_metrics(run_id=run_id, step=index, values={f"{label}/value": float(index)})
            if index % 10 == 0:
                query_id = post(store, run_id, env_step=index)
                store.answer_query(query_id=query_id, success=bool(index % 20), labeler=label)
                store.record_event(run_id=run_id, message=f"{label} {index}")
    except Exception as error:  # noqa: BLE001 - report any failure to the test
        errors.put(f"{label}: {error!r}")


def test_two_processes_write_one_sqlite_file_at_once_without_database_is_locked(
    database_url: str, store: Store
) -> None:
    run_id = make_run(store)
    context = mp.get_context("spawn")
    errors = context.Queue()
    writers = [context.Process(target=_write_a_lot, args=(database_url, run_id, name, 300, errors)) for name in "xy"]
    for writer in writers:
        writer.start()
    for writer in writers:
        writer.join(timeout=120)
    assert errors.empty(), errors.get()
    for name in "xy":
        assert len(store.metrics(run_id=run_id, names=[f"{name}/value"])) == 300
    assert store.query_counts(run_id=run_id)["answered"] == 60
    seqs = [answer.answer_seq for answer in store.new_answers(run_id=run_id, since_seq=0)]
    assert seqs == sorted(set(seqs)) and len(seqs) == 60  # one total order of answers


def _hold_write_lock(url: str, held: Any, seconds: float) -> None:
    """Another process (a learner) in a write transaction for `seconds`."""
    other = Store(url)
    with other.writing() as session:
        session.execute(text("UPDATE runs SET step = step + 1"))
        held.set()
        time.sleep(seconds)
    other.dispose()


def test_a_write_waits_for_another_process_write_lock_then_lands(store: Store, database_url: str) -> None:
    run_id = make_run(store)
    query_id = post(store, run_id)
    held = mp.get_context("spawn").Event()
    holder = mp.get_context("spawn").Process(target=_hold_write_lock, args=(database_url, held, 0.5))
    holder.start()
    assert held.wait(timeout=60)
    started = time.monotonic()
    store.answer_query(query_id=query_id, success=True, labeler="waited")  # would be "database is locked"
    assert time.monotonic() - started >= 0.2  # it did wait for the other process's commit
    holder.join(timeout=60)
    assert store.get_query(query_id=query_id).answer is True
    assert store.get_run(run_id=run_id).step == 1  # the other process's write landed too
    with store.engine.connect() as connection:  # the wait polled with busy_timeout 0, then restored it
        assert connection.execute(text("PRAGMA busy_timeout")).scalar() == 30000


def take_the_write_lock_at_once(database_url: str) -> None:
    """Another connection takes SQLite's write lock without waiting: raises "database is locked" if one is held."""
    other = sqlite3.connect(database_url.removeprefix("sqlite:///"), timeout=0)
    other.execute("BEGIN IMMEDIATE")
    other.rollback()
    other.close()


def test_a_learners_writes_are_single_statements_that_leave_no_lock_behind(store: Store, database_url: str) -> None:
    """Heartbeat, query, metrics, event and the answers read: each one statement in SQLite's own transaction (no
    BEGIN from Python, so the write lock is never held while the learner's process waits between statements),
    stored the moment it returns."""
    run_id = make_run(store)
    assert store.claim_next_run(worker="w") is not None
    answered = post(store, run_id)
    store.answer_query(query_id=answered, success=True, labeler="person")
    statements: list[str] = []

    def record(_connection, _cursor, statement, *_args) -> None:  # type: ignore[no-untyped-def]
        statements.append(statement.split()[0].upper())

    sa.event.listen(store.engine, "before_cursor_execute", record)
    try:
        assert store.heartbeat(run_id=run_id, worker="w", step=7, phase="training")
        query = store.post_query(run_id=run_id, env_step=7, model_png=PNG, display_png=PNG + b"big", score=1.0)
        posted = query.id
        assert (query.model_png, query.display_png, query.status) == (PNG, PNG + b"big", QueryStatus.PENDING)
        assert store.record_metrics(run_id=run_id, step=7, values={"a": 1.0, "b": float("nan"), "c": 2.0}) == 2
        store.record_event(run_id=run_id, message="epoch 1")
        assert [a.query_id for a in store.new_answers(run_id=run_id)] == [answered]
    finally:
        sa.event.remove(store.engine, "before_cursor_execute", record)
    assert statements == ["UPDATE", "INSERT", "INSERT", "INSERT", "UPDATE"]
    take_the_write_lock_at_once(database_url)
    fresh = Store(database_url)
    try:
        assert fresh.get_run(run_id=run_id).step == 7
        assert fresh.get_query(query_id=posted).status == QueryStatus.PENDING
        assert fresh.query_image(query_id=posted, resolution="display") == PNG + b"big"
        assert {m.name: m.value for m in fresh.metrics(run_id=run_id)} == {"a": 1.0, "c": 2.0}
        assert "epoch 1" in [e.message for e in fresh.events(run_id=run_id)]
        assert fresh.get_query(query_id=answered).used_at is not None
        with pytest.raises(NotFound):
            post(fresh, 10_000)
        assert fresh.count_queries() == 2
    finally:
        fresh.dispose()


def test_an_answer_holds_sqlites_write_lock_for_three_statements_only(store: Store, database_url: str) -> None:
    """Under BEGIN IMMEDIATE an answer runs exactly: take a number, set the answer, log the event (no ORM read and
    flush between them); an answer given again writes nothing and is explained by a read after the lock is gone."""
    run_id = make_run(store)
    query_id = post(store, run_id)
    statements: list[str] = []

    def record(_connection, _cursor, statement, *_args) -> None:  # type: ignore[no-untyped-def]
        statements.append(statement.split()[0].upper())

    sa.event.listen(store.engine, "before_cursor_execute", record)
    try:
        answered = store.answer_query(query_id=query_id, success=True, labeler="person")
        first = list(statements)
        statements.clear()
        again = store.answer_query(query_id=query_id, success=True, labeler="someone else")
    finally:
        sa.event.remove(store.engine, "before_cursor_execute", record)
    assert first == ["INSERT", "UPDATE", "INSERT"]
    assert statements[0] == "INSERT" and "UPDATE" not in statements  # no number taken, nothing changed
    assert (answered.status, answered.answer, answered.labeler, answered.answer_seq) == (
        QueryStatus.ANSWERED, True, "person", 1,
    )  # fmt: skip
    assert (again.labeler, again.answer_seq) == ("person", 1)
    take_the_write_lock_at_once(database_url)
    assert [e.message for e in store.events(run_id=run_id)].count(f"query {query_id} answered yes by person") == 1
    with pytest.raises(Conflict):
        store.answer_query(query_id=query_id, success=False)
    with pytest.raises(NotFound):
        store.answer_query(query_id=10_000, success=True)


def test_many_threads_answering_while_a_learner_beats_all_land_numbered_in_order(
    store: Store, database_url: str
) -> None:
    """As bench/load.py's labellers and learners on one SQLite file: every answer lands, answer_seq 1..N."""
    run_id = make_run(store)
    store.claim_next_run(worker="learner-a")
    ids = [post(store, run_id, env_step=i) for i in range(60)]
    learner = Store(database_url)  # its own connections, as the learner process has
    beats: list[bool] = []

    def beat() -> None:
        beats.extend(learner.heartbeat(run_id=run_id, worker="learner-a") for _ in range(30))

    assert answer_at_once(store, ids, 12, alongside=beat) == []
    assert beats == [True] * 30
    answers = learner.new_answers(run_id=run_id, since_seq=0)
    assert [a.answer_seq for a in answers] == list(range(1, 61))
    assert sorted(a.query_id for a in answers) == ids
    assert all(a.success == (a.query_id % 2 == 0) for a in answers)
    learner.dispose()


def test_answer_numbers_go_on_from_the_answers_given_before_the_counter_existed(tmp_path: Path) -> None:
    """Migration 0005 starts the answer counter at the highest answer_seq already given."""
    url = f"sqlite:///{tmp_path / 'old.sqlite3'}"
    upgrade(url, "0004_login_failures")
    run_id = 1
    with sa.create_engine(url).begin() as connection:  # a run and its questions as 0004's store wrote them
        connection.execute(sa.text(
            "INSERT INTO runs (id, name, env_id, algorithm, config, seed, status, status_reason, stop_requested, "
            "step, total_steps, priority, archived, created_at) VALUES (1, 'r', 'VisualPusher-v0', 'vice_raq', "
            "'{}', 3, 'queued', '', 0, 0, 1000, 0, 0, CURRENT_TIMESTAMP)"
        ))  # fmt: skip
        ids = [
            connection.execute(
                sa.text(
                    "INSERT INTO queries (run_id, env_step, score, strategy, info, model_png, display_png, status, "
                    "created_at) VALUES (:run_id, :step, 2.5, 'argmax', '{}', :png, :png, 'pending', "
                    "CURRENT_TIMESTAMP) RETURNING id"
                ),
                {"run_id": run_id, "step": step, "png": PNG},
            ).scalar_one()
            for step in range(3)
        ]
    with sa.create_engine(url).begin() as connection:  # answers as 0004's store numbered them
        for seq, query_id in enumerate(ids[:2], start=1):
            connection.execute(
                sa.text("UPDATE queries SET status = 'answered', answer = 1, answer_seq = :seq WHERE id = :id"),
                {"seq": seq, "id": query_id},
            )
    upgrade(url)
    store = Store(url)
    store.answer_query(query_id=ids[2], success=False)
    assert [a.answer_seq for a in store.new_answers(run_id=run_id, since_seq=0)] == [1, 2, 3]
    store.dispose()


def check_answer_numbers_heal(store: Store) -> None:
    """The counter behind the numbers already given (an older server process answered while this one migrated)
    or missing: the next answer still takes a new, higher number."""
    run_id = make_run(store)
    ids = [post(store, run_id, env_step=i) for i in range(3)]
    first = store.answer_query(query_id=ids[0], success=True).answer_seq
    with store.engine.begin() as connection:  # numbered past the counter, as the old code did
        connection.execute(
            sa.text("UPDATE queries SET status = 'answered', answer = true, answer_seq = :seq WHERE id = :id"),
            {"seq": first + 6, "id": ids[1]},
        )
    assert store.answer_query(query_id=ids[2], success=False).answer_seq == first + 7
    with store.engine.begin() as connection:
        connection.execute(sa.text("DELETE FROM answer_counter"))
    store.undo_answer(query_id=ids[2])
    assert store.answer_query(query_id=ids[2], success=True).answer_seq == first + 7  # (undone: free again)
    assert [a.answer_seq for a in store.new_answers(run_id=run_id, since_seq=0)] == [first, first + 6, first + 7]


def test_answer_numbers_heal_when_the_counter_fell_behind_or_is_missing(store: Store) -> None:
    check_answer_numbers_heal(store)
