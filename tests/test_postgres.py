"""The same store on PostgreSQL (DATABASE_URL): a real server started for the tests on 127.0.0.1 (the postgres_url
fixture of conftest.py, by tests/pg_server.py).

`make test` installs Debian's postgresql package; initdb refuses to run as root, so as root the server runs
as the `postgres` user that the package creates.
"""

import multiprocessing as mp
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
from sqlalchemy import inspect, text
from test_store import _claim_all, check_answer_numbers_heal  # the same checks as on SQLite

from app.migrate import downgrade, upgrade
from contract.store import Conflict, Store
from contract.store.db import IDLE_PING_S

PNG = b"\x89PNG\r\n\x1a\nquery"


def test_migrations_run_up_and_down_on_postgresql(postgres_url: str) -> None:
    upgrade(postgres_url)
    store = Store(postgres_url)
    assert {"runs", "queries", "goal_examples", "metrics"} <= set(inspect(store.engine).get_table_names())
    store.dispose()
    downgrade(postgres_url, "base")
    store = Store(postgres_url)
    assert "runs" not in inspect(store.engine).get_table_names()
    store.dispose()
    upgrade(postgres_url)


def test_the_store_works_on_postgresql(postgres_url: str) -> None:
    upgrade(postgres_url)
    store = Store(postgres_url)
    goal_set = store.create_goal_set(name="pg goals")
    example = store.add_goal_example(
        goal_set_id=goal_set.id, filename="g.png", original=b"orig", original_media_type="image/png",
        width=4, height=4, model_png=b"model", display_png=b"display",
    )  # fmt: skip
    assert store.goal_example_image(example_id=example.id, kind="model") == b"model"
    run_ids = [
        store.create_run(env_id="VisualPusher-v0", algorithm="vice_raq", config={"seed": 1}, goal_set_id=goal_set.id).id
        for _ in range(20)
    ]
    context = mp.get_context("spawn")
    barrier, results = context.Barrier(2), context.Queue()
    workers = [context.Process(target=_claim_all, args=(postgres_url, name, barrier, results)) for name in "ab"]
    for worker in workers:
        worker.start()
    claims = dict(results.get(timeout=60) for _ in workers)
    for worker in workers:
        worker.join(timeout=30)
    assert sorted(claims["a"] + claims["b"]) == run_ids and not set(claims["a"]) & set(claims["b"])

    run_id = run_ids[0]
    query = store.post_query(
        run_id=run_id, env_step=5, model_png=PNG, display_png=PNG, score=1.5, info={"success": 1.0},
        ground_truth_success=1.0,
    )  # fmt: skip
    store.answer_query(query_id=query.id, success=True, labeler="pg")
    with pytest.raises(Conflict):
        store.answer_query(query_id=query.id, success=False)
    assert [a.query_id for a in store.new_answers(run_id=run_id, since_seq=0)] == [query.id]
    assert store.query_image(query_id=query.id, resolution="model") == PNG
    store.record_metrics(run_id=run_id, step=1000, values={"eval/success_rate": 0.5, "critic/loss": float("nan")})
    assert store.latest_metric(run_id=run_id, name="eval/success_rate") == 0.5
    assert store.heartbeat(run_id=run_id, worker=store.get_run(run_id=run_id).worker, step=7) is True
    assert store.get_run(run_id=run_id).heartbeat_at.tzinfo is not None
    store.dispose()


def test_the_login_limit_on_postgresql_lets_exactly_the_limit_through_a_burst(postgres_url: str) -> None:
    """By PostgreSQL's clock, and one try per address at a time (an advisory lock): of 12 parallel tries from
    one address exactly 5 may go on; a right token (login_succeeded) is not counted."""
    upgrade(postgres_url)
    store = Store(postgres_url)
    with ThreadPoolExecutor(max_workers=12) as pool:
        waits = list(pool.map(lambda _: store.login_attempt(client="10.1.2.3", per_minute=5), range(12)))
    assert waits.count(None) == 5 and all(55 <= wait <= 60 for wait in waits if wait is not None)
    assert store.login_attempt(client="10.1.2.4", per_minute=5) is None
    store.login_succeeded(client="10.1.2.4")  # that try was the right token: with a limit of 1 it may try again
    assert store.login_attempt(client="10.1.2.4", per_minute=1) is None
    store.dispose()


def _answer_at_once(store: Store, query_id: int, success: bool, barrier, outcomes: list) -> None:  # type: ignore[no-untyped-def]
    barrier.wait()
    try:
        store.answer_query(query_id=query_id, success=success, labeler=str(success))
        outcomes.append(success)
    except Conflict:
        outcomes.append("conflict")


