"""Daily use through the API: the answer queue puts live runs' questions first, goal sets know their task, run
ids are never given twice, a finished run can be trained further, /compare without runs."""

import re

from conftest import image_bytes
from fastapi.testclient import TestClient

from contract.store import RunStatus, Store


def _run(store: Store, name: str = "", **values: object) -> int:
    return store.create_run(
        env_id=str(values.pop("env_id", "VisualPusher-v0")), algorithm="vice_raq", config={}, total_steps=25_000,
        name=name, **values,
    ).id  # fmt: skip


def _ask(store: Store, run_id: int) -> int:
    image = image_bytes((48, 48))
    return store.post_query(run_id=run_id, env_step=1000, model_png=image, display_png=image, score=1.0).id


def test_the_queue_shows_live_runs_questions_first_and_the_badge_counts_only_theirs(
    client: TestClient, store: Store
) -> None:
    stopped, live = _run(store, "stopped"), _run(store, "live")
    old_question = _ask(store, stopped)  # asked first, by a run that was stopped afterwards
    store.request_stop(run_id=stopped)
    assert store.get_run(run_id=stopped).status == RunStatus.STOPPED
    new_question = _ask(store, live)
    item = client.get("/api/queries/next").json()
    assert item["query"]["id"] == new_question and item["run"]["id"] == live
    assert (item["pending"], item["pending_all_runs"]) == (2, 1)
    badge = re.search(r'id="nav-pending"[^>]*>(\d+)<', client.get("/").text)
    assert badge and badge.group(1) == "1"
    # once the live run's question is answered, the stopped run's comes next
    client.post(f"/api/queries/{new_question}/answer", json={"success": True})
    item = client.get("/api/queries/next").json()
    assert item["query"]["id"] == old_question and (item["pending"], item["pending_all_runs"]) == (1, 0)


def test_a_deleted_runs_id_is_never_given_again(client: TestClient, store: Store) -> None:
    ids = [_run(store, f"run {n}") for n in range(3)]
    assert client.delete(f"/api/runs/{ids[-1]}").status_code == 204
    created = client.post("/api/runs", json={"env_id": "VisualPusher-v0", "algorithm": "sparse"})
    assert created.status_code == 201, created.text
    assert created.json()["id"] == ids[-1] + 1


def test_run_ids_are_not_reused_in_a_database_made_before_migration_0007(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Migration 0007 rebuilds the runs table with AUTOINCREMENT and keeps what the runs own."""
    from app.migrate import upgrade

    url = f"sqlite:///{tmp_path / 'before.sqlite3'}"
    upgrade(url, "0006_goal_set_env")
    old = Store(url)
    first, second = _run(old, "first"), _run(old, "second")
    _ask(old, first)
    old.record_metrics(run_id=second, step=10, values={"eval/return": 1.0})
    old.delete_run(run_id=second)
    reused = _run(old, "made before the migration")
    assert reused == second  # what 0006's table did
    old.dispose()
    upgrade(url)
    store = Store(url)
    assert store.count_queries(run_id=first) == 1 and len(store.events(run_id=first)) == 1
    store.delete_run(run_id=reused)
    assert _run(store, "after") == reused + 1
    store.dispose()
