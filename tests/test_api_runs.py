"""Runs: create validated by TrainConfig (422 naming the field), list, stop, resume, metrics, events, rollouts."""

import io

from fastapi.testclient import TestClient
from PIL import Image

from contract.config import TrainConfig
from contract.store import RunStatus, Store


def _create_run(client: TestClient, goal_set_id: int | None, **body: object) -> dict:
    payload = {"env_id": "VisualPusher-v0", "algorithm": "vice_raq", "goal_set_id": goal_set_id, "seed": 3}
    payload.update(body)
    response = client.post("/api/runs", json=payload)
    assert response.status_code == 201, response.text
    return response.json()


def _field_errors(response) -> dict[str, str]:  # type: ignore[no-untyped-def]
    assert response.status_code == 422, response.text
    return {item["loc"][-1]: item["msg"] for item in response.json()["detail"]}


def test_create_run_stores_the_full_config(client: TestClient, goal_set_with_photo: dict, store: Store) -> None:
    run = _create_run(
        client, goal_set_with_photo["id"], name="first", config={"query_every": 2000, "total_steps": 30000}
    )
    assert run["status"] == "queued" and run["name"] == "first"
    assert (run["env_id"], run["algorithm"], run["seed"], run["total_steps"]) == (
        "VisualPusher-v0",
        "vice_raq",
        3,
        30000,
    )
    expected = TrainConfig(env_id="VisualPusher-v0", seed=3, query_every=2000, total_steps=30000).to_dict()
    assert run["config"] == expected
    stored = store.get_run(run_id=run["id"])
    assert stored.config_values() == expected  # each field stored once: these four in the run's columns only
    assert not {"env_id", "algorithm", "seed", "total_steps"} & set(stored.config)
    assert run["queries"] == {"asked": 0, "pending": 0, "answered": 0, "yes": 0, "skipped": 0}
    assert [r["id"] for r in client.get("/api/runs").json()] == [run["id"]]
    assert client.get(f"/api/runs/{run['id']}").json()["config"]["query_every"] == 2000


def test_bad_config_is_422_naming_the_field(client: TestClient, goal_set_with_photo: dict) -> None:
    goal_set_id = goal_set_with_photo["id"]
    base = {"env_id": "VisualPusher-v0", "goal_set_id": goal_set_id}
    errors = _field_errors(client.post("/api/runs", json={**base, "config": {"query_every": 0}}))
    assert "query_every" in errors and "at least 1" in errors["query_every"]
    errors = _field_errors(client.post("/api/runs", json={**base, "config": {"query_budget": "lots"}}))
    assert "query_budget" in errors and "query_budget" in errors["query_budget"]
    errors = _field_errors(client.post("/api/runs", json={**base, "config": {"learning_rate": 1}}))
    assert errors == {"learning_rate": "learning_rate: unknown config field"}
    errors = _field_errors(client.post("/api/runs", json={**base, "algorithm": "magic"}))
    assert "algorithm" in errors
    errors = _field_errors(client.post("/api/runs", json={**base, "config": {"discount": 2.0}}))
    assert "discount" in errors
    assert client.get("/api/runs").json() == []


def test_goal_based_algorithms_need_goal_photos(client: TestClient) -> None:
    errors = _field_errors(client.post("/api/runs", json={"env_id": "VisualDoor-v0", "algorithm": "vice"}))
    assert "goal photos" in errors["goal_set_id"]
    empty = client.post("/api/goal-sets", json={"name": "empty"}).json()
    errors = _field_errors(client.post("/api/runs", json={"algorithm": "vice_raq", "goal_set_id": empty["id"]}))
    assert "no goal photos" in errors["goal_set_id"]
    errors = _field_errors(client.post("/api/runs", json={"algorithm": "vice_raq", "goal_set_id": 999}))
    assert "not found" in errors["goal_set_id"]
    sparse = client.post("/api/runs", json={"env_id": "VisualDoor-v0", "algorithm": "sparse"})
    assert sparse.status_code == 201 and sparse.json()["goal_set_id"] is None


