"""Daily use through the API: the answer queue puts live runs' questions first, goal sets know their task, run
ids are never given twice, a finished run can be trained further, /compare without runs."""

import re

import sqlalchemy as sa
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


def _ask_in_an_old_schema(store: Store, run_id: int) -> None:
    """A question as a store of the schema's own version posted it (today's store writes newer columns)."""
    image = image_bytes((48, 48))
    with store.engine.begin() as connection:
        connection.execute(
            sa.text(
                "INSERT INTO queries (run_id, env_step, score, strategy, info, model_png, display_png, status, "
                "created_at) VALUES (:run_id, 1000, 1.0, 'argmax', '{}', :png, :png, 'pending', CURRENT_TIMESTAMP)"
            ),
            {"run_id": run_id, "png": image},
        )


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


def _run_in_an_old_schema(store: Store, name: str) -> int:
    """A run as a store of the schema's own version made it (today's store writes newer columns)."""
    with store.engine.begin() as connection:
        return connection.execute(
            sa.text(
                "INSERT INTO runs (name, env_id, algorithm, config, seed, status, status_reason, stop_requested, "
                "step, total_steps, priority, archived, created_at) VALUES (:name, 'VisualPusher-v0', 'vice_raq', "
                "'{}', 0, 'queued', '', 0, 0, 25000, 0, 0, CURRENT_TIMESTAMP) RETURNING id"
            ),
            {"name": name},
        ).scalar_one()