def test_two_different_answers_at_once_on_postgresql_keep_exactly_one(postgres_url: str) -> None:
    upgrade(postgres_url)
    store = Store(postgres_url)
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="sparse", config={}).id
    for _round in range(10):
        query_id = store.post_query(run_id=run_id, env_step=1, model_png=PNG, display_png=PNG, score=0.0).id
        barrier, outcomes = threading.Barrier(2), []
        threads = [
            threading.Thread(target=_answer_at_once, args=(store, query_id, value, barrier, outcomes))
            for value in (True, False)
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        kept = store.get_query(query_id=query_id)
        assert outcomes.count("conflict") == 1  # one answer wins, the other is refused
        assert [o for o in outcomes if o != "conflict"] == [kept.answer] and kept.labeler == str(kept.answer)
    store.dispose()


def test_answers_at_once_on_postgresql_reach_a_polling_learner_each_exactly_once(postgres_url: str) -> None:
    """40 labellers answer 200 queries at once while a learner polls "answers since my cursor": every answer
    reaches it once, so no number was given out of commit order (a cursor that passed an answer still being
    written would skip it for good), and each answer's event is logged."""
    upgrade(postgres_url)
    store, learner = Store(postgres_url), Store(postgres_url)
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="sparse", config={}).id
    ids = [
        store.post_query(run_id=run_id, env_step=i, model_png=PNG, display_png=PNG, score=0.0).id for i in range(200)
    ]
    seen: list[int] = []
    done = threading.Event()

    def poll() -> None:
        cursor = 0
        while True:
            finished = done.is_set()
            for answer in learner.new_answers(run_id=run_id, since_seq=cursor):
                seen.append(answer.query_id)
                cursor = max(cursor, answer.answer_seq)
            if finished:
                return

    reader = threading.Thread(target=poll)
    reader.start()
    with ThreadPoolExecutor(max_workers=40) as pool:
        list(pool.map(lambda query_id: store.answer_query(query_id=query_id, success=True, labeler="l"), ids))
    done.set()
    reader.join(timeout=60)
    assert sorted(seen) == ids
    events = store.events(run_id=run_id, limit=1000)
    assert sum("answered yes by l" in event.message for event in events) == 200
    store.dispose()
    learner.dispose()


def test_a_connection_dropped_by_the_server_is_replaced_after_it_idled(postgres_url: str) -> None:
    """PostgreSQL restarted (here: every backend terminated): a pooled connection that idled past IDLE_PING_S is
    pinged, found dead and replaced, so the next call works."""
    upgrade(postgres_url)
    store, admin = Store(postgres_url), Store(postgres_url)
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="sparse", config={}).id
    with admin.engine.connect() as connection:
        others = "pid <> pg_backend_pid() AND datname = 'raq'"
        connection.execute(text(f"SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE {others}"))
    time.sleep(IDLE_PING_S + 0.2)
    assert store.get_run(run_id=run_id).id == run_id
    store.dispose()
    admin.dispose()


def test_answer_numbers_heal_on_postgresql(postgres_url: str) -> None:
    upgrade(postgres_url)
    store = Store(postgres_url)
    check_answer_numbers_heal(store)
    store.dispose()


def test_an_answer_on_postgresql_waits_for_the_number_before_it_to_commit(postgres_url: str) -> None:
    """Numbers follow commit order: while another transaction holds the counter (an answer still being written),
    an answer waits, and then takes a higher number. What it returns is the stored row."""
    upgrade(postgres_url)
    store = Store(postgres_url)
    run_id = store.create_run(env_id="VisualPusher-v0", algorithm="sparse", config={}).id
    query_id = store.post_query(
        run_id=run_id, env_step=3, model_png=PNG, display_png=PNG, score=2.5, info={"success": 1.0}
    ).id
    store.skip_query(query_id=query_id)  # a skipped query can still be answered
    returned: list = []
    with store.engine.connect() as holder:
        held = holder.execute(text("UPDATE answer_counter SET value = value + 1 RETURNING value")).scalar_one()
        answering = threading.Thread(
            target=lambda: returned.append(store.answer_query(query_id=query_id, success=True, labeler="ann"))
        )
        answering.start()
        answering.join(timeout=0.5)
        assert answering.is_alive() and not returned  # waiting for the held number to commit
        holder.commit()
    answering.join(timeout=10)
    (query,) = returned
    assert query.answer_seq == held + 1
    assert (query.id, query.run_id, query.status, query.answer, query.labeler) == (
        query_id,
        run_id,
        "answered",
        True,
        "ann",
    )
    assert query.info == {"success": 1.0} and query.score == 2.5 and query.answered_at.tzinfo is not None
    stored = store.get_query(query_id=query_id)
    assert (stored.answer_seq, stored.answered_at, stored.status) == (query.answer_seq, query.answered_at, "answered")
    store.dispose()