def test_stop_and_resume(client: TestClient, goal_set_with_photo: dict, store: Store) -> None:
    run = _create_run(client, goal_set_with_photo["id"])
    stopped = client.post(f"/api/runs/{run['id']}/stop")
    assert stopped.status_code == 200 and stopped.json()["status"] == "stopped"
    assert client.post(f"/api/runs/{run['id']}/stop").status_code == 409
    resumed = client.post(f"/api/runs/{run['id']}/resume")
    assert resumed.status_code == 200 and resumed.json()["status"] == "queued"
    assert client.post(f"/api/runs/{run['id']}/resume").status_code == 409
    # an active run is asked to stop; its learner sees it at the next heartbeat
    claimed = store.claim_next_run(worker="test-learner")
    assert claimed is not None and claimed.id == run["id"]
    stopping = client.post(f"/api/runs/{run['id']}/stop").json()
    assert stopping["status"] == "starting" and stopping["stop_requested"] is True
    assert store.heartbeat(run_id=run["id"], worker="test-learner", step=10) is False
    # a failed run shows its reason and can be resumed
    store.set_run_status(run_id=run["id"], status=RunStatus.FAILED, reason="RuntimeError: out of memory")
    failed = client.get(f"/api/runs/{run['id']}").json()
    assert failed["status"] == "failed" and failed["status_reason"] == "RuntimeError: out of memory"
    assert client.post(f"/api/runs/{run['id']}/resume").json()["status"] == "queued"
    messages = [event["message"] for event in client.get(f"/api/runs/{run['id']}/events").json()]
    assert "resume requested: queued" in messages and "run queued" in messages
    assert client.post("/api/runs/999/stop").status_code == 404
    assert client.get("/api/runs/999").status_code == 404


def test_run_summary_shows_progress(client: TestClient, goal_set_with_photo: dict, store: Store) -> None:
    run = _create_run(client, goal_set_with_photo["id"])
    store.claim_next_run(worker="w")
    store.heartbeat(run_id=run["id"], worker="w", step=1500, status=RunStatus.TRAINING)
    store.record_metrics(
        run_id=run["id"], step=1500,
        values={"eval/success_rate": 0.4, "perf/steps_per_second": 123.0, "perf/eta_seconds": 600.0},
    )  # fmt: skip
    summary = client.get("/api/runs").json()[0]
    assert summary["status"] == "training" and summary["step"] == 1500
    assert summary["success_rate"] == 0.4 and summary["steps_per_second"] == 123.0 and summary["eta_seconds"] == 600
    assert 0 <= summary["heartbeat_age_seconds"] < 30
    page = client.get("/")
    assert page.status_code == 200 and "VisualPusher-v0" in page.text


def test_metrics_since_step_and_names(client: TestClient, goal_set_with_photo: dict, store: Store) -> None:
    run = _create_run(client, goal_set_with_photo["id"])
    for step in (1000, 2000, 3000):
        store.record_metrics(
            run_id=run["id"], step=step, values={"eval/success_rate": step / 4000, "reward/loss": 1.0 / step}
        )
    store.record_metrics(run_id=run["id"], step=3000, values={"critic/loss": float("inf")})
    everything = client.get(f"/api/runs/{run['id']}/metrics").json()
    assert everything["last_step"] == 3000
    assert everything["series"]["eval/success_rate"] == [[1000, 0.25], [2000, 0.5], [3000, 0.75]]
    assert "critic/loss" not in everything["series"]  # non-finite values are left out
    newer = client.get(f"/api/runs/{run['id']}/metrics", params={"since_step": 1000}).json()
    assert [point[0] for point in newer["series"]["reward/loss"]] == [2000, 3000]
    nothing_new = client.get(f"/api/runs/{run['id']}/metrics", params={"since_step": 3000}).json()
    assert nothing_new == {"run_id": run["id"], "last_step": 3000, "series": {}}
    only = client.get(f"/api/runs/{run['id']}/metrics", params={"names": "reward/loss"}).json()
    assert list(only["series"]) == ["reward/loss"]
    both = client.get(
        f"/api/runs/{run['id']}/metrics", params=[("names", "reward/loss"), ("names", "eval/success_rate")]
    ).json()
    assert set(both["series"]) == {"reward/loss", "eval/success_rate"}
    assert client.get("/api/runs/999/metrics").status_code == 404


def test_latest_rollout_is_served_from_the_store(client: TestClient, goal_set_with_photo: dict, store: Store) -> None:
    run = _create_run(client, goal_set_with_photo["id"])
    url = f"/api/runs/{run['id']}/rollout/latest"
    assert client.get(url).status_code == 404
    frames = [Image.new("RGB", (32, 32), (i * 40, 0, 0)) for i in range(4)]
    buffer = io.BytesIO()
    frames[0].save(buffer, format="GIF", save_all=True, append_images=frames[1:], duration=80, loop=0)
    rollout = store.record_rollout(run_id=run["id"], env_step=5000, data=buffer.getvalue(), frame_count=4, success=1.0)
    response = client.get(url)
    assert response.status_code == 200 and response.headers["content-type"] == "image/gif"
    assert response.content == buffer.getvalue()
    detail = client.get(f"/api/runs/{run['id']}").json()
    assert detail["latest_rollout"]["id"] == rollout.id and detail["latest_rollout"]["env_step"] == 5000
    page = client.get(f"/runs/{run['id']}")
    assert page.status_code == 200 and "Latest evaluation" in page.text