def test_run_ids_are_not_reused_in_a_database_made_before_migration_0007(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Migration 0007 rebuilds the runs table with AUTOINCREMENT and keeps what the runs own."""
    from app.migrate import upgrade

    url = f"sqlite:///{tmp_path / 'before.sqlite3'}"
    upgrade(url, "0006_goal_set_env")
    old = Store(url)
    first, second = _run_in_an_old_schema(old, "first"), _run_in_an_old_schema(old, "second")
    _ask_in_an_old_schema(old, first)
    with old.engine.begin() as connection:
        connection.execute(
            sa.text(
                "INSERT INTO events (run_id, level, message, created_at) VALUES (:run_id, 'info', 'started', "
                "CURRENT_TIMESTAMP)"
            ),
            {"run_id": first},
        )
        connection.execute(sa.text("DELETE FROM runs WHERE id = :id"), {"id": second})
    reused = _run_in_an_old_schema(old, "made before the migration")
    assert reused == second  # what 0006's table did
    old.dispose()
    upgrade(url)
    store = Store(url)
    assert store.count_queries(run_id=first) == 1 and len(store.events(run_id=first)) == 1
    store.delete_run(run_id=reused)
    assert _run(store, "after") == reused + 1
    store.dispose()


def _goal_set(client: TestClient, name: str, **values: object) -> dict:
    goal_set = client.post("/api/goal-sets", json={"name": name, **values})
    assert goal_set.status_code == 201, goal_set.text
    photo = ("files", ("goal.png", image_bytes((48, 48)), "image/png"))
    assert client.post(f"/api/goal-sets/{goal_set.json()['id']}/examples", files=[photo]).status_code == 201
    return goal_set.json()


def test_a_goal_set_knows_its_task_and_a_run_of_another_is_refused_unless_confirmed(client: TestClient) -> None:
    door = _goal_set(client, "door open", env_id="VisualDoor-v0")
    assert door["env_id"] == "VisualDoor-v0"
    assert client.get(f"/api/goal-sets/{door['id']}").json()["env_id"] == "VisualDoor-v0"
    # "Start a run with this set" opens the New run form on the set's task
    form = client.get(f"/runs/new?goal_set={door['id']}").text
    assert re.search(r'id="env_id"[^>]*value="VisualDoor-v0"', form)
    body = {"env_id": "VisualPusher-v0", "goal_set_id": door["id"]}
    refused = client.post("/api/runs", json=body)
    assert refused.status_code == 409
    assert "made for VisualDoor-v0, not VisualPusher-v0" in refused.json()["detail"]
    assert client.post("/api/runs/sweep", json={**body, "algorithms": ["vice"], "seeds": [0]}).status_code == 409
    assert client.get("/api/runs").json() == []
    confirmed = client.post("/api/runs", json={**body, "confirm_env_mismatch": True})
    assert confirmed.status_code == 201, confirmed.text
    same_task = client.post("/api/runs", json={**body, "env_id": "VisualDoor-v0"})
    assert same_task.status_code == 201, same_task.text
    # a set made for no task in particular fits any
    anything = _goal_set(client, "anything")
    assert anything["env_id"] is None
    assert client.post("/api/runs", json={**body, "goal_set_id": anything["id"]}).status_code == 201


def test_the_simulated_goal_set_of_a_task_knows_it(store: Store) -> None:
    from app.demo import add_simulated_goal_set

    goal_set_id = add_simulated_goal_set(store, task="door", name="door goals", count=1)
    assert store.get_goal_set(goal_set_id=goal_set_id).env_id == "VisualDoor-v0"


def test_a_run_takes_its_image_size_from_its_goal_set(client: TestClient) -> None:
    big = _goal_set(client, "big photos", image_size=64, env_id="VisualPusher-v0")
    run = client.post("/api/runs", json={"env_id": "VisualPusher-v0", "goal_set_id": big["id"]})
    assert run.status_code == 201, run.text
    assert run.json()["config"]["image_size"] == 64
    other = client.post(
        "/api/runs", json={"env_id": "VisualPusher-v0", "goal_set_id": big["id"], "config": {"image_size": 32}}
    )
    assert other.status_code == 422
    assert "prepares its photos at 64×64 px" in other.json()["detail"][0]["msg"]
    same = client.post(
        "/api/runs", json={"env_id": "VisualPusher-v0", "goal_set_id": big["id"], "config": {"image_size": 64}}
    )
    assert same.status_code == 201
    # without a goal set the config's own default
    sparse = client.post("/api/runs", json={"env_id": "VisualPusher-v0", "algorithm": "sparse"})
    assert sparse.json()["config"]["image_size"] == 48


def test_a_finished_run_is_continued_to_a_new_total_from_its_last_checkpoint(client: TestClient, store: Store) -> None:
    run_id = _run(store, "done")
    store.claim_next_run(worker="learner-a")
    store.heartbeat(run_id=run_id, worker="learner-a", step=25_000, status=RunStatus.TRAINING)
    store.set_run_status(run_id=run_id, status=RunStatus.FINISHED, worker="learner-a")
    resumed = client.post(f"/api/runs/{run_id}/resume")
    assert resumed.status_code == 409 and "continue it" in resumed.json()["detail"]
    assert client.post(f"/api/runs/{run_id}/continue", json={"total_steps": 25_000}).status_code == 400
    assert client.post(f"/api/runs/{run_id}/continue", json={"total_steps": 0}).status_code == 422
    continued = client.post(f"/api/runs/{run_id}/continue", json={"total_steps": 50_000})
    assert continued.status_code == 200, continued.text
    run = continued.json()
    assert (run["status"], run["step"], run["total_steps"]) == ("queued", 25_000, 50_000)
    assert any("continued from step 25,000 to 50,000 steps" in e.message for e in store.events(run_id=run_id))
    # a learner takes it again, at the new total (it loads the run's last checkpoint)
    claimed = store.claim_next_run(worker="learner-b")
    assert claimed is not None and claimed.id == run_id and claimed.total_steps == 50_000
    from learner.train import config_for_run

    assert config_for_run(store.get_run(run_id=run_id)).total_steps == 50_000
    # not while a learner holds it
    assert client.post(f"/api/runs/{run_id}/continue", json={"total_steps": 90_000}).status_code == 409


def test_compare_with_no_runs_picked_shows_the_page_with_how_to_pick_them(client: TestClient) -> None:
    for url in ("/compare", "/compare?runs=", "/compare?runs=,"):
        page = client.get(url)
        assert page.status_code == 200, url
        assert 'id="compare-hint"' in page.text and "Compare selected" in page.text
        assert 'id="compare-chart"' not in page.text
    assert client.get("/compare?runs=999").status_code == 404  # a run that is not there is still named
